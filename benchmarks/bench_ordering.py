#!/usr/bin/env python3
"""Benchmark: fill-reducing orderings of the 50k-vertex Gauss-Newton systems (what one factorization costs).

Cases ``bar50k`` and ``body50k`` of ``bench_multires.py`` (the systems of
``bench_continuation.py``): the Gauss-Newton matrix of ``W_q`` at key 0 for
the blend ``t = 0.5``, 3 V unknowns.  Each ordering is given to CHOLMOD alone
(``cvxopt.cholmod.options["nmethods"] = 1``: no comparison with AMD; this CHOLMOD has no METIS):

* ``amd``: CHOLMOD's AMD;
* ``nested_dissection``: lacore's geometric nested dissection
  (:func:`lacore.linalg.sparse_cholesky.nested_dissection` on the coupled-vertex graph,
  from key 0's coordinates);
* ``metis``: METIS nested dissection of the same graph
  (:func:`lacore.linalg.sparse_cholesky.metis_nested_dissection`; pymetis, an optional
  dependency, ``lacore[fast]``), else ``{"unavailable": ...}``;
* ``lacore_default``: what :class:`lacore.reconstruction.ReconstructionContext`
  uses (:func:`lacore.reconstruction.assembly.dof_ordering`: METIS if available,
  else the geometric one, and AMD tried, the one with fewer nonzeros kept).

Per ordering: the ordering's own time, nonzeros of ``L``, the flop estimate
``sum_j c_j^2`` (``c_j`` nonzeros of column ``j`` of ``L``) and the fastest of
``--repeat`` numeric factorizations.  Peak memory of the process (``maxrss_mb``).

Prints ONE JSON object.  usage: python benchmarks/bench_ordering.py [--quick] [--repeat 3]
"""

import argparse
import json
import os
import resource
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

from bench_common import machine_info  # noqa: E402
from bench_multires import cases  # noqa: E402


def measure(pattern, values, vertex_order, repeat, compare_amd=False):
    """Nonzeros, flop estimate and numeric time of CHOLMOD with one vertex ordering (None: AMD)."""
    import cvxopt.cholmod

    from lacore.linalg.sparse_cholesky import SparseCholesky

    ordering = None if vertex_order is None else (3 * vertex_order[:, None] + np.arange(3)).ravel()
    saved = dict(cvxopt.cholmod.options)
    if vertex_order is not None and not compare_amd:
        cvxopt.cholmod.options["nmethods"] = 1  # the given ordering only (without one, CHOLMOD's AMD alone)
    try:
        t0 = time.perf_counter()
        chol = SparseCholesky(pattern["matrix"], ordering=ordering)
        symbolic = time.perf_counter() - t0
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            chol.factorize(values)
            times.append(time.perf_counter() - t0)
    finally:
        cvxopt.cholmod.options.clear()
        cvxopt.cholmod.options.update(saved)
    counts = chol.factor_column_counts().astype(float)
    return {"factor_nnz": int(counts.sum()), "flops_estimate": float(np.sum(counts ** 2)),
            "symbolic_seconds": symbolic, "numeric_seconds": min(times), "numeric_seconds_all": times}


def run_case(S, topo, repeat):
    from lacore.geometry.lengths_angles import lengths_and_angles
    from lacore.reconstruction import get_context
    from lacore.reconstruction.assembly import coupled_vertex_graph, dof_ordering
    from lacore.linalg.sparse_cholesky import metis_nested_dissection, nested_dissection

    ctx = get_context(topo, S[0])
    pat = ctx.pattern
    z = 0.5 * (lengths_and_angles(S[0], topo) + lengths_and_angles(S[1], topo))
    _, _, matrix = ctx.objective(z).linearize(ctx.to_canonical(S[0]))
    values = matrix()
    ctx.eliminate_fixed(values)
    G = coupled_vertex_graph(pat, topo.n_vertices)
    out = {"vertices": int(topo.n_vertices), "unknowns": int(pat["n"]), "matrix_nnz_lower": int(pat["nnz"]),
           "orderings": {}}
    t0 = time.perf_counter()
    nd = nested_dissection(G, S[0])
    nd_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    metis = metis_nested_dissection(G)
    metis_seconds = time.perf_counter() - t0
    rows = {"amd": (None, 0.0), "nested_dissection": (nd, nd_seconds)}
    if metis is not None:
        rows["metis"] = (metis, metis_seconds)
    else:
        out["orderings"]["metis"] = {"unavailable": "pymetis is not importable"}
    for name, (order, seconds) in rows.items():
        out["orderings"][name] = {"ordering_seconds": seconds, **measure(pat, values, order, repeat)}
        print(f"{name}: {out['orderings'][name]['flops_estimate'] / 1e9:.1f} GFlop", file=sys.stderr, flush=True)
    default = dof_ordering(topo, pat, S[0])[0][::3] // 3
    out["orderings"]["lacore_default"] = measure(pat, values, default, repeat, compare_amd=True)
    out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small meshes (bar 1.8k, body 13.4k) instead of ~50k")
    parser.add_argument("--repeat", type=int, default=3, help="numeric factorizations per ordering (fastest kept)")
    args = parser.parse_args(argv)
    result = {"benchmark": "ordering", "machine": machine_info(), "cases": {}}
    from lacore.linalg.sparse_cholesky import _pymetis

    result["machine"]["pymetis"] = _pymetis() is not None
    for name, (S, topo) in cases(args.quick).items():
        result["cases"][name] = run_case(S, topo, args.repeat)
    result["machine"]["load_average_after"] = list(os.getloadavg())
    json.dump(result, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
