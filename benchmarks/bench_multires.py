#!/usr/bin/env python3
"""Benchmark: multiresolution in-betweens of ~50k-vertex meshes against full Gauss-Newton (thesis 2.3).

Cases (``W_q``, weights (3.20) from the first key, ``eta = 1e-3``; in-between
``z(t) = (1 - t) z_0 + t z_1``):

* ``bar50k``: the closed box bar of ``bench_interpolation.box_bar(210, 52)``
  (49,828 vertices), key 0 bent by 90 degrees (Blender's Simple Deform BEND
  formula), key 1 twisted by 90 degrees about its axis;
* ``body50k``: the closed MakeHuman body (``shared/data/human/base.obj``, group
  ``body``, 13,380 vertices, quads split into triangles) midpoint-subdivided
  once (53,510 vertices), key 0 bent forward by 60 degrees as a beam along
  its height, key 1 twisted by 60 degrees about the vertical axis.

For each case: set-up (coarsening to V / 10 with both keys, prolongation,
contexts), then in-betweens at ``t = 0.25, 0.5, 0.75`` by
:class:`lacore.multiresolution.MultiresolutionReconstruction` (default: coarse
Gauss-Newton from the nearer key, prolongation, 3 exact fine Gauss-Newton
iterations), the same at
``t = 0.5`` with the rotated-reference PCG fine solver, with the two-level
PCG fine solver (5 and 10 Gauss-Newton steps of at most 30 PCG iterations,
relative residual 1e-2), and with the fine
Gauss-Newton run to convergence (``ftol = 1e-9``), the add-on's previous "Fast" method
on the full mesh (least-squares start + 2 Gauss-Newton steps reusing
factorizations, ``t = 0.25, 0.5, 0.75`` in order), and full Gauss-Newton
(from key 0) at ``t = 0.5``: energies, relative energy excess, RMS vertex
distance to full Gauss-Newton over the bounding-box diagonal (after a rigid
fit, and as returned), peak memory (``ru_maxrss``) after the multiresolution
and Fast runs and after full Gauss-Newton.  ``fill`` measures the fine Cholesky factor
(nonzeros, numeric time) of an 11k-vertex bar under AMD, the geometric nested
dissection lacore uses, and reverse Cuthill-McKee.

Prints ONE JSON object.  usage: python benchmarks/bench_multires.py [--quick]
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

from bench_common import machine_info, shared_meshes_dir  # noqa: E402
from bench_interpolation import box_bar, simple_deform_bend  # noqa: E402

HUMAN = os.path.join(os.path.dirname(shared_meshes_dir()), "human", "base.obj")  # LACORE_SHARED_DATA applies


def twist(X, angle, axis=0):
    """Rotate every point about the coordinate ``axis`` by ``angle * s``, ``s`` in [0, 1] along that axis."""
    X = np.asarray(X, float)
    h = X[:, axis]
    s = (h - h.min()) / (h.max() - h.min())
    a = angle * s
    c, si = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    out = X.copy()
    out[:, i] = c * X[:, i] - si * X[:, j]
    out[:, j] = si * X[:, i] + c * X[:, j]
    return out


def load_body(path=HUMAN):
    """Vertices (13380, 3) and triangles of group ``body`` of the MakeHuman base mesh (quads split 0-1-2, 0-2-3)."""
    verts, faces, group = [], [], None
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("g "):
                group = line.split()[1]
            elif line.startswith("f ") and group == "body":
                idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
                faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    F = np.array(faces, np.int64)
    return np.array(verts)[: F.max() + 1], F


def midpoint_subdivide(X, F):
    """Split every triangle into four at its edge midpoints (vertices: V + E)."""
    from lacore.geometry.topology import MeshTopology

    topo = MeshTopology.from_faces(F, n_vertices=len(X))
    V = len(X)
    mid = 0.5 * (X[topo.edges[:, 0]] + X[topo.edges[:, 1]])
    m = V + topo.face_edges  # m[:, i]: midpoint of the edge opposite corner i
    a, b, c = F.T
    m0, m1, m2 = m.T
    faces = np.concatenate([np.stack([a, m2, m1], 1), np.stack([b, m0, m2], 1), np.stack([c, m1, m0], 1),
                            np.stack([m0, m1, m2], 1)])
    return np.concatenate([X, mid]), faces


def beam_bend(X, angle, axis=1, towards=2):
    """Bend like Blender's Simple Deform along coordinate ``axis``, curving towards coordinate ``towards``."""
    perm = [axis, towards] + [k for k in range(3) if k not in (axis, towards)]
    Y = X[:, perm] - np.array([X[:, axis].min(), 0.0, 0.0])
    B = simple_deform_bend(Y, angle)
    out = np.empty_like(X)
    out[:, perm] = B + np.array([X[:, axis].min(), 0.0, 0.0])
    return out


