#!/usr/bin/env python3
"""Benchmark: in-betweens by linear interpolation in lengths and angles plus projection (thesis 4.2).

Cases (``W_q``, weights (3.20) from the first shape, ``eta = 1e-3``, Gauss-Newton
projection, every frame warm-started from its nearest computed neighbour, all
frames sharing one symbolic factorization):

* ``finger``: the 2046-vertex finger0 -> finger1 pair of the shared data, 10 in-betweens
  ``t = 1/11 .. 10/11``;
* ``bar50k``: a generated closed box bar ``4 x 1 x 1`` with ~49k vertices
  (:func:`lacore.samples.simple_deform.box_bar`, ``n_length=210, n_width=52``), straight -> bent by 90 degrees
  with Blender's Simple Deform 'BEND' formula (:func:`lacore.samples.simple_deform.simple_deform_bend`), 10 in-betweens.

Deterministic (no random numbers).  Every case reports per-frame seconds,
iterations and energies, the total, the same run started from the nearest
known frame instead of the secant extrapolation (``nearest_start``), and
without warm starts (``--no-cold`` skips it).  Timings on a shared machine vary with its load
(reported before and after).

Prints ONE JSON object.  usage: python benchmarks/bench_interpolation.py [--quick] [--no-cold]
"""

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
if REPO not in sys.path:  # lacore importable without installing it
    sys.path.insert(0, REPO)

from bench_common import machine_info, shared_meshes_dir  # noqa: E402

from lacore.samples.simple_deform import box_bar, simple_deform_bend  # noqa: E402

__all__ = ["main"]


# --------------------------------------------------------------------------- benchmark


def cases(quick):
    from lacore.io.meshes import load_mesh
    from lacore.geometry.topology import MeshTopology

    d = shared_meshes_dir()
    X0, F = load_mesh(os.path.join(d, "finger", "finger0.ply"))
    X1, _ = load_mesh(os.path.join(d, "finger", "finger1.ply"))
    out = {"finger": (MeshTopology.from_faces(F, n_vertices=len(X0)), X0, X1)}
    nl, nw = (40, 10) if quick else (210, 52)
    B, FB = box_bar(nl, nw)
    out["bar50k" if not quick else "bar_quick"] = (MeshTopology.from_faces(FB, n_vertices=len(B)), B,
                                                   simple_deform_bend(B, np.pi / 2))
    return out


def run_case(topo, X0, X1, factors, warm_start):
    from lacore.shapes.interpolation import interpolate

    t0 = time.perf_counter()
    res = interpolate([X0, X1], topo, factors, method="gn", warm_start=warm_start)  # not the default, Fast
    total = time.perf_counter() - t0
    return {
        "total_seconds": total,
        "projection_seconds": float(res.seconds.sum()),
        "total_iterations": int(res.total_iterations),
        "success": bool(res.success),
        "frames": [{"t": float(t), "seconds": float(s), "iterations": int(i), "energy": float(e),
                    "max_length_error": float(le), "max_angle_error": float(ae)}
                   for t, s, i, e, le, ae in zip(res.times, res.seconds, res.iterations, res.energy,
                                                 res.max_length_error, res.max_angle_error, strict=True)],
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small bar (~4k vertices) instead of ~50k")
    parser.add_argument("--no-cold", action="store_true", help="skip the runs without warm starts")
    args = parser.parse_args(argv)
    from lacore.linalg.sparse_cholesky import default_backend

    factors = np.arange(1, 11) / 11.0
    result = {"benchmark": "interpolation", "machine": machine_info(), "backend": default_backend(),
              "factors": factors.tolist(), "cases": {}}
    for name, (topo, X0, X1) in cases(args.quick).items():
        entry = {"vertices": int(topo.n_vertices), "faces": int(topo.n_faces)}
        entry["warm_start"] = run_case(topo, X0, X1, factors, True)   # "secant": continuation along t
        entry["nearest_start"] = run_case(topo, X0, X1, factors, "nearest")
        if not args.no_cold:
            entry["cold_start"] = run_case(topo, X0, X1, factors, False)
        result["cases"][name] = entry
    result["machine"]["load_average_after"] = list(os.getloadavg())
    json.dump(result, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
