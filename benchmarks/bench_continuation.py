#!/usr/bin/env python3
"""Benchmark: 10 in-betweens of ~50k-vertex meshes by continuation along t, and Newton steps.

Cases: ``bar50k`` (box bar, 49,090 vertices, bend 90 -> twist 90) and ``body50k``
(the MakeHuman body subdivided once, 53,514 vertices, bent 60 -> twisted 60), the
cases of ``bench_multires.py``, and ``bend50k`` (the same closed bar, straight -> bent 90
degrees by Blender's Simple Deform formula, as in ``bench_interpolation.py``: a smooth
motion).  ``W_q``, weights (3.20) from key 0, ``eta = 1e-3``.

Sequence ``t = 1/11 .. 10/11`` (:func:`lacore.shapes.interpolation.interpolate`, frames in
order, one context), by

* ``gauss_newton``: ``method="gn"`` run to convergence, started from the secant
  prediction through the two frames before (default ``warm_start="secant"``)
  with Newton steps where Gauss-Newton converges slowly (default
  ``newton="auto"``): the reference every other row is compared with;
* ``gauss_newton_before``: the same before this change (``warm_start="nearest"``,
  ``newton="never"``);
* ``fast``: :data:`lacore.reconstruction.settings.FAST`, the default projection of
  ``lacore interpolate``, of :func:`lacore.shapes.interpolation.interpolate` and the
  add-on's Fast: the secant prediction and one Gauss-Newton step (a frame started
  from a known shape itself, the first after a key: up to three, ``ftol = 1e-4``;
  more where a step did not agree with its quadratic model, ``extend_smoothing``);
* ``cli_default``: ``lacore interpolate`` itself (default options, in this process;
  the row's time includes reading and writing PLY files and the set-up of the CLI's
  own topology: its symbolic analysis), its energies read back from ``--json``;
* ``fast_no_extension``: ``fast`` without ``extend_smoothing`` (the add-on's Fast before);
* ``fast_geometric_ordering``: ``fast`` with lacore's geometric nested dissection
  instead of METIS (``ordering="geometric"``; both tried against AMD by CHOLMOD);
* ``fast_2_workers``: ``fast`` with ``workers=2`` (:mod:`lacore.parallel`): frames
  1-5 here, 10-6 in a worker process (which builds its own solver);
* ``fast_before``: the add-on's Fast before (least-squares start, two steps
  reusing factorizations across frames, nearest warm start ignored);
* ``one_step``: the secant prediction and one Gauss-Newton step;
* ``path``: ``method="path"`` (:func:`lacore.shapes.mixing.path_inbetweens`, the add-on's default on large
  meshes): a reduced model of the path, polished by the full projection where its error indicator stays above the
  tolerance (``message`` says which; ``indicator`` per frame; ``success`` is the call's, one flag).

Per row: seconds per frame and in total, iterations and numeric factorizations
per frame, energy excess over ``gauss_newton`` per frame, the largest RMS vertex
distance to ``gauss_newton`` (rigid fit) over the bounding-box diagonal, peak
memory (``maxrss_mb``: this process; ``worker_maxrss_mb``: the largest worker
process so far).  ``single`` solves ``t = 0.5`` alone from the least-squares start
with ``newton="never"`` and ``"auto"`` (on the bar Gauss-Newton alone stalls).

Prints ONE JSON object.  usage: python benchmarks/bench_continuation.py [--quick] [--cases bar50k body50k]
[--rows gauss_newton fast ...]
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
from bench_multires import cases as multires_cases  # noqa: E402

ROWS = ("gauss_newton", "fast", "cli_default", "path", "fast_no_extension", "fast_geometric_ordering",
        "fast_2_workers", "one_step", "fast_before", "gauss_newton_before")


def cases(quick):
    """The cases of ``bench_multires.py`` and ``bend50k`` (``bend_quick``): the bar straight -> bent 90 degrees."""
    from bench_interpolation import box_bar, simple_deform_bend

    from lacore.geometry.topology import MeshTopology

    out = multires_cases(quick)
    nl, nw = (40, 10) if quick else (210, 52)
    B, FB = box_bar(nl, nw)
    out["bend_quick" if quick else "bend50k"] = (np.stack([B, simple_deform_bend(B, np.pi / 2)]),
                                                 MeshTopology.from_faces(FB, n_vertices=len(B)))
    return out


def row_options(name):
    """Keywords of :func:`lacore.shapes.interpolation.interpolate` for a row (Fast: lacore's preset)."""
    from dataclasses import replace

    from lacore.reconstruction import GaussNewtonOptions, HybridOptions
    from lacore.reconstruction.settings import FAST

    if name == "gauss_newton":
        return {"method": "gn"}
    if name == "gauss_newton_before":
        return {"method": "gn", "warm_start": "nearest", "newton": "never"}
    if name == "fast":
        return FAST.keywords()
    if name == "fast_no_extension":
        return {**FAST.keywords(), "hybrid": replace(FAST.hybrid, extend_smoothing=False)}
    if name == "fast_2_workers":
        return {**row_options("fast"), "workers": 2}
    if name == "fast_geometric_ordering":
        return {**row_options("fast"), "ordering": "geometric"}
    if name == "fast_before":
        return {"method": "hybrid", "hybrid": HybridOptions(start="lsq", smoothing_iterations=2),
                "options": GaussNewtonOptions(reuse_factorization=True, newton="never"), "warm_start": "nearest"}
    if name == "path":
        return {"method": "path"}
    if name == "one_step":
        return {"method": "hybrid", "hybrid": HybridOptions(start="given", smoothing_iterations=1)}
    raise ValueError(name)


class _CliRun:
    """What ``lacore interpolate --json`` reports, shaped like the fields of an InterpolationResult used here."""

    def __init__(self, summary, vertices):
        frames = summary["outputs"]
        self.seconds = np.array([o["seconds"] for o in frames])
        self.iterations = np.array([o["iterations"] for o in frames])
        self.energy = np.array([o["energy"] for o in frames])
        self.success_per_frame = [o["success"] for o in frames]
        self.vertices = vertices
        self.reconstructions = []


def run_cli(S, topo, ts):
    """``lacore interpolate A.ply B.ply --t ... --json`` with the default options, in this process."""
    import contextlib
    import io
    import tempfile

    from lacore.cli import main
    from lacore.io.meshes import load_mesh, save_mesh

    with tempfile.TemporaryDirectory() as d:
        paths = [os.path.join(d, f"key{k}.ply") for k in range(len(S))]
        for p, X in zip(paths, S, strict=True):
            save_mesh(p, X, topo.faces)
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            code = main(["interpolate", *paths, "--t", *[repr(float(t)) for t in ts], "-o",
                         os.path.join(d, "frame"), "--json", "--allow-failure"])
        summary = json.loads(out.getvalue())
        if code != 0:
            raise RuntimeError(f"lacore interpolate exited {code}")
        vertices = np.array([load_mesh(o["file"])[0] for o in summary["outputs"]])
    return _CliRun(summary, vertices)


def maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_case(S, topo, rows, single=True):
    from lacore.shapes.interpolation import interpolate
    from lacore.geometry.lengths_angles import lengths_and_angles
    from lacore.reconstruction import get_context, reconstruct
    from lacore.geometry.rigid import rigid_rms

    ts = np.arange(1, 11) / 11.0
    diag = float(np.linalg.norm(S[0].max(0) - S[0].min(0)))
    out = {"vertices": int(topo.n_vertices), "faces": int(topo.n_faces), "t": ts.tolist(), "rows": {}}
    ctx = get_context(topo, S[0])
    t0 = time.perf_counter()
    _ = ctx.solver  # symbolic analysis once, outside the rows
    out["symbolic_seconds"] = time.perf_counter() - t0
    out["ordering"] = ctx.ordering
    if "fast_geometric_ordering" in rows:  # its own context (settings differ), also set up outside the rows
        _ = get_context(topo, S[0], ordering="geometric").solver
    ref = None
    for name in rows:
        t0 = time.perf_counter()
        if name == "cli_default":
            r = run_cli(S, topo, ts)
        else:
            r = interpolate(list(S), topo, ts, **row_options(name))
        total = time.perf_counter() - t0
        if ref is None:
            ref = r
        row = {"total_seconds": total, "seconds": r.seconds.tolist(), "iterations": r.iterations.tolist(),
               "energy": r.energy.tolist(),
               "success": [bool(x) for x in getattr(r, "success_per_frame", [x.success for x in r.reconstructions])]}
        if name == "path":
            row.update(success=bool(r.success), message=r.message, indicator=r.indicator.tolist())
        if r.reconstructions:
            row.update(factorizations=[x.factorizations for x in r.reconstructions],
                       newton_steps=[x.newton_steps for x in r.reconstructions])
        if ref is not r:
            excess = r.energy / ref.energy - 1.0
            row["energy_excess"] = excess.tolist()
            row["max_energy_excess"] = float(excess.max())
            row["max_rms_over_diagonal"] = max(rigid_rms(a, b) / diag for a, b in zip(r.vertices, ref.vertices,
                                                                                    strict=True))
        row["maxrss_mb"] = maxrss_mb()
        row["worker_maxrss_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0  # largest so far
        out["rows"][name] = row
        print(f"{name}: {total:.1f} s", file=sys.stderr, flush=True)
    if not single:
        return out
    z = 0.5 * (lengths_and_angles(S[0], topo) + lengths_and_angles(S[1], topo))
    single = {}
    for mode in ("never", "auto"):
        t0 = time.perf_counter()
        r = reconstruct(z, topo, S[0], context=ctx, method="hybrid", hybrid_start="lsq", smoothing_iterations=200,
                        newton=mode)
        single[mode] = {"seconds": time.perf_counter() - t0, "iterations": r.iterations,
                        "factorizations": r.factorizations, "newton_steps": r.newton_steps, "energy": r.energy,
                        "success": bool(r.success), "message": r.message}
    out["single_t05_from_least_squares"] = single
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small meshes (bar 1.8k, body 13.4k) instead of ~50k")
    parser.add_argument("--cases", nargs="+", help="case names (default: all)")
    parser.add_argument("--rows", nargs="+", choices=ROWS, default=list(ROWS),
                        help="rows to run; the first is the reference of the others (default: all)")
    parser.add_argument("--no-single", action="store_true", help="skip the single t = 0.5 solves")
    args = parser.parse_args(argv)
    from lacore.linalg.sparse_cholesky import default_backend

    result = {"benchmark": "continuation", "machine": machine_info(), "backend": default_backend(), "cases": {}}
    for name, (S, topo) in cases(args.quick).items():
        if args.cases and name not in args.cases:
            continue
        result["cases"][name] = run_case(S, topo, args.rows, single=not args.no_single)
    result["machine"]["load_average_after"] = list(os.getloadavg())
    json.dump(result, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