def cases(quick):
    from lacore.geometry.topology import MeshTopology

    nl, nw = (40, 10) if quick else (210, 52)
    B, FB = box_bar(nl, nw)
    bar = np.stack([simple_deform_bend(B, np.pi / 2), twist(B, np.pi / 2, axis=0)])
    Xb, Fb = load_body()
    if not quick:
        Xb, Fb = midpoint_subdivide(Xb, Fb)
    body = np.stack([beam_bend(Xb, np.pi / 3), twist(Xb, np.pi / 3, axis=1)])
    return {("bar_quick" if quick else "bar50k"): (bar, MeshTopology.from_faces(FB, n_vertices=len(B))),
            ("body_quick" if quick else "body50k"): (body, MeshTopology.from_faces(Fb, n_vertices=len(Xb)))}


def maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_case(S, topo):
    from lacore.multiresolution import MultiresolutionReconstruction
    from lacore.reconstruction import GaussNewtonOptions, HybridOptions, reconstruct
    from lacore.geometry.rigid import rigid_rms

    diag = float(np.linalg.norm(S[0].max(0) - S[0].min(0)))
    out = {"vertices": int(topo.n_vertices), "faces": int(topo.n_faces)}
    t0 = time.perf_counter()
    mr = MultiresolutionReconstruction(S, topo)
    out["setup_seconds"] = time.perf_counter() - t0
    out["coarsening_seconds"] = mr.coarsening.seconds
    out["coarse_vertices"] = int(mr.coarsening.n_vertices)
    frames = []
    for t in (0.25, 0.5, 0.75):
        r = mr.reconstruct([1 - t, t])  # coarse Gauss-Newton from the nearer key
        frames.append({"t": t, "seconds": r.timings["total"], "timings": r.timings, "energy": r.energy,
                       "prolonged_energy": r.prolonged_energy, "coarse_iterations": r.coarse_iterations,
                       "fine_iterations": r.iterations, "fine_factorizations": r.factorizations,
                       "vertices": r.vertices})
    ref = mr.reconstruct([0.5, 0.5], fine_solver="reference")
    two = {}
    for its in (5, 10):  # two-level PCG (coarse Galerkin + block Jacobi): no fine factorization
        two[its] = mr.reconstruct([0.5, 0.5], fine_solver="two_level", fine_iterations=its, pcg_rtol=1e-2,
                                  pcg_maxiter=30, ftol=1e-9)
    conv = mr.reconstruct([0.5, 0.5], fine_iterations=200, ftol=1e-9)  # fine Gauss-Newton to convergence
    # the add-on's previous "Fast" (before the continuation of bench_continuation.py) on the full mesh,
    # the three in-betweens in order as the add-on computes them (each may reuse the last one's factorization)
    fast = []
    for t in (0.25, 0.5, 0.75):
        t0 = time.perf_counter()
        r = reconstruct(mr.fine_target([1 - t, t]), topo, S[0], method="hybrid", context=mr.fine_context,
                        hybrid=HybridOptions(start="lsq", smoothing_iterations=2),
                        options=GaussNewtonOptions(reuse_factorization=True, newton="never"))
        fast.append((t, time.perf_counter() - t0, r))
    out["maxrss_mb_after_multires_and_fast"] = maxrss_mb()
    z = mr.fine_target([0.5, 0.5])
    t0 = time.perf_counter()
    full = reconstruct(z, topo, S[0], context=mr.fine_context, max_iterations=200)
    full_seconds = time.perf_counter() - t0
    out["maxrss_mb_after_full_gn"] = maxrss_mb()
    out["full_gn"] = {"t": 0.5, "seconds": full_seconds, "iterations": full.iterations,
                      "factorizations": full.factorizations, "energy": full.energy, "message": full.message}

    def compare(X, energy):
        return {"energy_excess": energy / full.energy - 1.0,
                "rms_rigid_over_diagonal": rigid_rms(X, full.vertices) / diag,
                "rms_over_diagonal": float(np.sqrt(np.mean(np.sum((X - full.vertices) ** 2, 1)))) / diag}

    for f in frames:
        X = f.pop("vertices")
        if f["t"] == 0.5:
            f.update(compare(X, f["energy"]))
    out["multires"] = frames
    out["multires_mean_seconds"] = float(np.mean([f["seconds"] for f in frames]))
    out["multires_converged"] = {"seconds": conv.timings["total"], "timings": conv.timings, "energy": conv.energy,
                                 "fine_iterations": conv.iterations, "fine_factorizations": conv.factorizations,
                                 "message": conv.message, **compare(conv.vertices, conv.energy)}
    out["multires_reference_pcg"] = {"seconds": ref.timings["total"], "timings": ref.timings,
                                     "energy": ref.energy, "pcg_iterations": ref.pcg_iterations,
                                     **compare(ref.vertices, ref.energy)}
    out["fast"] = [{"t": t, "seconds": sec, "energy": r.energy, "factorizations": r.factorizations,
                    "pcg_iterations": r.pcg_iterations, "timings": r.timings,
                    **(compare(r.vertices, r.energy) if t == 0.5 else {})} for t, sec, r in fast]
    out["multires_two_level"] = [{"fine_iterations": r.iterations, "seconds": r.timings["total"],
                                  "timings": r.timings, "energy": r.energy, "pcg_iterations": r.pcg_iterations,
                                  "fine_factorizations": r.factorizations, **compare(r.vertices, r.energy)}
                                 for r in two.values()]
    return out


