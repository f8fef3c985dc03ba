#!/usr/bin/env python3
"""Benchmark: in-betweens by linear interpolation in lengths and angles plus projection (thesis 4.2).

Cases (``W_q``, weights (3.20) from the first shape, ``eta = 1e-3``, Gauss-Newton
projection, every frame warm-started from its nearest computed neighbour, all
frames sharing one symbolic factorization):

* ``finger``: the 2046-vertex finger0 -> finger1 pair of the shared data, 10 in-betweens
  ``t = 1/11 .. 10/11``;
* ``bar50k``: a generated closed box bar ``4 x 1 x 1`` with ~49k vertices
  (:func:`box_bar`, ``n_length=210, n_width=52``), straight -> bent by 90 degrees
  with Blender's Simple Deform 'BEND' formula (:func:`simple_deform_bend`), 10 in-betweens.

Deterministic (no random numbers).  Every case reports per-frame seconds,
iterations and energies, the total, and the same run without warm starts
(``--no-cold`` skips it).  Timings on a shared machine vary with its load
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

__all__ = ["box_bar", "simple_deform_bend", "main"]


# --------------------------------------------------------------------------- generated meshes
def box_bar(n_length=16, n_width=4, length=4.0, width=1.0):
    """Closed, outward-oriented triangulated surface of the box ``[0, length] x [-w/2, w/2]^2``.

    Every side is a regular grid (``n_length`` cells along x, ``n_width`` across),
    each grid square split into two triangles along the same diagonal; the sides
    share their boundary vertices (sphere topology, ``V - E + F = 2``).  The
    vertex count is ``(n_l + 1)(n_w + 1)^2 - (n_l - 1)(n_w - 1)^2``.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    """
    nx, nw = int(n_length), int(n_width)
    if nx < 1 or nw < 1:
        raise ValueError("n_length and n_width must be >= 1")
    n = (nx, nw, nw)
    sides = []
    # (fixed axis, u axis, v axis) with u x v the outward normal of the '+' side
    for axis, u, v in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        for value, (a, b) in ((n[axis], (u, v)), (0, (v, u))):
            I, J = np.meshgrid(np.arange(n[a] + 1), np.arange(n[b] + 1), indexing="ij")
            lattice = np.zeros(I.shape + (3,), np.int64)
            lattice[..., axis] = value
            lattice[..., a] = I
            lattice[..., b] = J
            p00, p10, p11, p01 = lattice[:-1, :-1], lattice[1:, :-1], lattice[1:, 1:], lattice[:-1, 1:]
            sides.append(np.stack([p00, p10, p11], -2).reshape(-1, 3, 3))
            sides.append(np.stack([p00, p11, p01], -2).reshape(-1, 3, 3))
    corners = np.concatenate(sides).reshape(-1, 3)  # integer lattice points of all triangle corners
    keys, inverse = np.unique(corners, axis=0, return_inverse=True)
    faces = inverse.reshape(-1, 3).astype(np.int64)
    vertices = keys * np.array([length / nx, width / nw, width / nw]) - np.array([0.0, width / 2, width / 2])
    return vertices, faces


def simple_deform_bend(vertices, angle):
    """Blender's Simple Deform modifier, mode 'BEND', deform axis Z, applied analytically.

    Blender (``MOD_simpledeform.cc``, ``simpleDeform_bend``) bends the x axis
    into a circle about an axis parallel to z through ``(0, 1/k)``::

        k = angle / (x_max - x_min)           (full limits [0, 1])
        theta = k x
        x' = -(y - 1/k) sin(theta)
        y' =  (y - 1/k) cos(theta) + 1/k
        z' = z

    Points at ``x = 0`` stay fixed; the fibre ``y = 0`` keeps its length and a
    fibre at height ``y`` is scaled by ``1 - k y`` (pure bending of a beam).

    Parameters
    ----------
    vertices : (V, 3) array_like
        In object coordinates (origin at the fixed end).
    angle : float
        Total bend angle in radians (non-zero).
    """
    X = np.asarray(vertices, float)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    k = angle / (x.max() - x.min())
    theta = k * x
    r = 1.0 / k
    return np.stack([-(y - r) * np.sin(theta), (y - r) * np.cos(theta) + r, z], axis=1)


# --------------------------------------------------------------------------- benchmark


def cases(quick):
    from lacore.mesh_io import load_mesh
    from lacore.topology import MeshTopology

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
    from lacore.interpolation import interpolate

    t0 = time.perf_counter()
    res = interpolate([X0, X1], topo, factors, warm_start=warm_start)
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
    from lacore.sparse_cholesky import default_backend

    factors = np.arange(1, 11) / 11.0
    result = {"benchmark": "interpolation", "machine": machine_info(), "backend": default_backend(),
              "factors": factors.tolist(), "cases": {}}
    for name, (topo, X0, X1) in cases(args.quick).items():
        entry = {"vertices": int(topo.n_vertices), "faces": int(topo.n_faces)}
        entry["warm_start"] = run_case(topo, X0, X1, factors, True)
        if not args.no_cold:
            entry["cold_start"] = run_case(topo, X0, X1, factors, False)
        result["cases"][name] = entry
    result["machine"]["load_average_after"] = list(os.getloadavg())
    json.dump(result, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
