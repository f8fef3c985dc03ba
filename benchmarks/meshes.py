"""Deterministic benchmark meshes (no random numbers, no files): smooth closed and open surfaces of any size.

Two families, both consistently oriented (outward normals), manifold and free of
degenerate triangles:

* :func:`deformed_sphere` -- a class-I geodesic sphere (every face of an
  icosahedron split into ``frequency**2`` triangles, projected to the sphere;
  ``V = 10 frequency**2 + 2``, valences 5 and 6), stretched to an elongated,
  bumpy, cactus-like closed surface by a smooth radial deformation.
  ``frequency=23`` gives 5292 vertices (close to the 5261-vertex "cactus" of the
  thesis' experiments and of the GOAST reference timings), ``frequency=100``
  gives 100002.
* :func:`bent_tube` -- an open tube (cylinder topology: two boundary loops)
  from an ``n_around x n_along`` vertex grid, bent along a quarter circle, with
  a wavy radius; all interior vertices have valence 6.

Vertices are numbered by a reverse Cuthill-McKee ordering of the vertex graph
(as a mesh optimized for cache locality would be), faces are sorted by their
smallest vertex.  :data:`BENCHMARK_MESHES` names the standard sizes and
:func:`benchmark_mesh` builds one of them by name.

Run ``python benchmarks/meshes.py`` for a summary of the standard meshes.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

__all__ = ["icosahedron", "geodesic_sphere", "deformed_sphere", "bent_tube", "BENCHMARK_MESHES", "benchmark_mesh"]


def icosahedron():
    """Regular icosahedron on the unit sphere: ``(vertices (12, 3), faces (20, 3))``, outward oriented."""
    p = (1.0 + np.sqrt(5.0)) / 2.0
    X = np.array([[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0],
                  [0, -1, p], [0, 1, p], [0, -1, -p], [0, 1, -p],
                  [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]], float)
    X /= np.linalg.norm(X, axis=1)[:, None]
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    return X, F


def _reorder(X, faces):
    """Renumber vertices by reverse Cuthill-McKee and sort faces by their smallest vertex."""
    V = len(X)
    i = faces.ravel()
    j = np.roll(faces, -1, axis=1).ravel()
    g = sp.csr_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(V, V))
    perm = reverse_cuthill_mckee(g, symmetric_mode=True).astype(np.int64)
    new_index = np.empty(V, np.int64)
    new_index[perm] = np.arange(V)
    faces = new_index[faces]
    # rotate each face so that its smallest vertex comes first (keeps the orientation), then sort
    shift = np.argmin(faces, axis=1)
    faces = np.take_along_axis(faces, (shift[:, None] + np.arange(3)) % 3, axis=1)
    faces = faces[np.lexsort((faces[:, 2], faces[:, 1], faces[:, 0]))]
    return np.ascontiguousarray(X[perm]), np.ascontiguousarray(faces)


def geodesic_sphere(frequency):
    """Class-I geodesic sphere on the unit sphere, ``V = 10 frequency**2 + 2``.

    Every icosahedron face is split into ``frequency**2`` triangles whose
    vertices are identified across faces exactly (by their integer barycentric
    weights on the icosahedron's vertices), then projected to the sphere.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (20 frequency**2, 3) int64
    """
    n = int(frequency)
    if n < 1:
        raise ValueError("frequency must be >= 1")
    X0, F0 = icosahedron()
    ii, jj = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = ii + jj <= n
    ii, jj = ii[keep], jj[keep]                                   # local lattice points (i, j)
    local = -np.ones((n + 1, n + 1), np.int64)
    local[ii, jj] = np.arange(len(ii))
    P = len(ii)
    # integer weights of every lattice point of every face on the 12 icosahedron vertices
    W = np.zeros((20, P, 12), np.int16)
    rows = np.arange(P)
    for f, (a, b, c) in enumerate(F0):
        W[f, rows, a] += n - ii - jj
        W[f, rows, b] += ii
        W[f, rows, c] += jj
    keys, gid = np.unique(W.reshape(-1, 12), axis=0, return_inverse=True)
    gid = gid.reshape(20, P)
    X = keys.astype(float) @ X0 / n
    X /= np.linalg.norm(X, axis=1)[:, None]
    # small triangles of the lattice: "up" (i, j), (i+1, j), (i, j+1) and "down" (i+1, j), (i+1, j+1), (i, j+1)
    ui, uj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = ui + uj <= n - 1
    down = ui + uj <= n - 2
    tri_up = np.stack([local[ui[up], uj[up]], local[ui[up] + 1, uj[up]], local[ui[up], uj[up] + 1]], 1)
    tri_dn = np.stack([local[ui[down] + 1, uj[down]], local[ui[down] + 1, uj[down] + 1],
                       local[ui[down], uj[down] + 1]], 1)
    tri = np.r_[tri_up, tri_dn]
    faces = gid[:, tri].reshape(-1, 3)
    return _reorder(X, faces)


def deformed_sphere(frequency):
    """A smooth, elongated and bumpy closed surface: a deformed :func:`geodesic_sphere`.

    The unit sphere point ``u`` moves to ``r(u) * (u_x, u_y, 1.8 u_z)`` with the
    radial profile ``r = 1 + 0.12 sin(3 u_x + 1) cos(2 u_y) + 0.08 u_z^3 + 0.05 sin(5 u_z)``
    (a cactus-like body with low-frequency bumps; all triangles stay well shaped).
    """
    X, faces = geodesic_sphere(frequency)
    x, y, z = X.T
    r = 1.0 + 0.12 * np.sin(3.0 * x + 1.0) * np.cos(2.0 * y) + 0.08 * z ** 3 + 0.05 * np.sin(5.0 * z)
    return np.ascontiguousarray(np.stack([r * x, r * y, 1.8 * r * z], 1)), faces


def bent_tube(n_around, n_along, length=4.0, radius=0.5):
    """Open tube from an ``n_around x n_along`` vertex grid, bent along a quarter circle.

    The centre line is an arc of angle ``pi / 2`` and length ``length``; the
    radius varies smoothly, ``radius (1 + 0.15 sin(3 phi) sin(2 pi t))``.  Each
    grid quad is split along the same diagonal, so interior vertices have
    valence 6; the two ends are boundary loops.

    Returns
    -------
    vertices : (n_around n_along, 3) float64
    faces : (2 n_around (n_along - 1), 3) int64
    """
    na, nl = int(n_around), int(n_along)
    if na < 3 or nl < 2:
        raise ValueError("need n_around >= 3 and n_along >= 2")
    phi = 2.0 * np.pi * np.arange(na) / na
    t = np.linspace(0.0, 1.0, nl)
    P, T = np.meshgrid(phi, t, indexing="ij")                     # (na, nl)
    rho = radius * (1.0 + 0.15 * np.sin(3.0 * P) * np.sin(2.0 * np.pi * T))
    R = length / (np.pi / 2.0)                                    # bend radius
    a = T * np.pi / 2.0                                           # arc angle along the centre line
    # centre c(a) = R (1 - cos a, 0, sin a); tangent (sin a, 0, cos a); normals n1 = (cos a, 0, -sin a), n2 = (0, 1, 0)
    cx, cz = R * (1.0 - np.cos(a)), R * np.sin(a)
    X = np.stack([cx + rho * np.cos(P) * np.cos(a), rho * np.sin(P), cz - rho * np.cos(P) * np.sin(a)], -1)
    idx = np.arange(na * nl).reshape(na, nl)
    i0, i1 = idx, np.roll(idx, -1, axis=0)                        # around direction wraps
    a00, a10 = i0[:, :-1].ravel(), i1[:, :-1].ravel()
    a01, a11 = i0[:, 1:].ravel(), i1[:, 1:].ravel()
    # orientation: (around) x (along) points outward for this parametrization
    faces = np.r_[np.stack([a00, a10, a11], 1), np.stack([a00, a11, a01], 1)]
    return _reorder(X.reshape(-1, 3), faces)


#: Standard benchmark meshes: name -> (generator, arguments, description).
BENCHMARK_MESHES = {
    "sphere5k": (deformed_sphere, (23,), "deformed geodesic sphere, frequency 23, closed (5292 vertices)"),
    "sphere100k": (deformed_sphere, (100,), "deformed geodesic sphere, frequency 100, closed (100002 vertices)"),
    "tube5k": (bent_tube, (64, 81), "bent tube 64 x 81, two boundary loops (5184 vertices)"),
    "tube100k": (bent_tube, (250, 400), "bent tube 250 x 400, two boundary loops (100000 vertices)"),
}


def benchmark_mesh(name):
    """Build a standard benchmark mesh by name (see :data:`BENCHMARK_MESHES`): ``(vertices, faces)``."""
    try:
        fn, args, _ = BENCHMARK_MESHES[name]
    except KeyError:
        raise KeyError(f"unknown benchmark mesh {name!r}; choose from {sorted(BENCHMARK_MESHES)}") from None
    return fn(*args)


if __name__ == "__main__":  # pragma: no cover
    import json
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from lacore.geometry.topology import MeshTopology

    summary = {}
    for name, (_, _, desc) in BENCHMARK_MESHES.items():
        X, F = benchmark_mesh(name)
        topo = MeshTopology.from_faces(F, n_vertices=len(X))
        summary[name] = {"description": desc, "vertices": len(X), "edges": topo.n_edges, "faces": len(F),
                         "boundary_loops": len(topo.boundary_loops()), "genus": int(topo.genus()[0]),
                         "valences": {int(k): int(v) for k, v in enumerate(np.bincount(topo.vertex_valence)) if v}}
    print(json.dumps(summary, indent=1))