def fill(quick):
    """Nonzeros of the fine Cholesky factor and numeric factorization time under three orderings."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    from lacore.geometry.lengths_angles import lengths_and_angles
    from lacore.reconstruction import get_context
    from lacore.reconstruction.assembly import coupled_vertex_graph
    from lacore.linalg.sparse_cholesky import SparseCholesky, nested_dissection
    from lacore.geometry.topology import MeshTopology

    nl, nw = (40, 10) if quick else (100, 25)
    B, F = box_bar(nl, nw)
    topo = MeshTopology.from_faces(F, n_vertices=len(B))
    ctx = get_context(topo, B)
    pat = ctx.pattern
    _, _, M = ctx.objective(lengths_and_angles(simple_deform_bend(B, np.pi / 2), topo)).linearize(
        ctx.to_canonical(B))
    vals = M()
    ctx.eliminate_fixed(vals)
    G = coupled_vertex_graph(pat, len(B))
    nd = nested_dissection(G, B)
    rcm = reverse_cuthill_mckee(G, symmetric_mode=True)
    out = {"vertices": len(B), "unknowns": int(pat["n"]), "matrix_nnz_lower": int(pat["nnz"])}
    for name, order in (("amd", None), ("nested_dissection", nd), ("rcm", rcm)):
        ordering = None if order is None else (3 * np.asarray(order)[:, None] + np.arange(3)).ravel()
        t0 = time.perf_counter()
        chol = SparseCholesky(pat["matrix"], ordering=ordering)
        t1 = time.perf_counter()
        chol.factorize(vals)
        t2 = time.perf_counter()
        chol.solve(np.ones(pat["n"]))
        t3 = time.perf_counter()
        out[name] = {"factor_nnz": int(chol.factor_column_counts().sum()), "symbolic_seconds": t1 - t0,
                     "numeric_seconds": t2 - t1, "solve_seconds": t3 - t2,
                     "note": "CHOLMOD keeps the given ordering or AMD, whichever fills less"}
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small meshes (bar 1.8k, body 13.4k) instead of ~50k")
    args = parser.parse_args(argv)
    from lacore.linalg.sparse_cholesky import default_backend

    result = {"benchmark": "multires", "machine": machine_info(), "backend": default_backend(), "cases": {}}
    result["fill"] = fill(args.quick)
    for name, (S, topo) in cases(args.quick).items():
        result["cases"][name] = run_case(S, topo)
    result["machine"]["load_average_after"] = list(os.getloadavg())
    json.dump(result, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
