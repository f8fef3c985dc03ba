#!/usr/bin/env python3
"""Benchmark: building a shape model of the human body (thesis 4.3, Table 4.1).

Training data: ``N`` poses of the CC0 body of ``shared/data/human`` by
linear-blend skinning (:mod:`lacore.samples.human`, seed 1, the default
training spread), the rest pose as reference (weights (3.20), ``eta = 0.005``).
For the full 13,380-vertex body (and the coarse body if
``tests/data/human_coarse.npz`` exists) and both tangent variants, every stage
of :meth:`lacore.models.shape_model.ShapeModel.fit` is timed (encode, mean (4.16),
tangent decomposition = Jacobian + Cholesky of ``D I (D I)^T``, tangent solves,
Gram matrix, eigendecomposition), twice: ``first`` (fresh process state: GN and
Cholesky symbolic analyses) and ``repeat`` (same topology, cached analyses).
Also: synthesis of a 5-frame mode sweep, and (``localized``) the varimax
rotation of the modes.

Timings on a shared machine vary with its load (reported before and after).
Prints ONE JSON object.  usage: python benchmarks/bench_shape_model.py [--samples N] [--modes J] [--quick]
"""

import argparse
import json
import os
import sys
import time
from dataclasses import replace

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_common import machine_info  # noqa: E402

from lacore import MeshTopology  # noqa: E402
from lacore.samples.human import coarse_body_file, load_human  # noqa: E402
from lacore.models.settings import MODEL_OPTIONS  # noqa: E402
from lacore.models.shape_model import ShapeModel  # noqa: E402

STAGES = ("encode", "mean", "tangent_decomposition", "tangent_solves", "gram", "eigen", "total")


def fit_case(body, n_samples, n_modes, tangent, sweep=True):
    topo = MeshTopology.from_faces(body.faces, n_vertices=body.n_vertices)
    poses, _ = body.random_poses(n_samples, seed=1)
    runs = {}
    model = None
    for run in ("first", "repeat"):
        t, c = time.perf_counter(), time.process_time()
        model = ShapeModel.fit(poses, topo, reference_vertices=body.vertices, n_modes=n_modes, tangent=tangent)
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        runs[run] = {k: round(model.timings[k], 4) for k in STAGES}
        runs[run]["wall"] = round(wall, 4)
        runs[run]["process_cpu"] = round(cpu, 4)  # all threads of this process; less affected by other jobs
        runs[run]["mean_iterations"] = int(model.mean_result.iterations)
    out = {"vertices": body.n_vertices, "edges": topo.n_edges, "samples": n_samples, "modes": n_modes,
           "tangent": tangent, "runs": runs,
           "explained_variance": [round(float(r), 5) for r in model.explained_variance_ratio],
           "explained_variance_total": round(float(model.explained_variance_ratio.sum()), 5)}
    out["mean_energy"] = float(model.mean_result.energy)
    if tangent == "projected":
        # the mean by Gauss-Newton with geodesic acceleration (lacore's default elsewhere) for comparison
        from lacore.shapes.projection import project

        t = time.perf_counter()
        _, res = project(model.linear_mean_z, topo, body.vertices, settings=model.settings,
                         options=replace(MODEL_OPTIONS, geodesic_acceleration=True))
        out["mean_with_geodesic_acceleration"] = {"energy": float(res.energy), "iterations": int(res.iterations),
                                                  "seconds": round(time.perf_counter() - t, 4)}
        if body.n_vertices < 5000:  # +-2 standard deviations of modes 0 and 1, both ways (coarse body only)
            A = np.zeros((4, n_modes))
            A[[0, 1], 0] = np.array([-2, 2]) * model.standard_deviations[0]
            A[[2, 3], 1] = np.array([-2, 2]) * model.standard_deviations[1]
            for acc in (False, True):
                _, rs = model.synthesize(A, return_results=True,
                                         options=replace(MODEL_OPTIONS, geodesic_acceleration=acc))
                out[f"synthesis_2sd_energies_acceleration_{acc}"] = [round(float(r.energy), 4) for r in rs]
        P = model.tangent_projector()
        out["max_integrability_residual_of_modes"] = float(P.residual(model.modes).max())
        out["projection_refinements"] = int(P.last_refinements)
    # generalization: share of the g-norm^2 of tangent vectors outside the model's span, training vs a held-out
    # take (60 frames, seed 5: smooth motion partly outside the training range, a walk of the whole body)
    take = body.take(60, seed=5)[0]

    def outside(X):
        v = model.tangent_vectors(X)
        c = model.coefficients(X)
        r = v - c @ model.modes
        return float(np.mean(model.metric_dot(r, r) / model.metric_dot(v, v)))

    out["residual_share_training"] = round(outside(poses), 4)
    out["residual_share_heldout_take"] = round(outside(take), 4)
    if sweep:
        t = time.perf_counter()
        _, results = model.mode_sweep(0, (-2, 2), 5, return_results=True)[0]
        out["sweep_5_frames_seconds"] = round(time.perf_counter() - t, 4)
        out["sweep_iterations"] = [int(r.iterations) for r in results]
    if hasattr(model, "localized"):
        t = time.perf_counter()
        model.localized()
        out["localize_seconds"] = round(time.perf_counter() - t, 4)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=30)
    ap.add_argument("--modes", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="projected tangent on the full body only, no sweep")
    args = ap.parse_args()
    load_before = os.getloadavg()
    t = time.perf_counter()
    body = load_human()
    t_load = time.perf_counter() - t
    t = time.perf_counter()
    body.random_poses(args.samples, seed=1)
    t_pose = time.perf_counter() - t
    cases = {}
    tangents = ("projected",) if args.quick else ("projected", "ambient")
    for tangent in tangents:
        cases[f"full_{tangent}"] = fit_case(body, args.samples, args.modes, tangent, sweep=not args.quick)
    if coarse_body_file().is_file() and not args.quick:
        coarse = load_human(coarse=True)
        for tangent in tangents:
            cases[f"coarse_{tangent}"] = fit_case(coarse, args.samples, args.modes, tangent)
    result = {"benchmark": "shape_model", "load_human_seconds": round(t_load, 4),
              "skin_training_poses_seconds": round(t_pose, 4), "cases": cases,
              "thesis_table_4_1": {"dyna_6.9k_N29": {"mean": 3.6, "tangent_decomposition": 860, "tangent_solves": 8.5,
                                                     "gram": 0.0058, "eigen": 0.0087},
                                   "dyna_1.4k_N29": {"mean": 1.3, "tangent_decomposition": 9.2, "tangent_solves": 0.7,
                                                     "gram": 0.0018, "eigen": 0.0025}},
              "machine": machine_info(load_average_before=[round(x, 2) for x in load_before])}
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
