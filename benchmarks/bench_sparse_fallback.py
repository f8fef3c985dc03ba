#!/usr/bin/env python3
"""Sparse factorization backends for platforms without cvxopt wheels (macOS on Python 3.13).

cvxopt (CHOLMOD) has no cp313 wheels for macOS, so Blender 5.1/5.2 on a Mac runs lacore's
SciPy backend (SuperLU, symmetric mode).  The candidate with cp313 macOS wheels is ``qdldl``
(LDL^T with AMD ordering, OSQP's factorization; not a dependency).  This measures, on the first
Gauss-Newton matrix of the shared finger (2046 vertices) and a 5.3k-vertex deformed sphere,
numeric factorization + solve time per backend (min over repeats) and the solution's relative
residual.  qdldl is measured only if importable (``pip install qdldl``).

Prints ONE JSON object.
"""

import json
import os
import sys
import time

import numpy as np
import scipy.sparse as sp

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
from bench_common import machine_info, shared_meshes_dir  # noqa: E402
from meshes import deformed_sphere  # noqa: E402

from lacore.geometry.lengths_angles import lengths_and_angles  # noqa: E402
from lacore.io.meshes import load_mesh  # noqa: E402
from lacore.reconstruction import ReconstructionContext  # noqa: E402
from lacore.linalg.sparse_cholesky import SparseCholesky, available_backends  # noqa: E402
from lacore.geometry.topology import MeshTopology  # noqa: E402


def min_time(fn, repeat):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def gn_system(topo, X, z):
    """The first Gauss-Newton matrix (lower triangle, fixed DOFs eliminated) and gradient."""
    ctx = ReconstructionContext(topo, X)
    obj = ctx.objective(z)
    _, grad, matrix = obj.linearize(ctx.to_canonical(X))
    H = matrix()
    ctx.eliminate_fixed(H)
    grad[ctx.fixed_dofs] = 0.0
    lower = sp.csc_matrix((H, ctx.pattern["matrix"].indices, ctx.pattern["matrix"].indptr),
                          shape=ctx.pattern["matrix"].shape)
    full = (lower + sp.tril(lower, -1).T).tocsc()
    return ctx.pattern["matrix"], H, full, grad


def case(name, topo, X, z, repeat):
    pattern, H, full, g = gn_system(topo, X, z)
    out = {"unknowns": int(full.shape[0]), "nnz": int(full.nnz)}
    for backend in available_backends():
        chol = SparseCholesky(pattern, backend=backend)
        t_f = min_time(lambda c=chol: c.factorize(H), repeat)
        t_s = min_time(lambda c=chol: c.solve(g), repeat)
        x = chol.solve(g)
        out[backend] = {"factorize_ms": 1e3 * t_f, "solve_ms": 1e3 * t_s,
                        "relative_residual": float(np.linalg.norm(full @ x - g) / np.linalg.norm(g))}
    try:
        import qdldl
    except ImportError:
        out["qdldl"] = "not installed"
        return out
    solver = qdldl.Solver(full)  # symbolic + numeric (AMD ordering inside)
    t_f = min_time(lambda: solver.update(full), repeat)
    t_s = min_time(lambda: solver.solve(g), repeat)
    x = solver.solve(g)
    out["qdldl"] = {"version": getattr(qdldl, "__version__", "?"), "factorize_ms": 1e3 * t_f, "solve_ms": 1e3 * t_s,
                    "relative_residual": float(np.linalg.norm(full @ x - g) / np.linalg.norm(g))}
    return out


def main():
    repeat = 5
    result = {"machine": machine_info(), "repeat": repeat, "cases": {}}
    X0, F = load_mesh(os.path.join(shared_meshes_dir(), "finger", "finger0.ply"))
    X1, _ = load_mesh(os.path.join(shared_meshes_dir(), "finger", "finger1.ply"))
    topo = MeshTopology.from_faces(F, n_vertices=len(X0))
    z = 0.5 * (lengths_and_angles(X0, topo) + lengths_and_angles(X1, topo))
    result["cases"]["finger"] = case("finger", topo, X0, z, repeat)
    Xs, Fs = deformed_sphere(23)  # 5292 vertices
    topo = MeshTopology.from_faces(Fs, n_vertices=len(Xs))
    z = lengths_and_angles(Xs, topo)
    z = z * (1.0 + 0.05 * np.sin(np.arange(len(z))))  # a target off the shape space: a nonzero gradient
    result["cases"]["sphere5k"] = case("sphere5k", topo, Xs, z, repeat)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
