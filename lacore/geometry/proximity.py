"""Distances between triangles of a mesh: :func:`touching_faces`, :func:`triangle_distances`.

Two faces *touch* when they share no vertex and come within a given distance of each
other without passing through each other: closed lips, an eyelid resting on the eyeball,
fingers held together.  A deformation that keeps such faces apart must keep a gap the
mesh itself barely has, so a test of a deformed mesh for faces passing through each
other (:func:`lacore.geometry.self_intersection.self_intersections`) treats the faces
touching in the rest mesh as contacts, like the pairs crossing there.

The distance between two triangles that do not cross is the least of the six distances
of a corner of one to the other triangle and the nine distances between an edge of one
and an edge of the other (Ericson, *Real-Time Collision Detection*, 5.1.5 and 5.1.9).
Candidate pairs come from the broad phase of the self-intersection search with the
boxes grown by the distance; everything is vectorized over pairs.
"""

import numpy as np

from .self_intersection import _candidate_pairs
from .topology import MeshTopology, check_faces, check_vertices

__all__ = ["touching_faces", "triangle_distances", "point_triangle_distances", "segment_distances",
           "closest_point_barycentrics"]


def closest_point_barycentrics(P, A, B, C):
    """Barycentric coordinates ``(..., 3)`` of the point of triangle ``(A, B, C)`` nearest to ``P``.

    Ericson's Voronoi-region test (*Real-Time Collision Detection* 5.1.5), vectorized over
    broadcasting ``(..., 3)`` arrays (e.g. points ``(p, 1, 3)`` against faces ``(F, 3)``).
    Regions are tested in Ericson's order of precedence: interior, edges ``AB``, ``AC``,
    ``BC``, then corners.  NaN where a triangle is degenerate and no edge or corner region
    applies.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.proximity import closest_point_barycentrics
    >>> closest_point_barycentrics(np.array([2.0, 2, 1]), np.zeros(3), np.array([1.0, 0, 0]), np.array([0.0, 1, 0]))
    array([0. , 0.5, 0.5])
    """
    AB, AC = B - A, C - A
    AP, BP, CP = P - A, P - B, P - C
    d1, d2 = np.einsum("...c,...c->...", AB, AP), np.einsum("...c,...c->...", AC, AP)
    d3, d4 = np.einsum("...c,...c->...", AB, BP), np.einsum("...c,...c->...", AC, BP)
    d5, d6 = np.einsum("...c,...c->...", AB, CP), np.einsum("...c,...c->...", AC, CP)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        v, w = vb / den, vc / den                                  # interior
        t = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)                       # edge AB
        v, w = np.where(m, t, v), np.where(m, 0.0, w)
        t = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)                       # edge AC
        v, w = np.where(m, 0.0, v), np.where(m, t, w)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)             # edge BC
        v, w = np.where(m, 1.0 - t, v), np.where(m, t, w)
    for vv, ww, m in ((0.0, 0.0, (d1 <= 0) & (d2 <= 0)), (1.0, 0.0, (d3 >= 0) & (d4 <= d3)),
                      (0.0, 1.0, (d6 >= 0) & (d5 <= d6))):          # corners
        v, w = np.where(m, vv, v), np.where(m, ww, w)
    return np.stack([1.0 - v - w, v, w], axis=-1)


def point_triangle_distances(P, A, B, C):
    """Distance of each point ``P[i]`` to the triangle ``(A[i], B[i], C[i])``, all ``(N, 3)``; returns ``(N,)``.

    :func:`closest_point_barycentrics`; a degenerate triangle gives the distance to its
    nearest corner or edge.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.proximity import point_triangle_distances
    >>> A, B, C = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    >>> point_triangle_distances(np.array([[0.2, 0.2, 0.5]]), A, B, C)
    array([0.5])
    """
    b = closest_point_barycentrics(P, A, B, C)
    d = np.linalg.norm(P - (b[:, :1] * A + b[:, 1:2] * B + b[:, 2:] * C), axis=1)
    bad = np.flatnonzero(~np.isfinite(b).all(axis=1))
    if bad.size:                                                   # degenerate: corners and edges
        d[bad] = np.min([segment_distances(P[bad], P[bad], S0[bad], S1[bad]) for S0, S1 in ((A, B), (B, C), (C, A))],
                        axis=0)
    return d


def segment_distances(P0, P1, Q0, Q1):
    """Distance between each segment ``P0[i] P1[i]`` and ``Q0[i] Q1[i]``, all ``(N, 3)``; returns ``(N,)``.

    Ericson 5.1.9 (closest points of two segments, clamped), degenerate segments included.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.proximity import segment_distances
    >>> segment_distances(np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]),
    ...                   np.array([[0.5, -1, 2]]), np.array([[0.5, 1, 2]]))
    array([2.])
    """
    d1, d2, r = P1 - P0, Q1 - Q0, P0 - Q0
    a, e = np.einsum("ic,ic->i", d1, d1), np.einsum("ic,ic->i", d2, d2)
    b, c, f = np.einsum("ic,ic->i", d1, d2), np.einsum("ic,ic->i", d1, r), np.einsum("ic,ic->i", d2, r)
    tiny = 1e-300
    den = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(den > 1e-12 * np.maximum(a * e, tiny), np.clip((b * f - c * e) / den, 0.0, 1.0), 0.0)
        s = np.where(a > tiny, s, 0.0)
        t = np.where(e > tiny, (b * s + f) / e, 0.0)
        # t outside [0, 1]: clamp it and recompute s for the clamped t
        s = np.where(t < 0, np.where(a > tiny, np.clip(-c / a, 0.0, 1.0), 0.0), s)
        s = np.where(t > 1, np.where(a > tiny, np.clip((b - c) / a, 0.0, 1.0), 0.0), s)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(P0 + s[:, None] * d1 - Q0 - t[:, None] * d2, axis=1)


def triangle_distances(vertices, faces, a, b):
    """Distance between faces ``a[i]`` and ``b[i]`` of a mesh (0 or more where they pass through each other).

    The least of the corner-to-triangle and edge-to-edge distances: the distance of
    two triangles that do not cross; two crossing triangles may give a small positive
    value (test them with :func:`lacore.geometry.self_intersection.self_intersections`).

    Parameters
    ----------
    vertices : (V, 3) array_like
    faces : (F, 3) array_like of int
    a, b : (N,) array_like of int

    Returns
    -------
    (N,) ndarray

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.proximity import triangle_distances
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0.3], [1, 0, 0.3], [0, 1, 0.3]])
    >>> triangle_distances(V, [[0, 1, 2], [3, 4, 5]], [0], [1]).round(6)
    array([0.3])
    """
    X = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    Ta, Tb = X[F[np.asarray(a, np.int64)]], X[F[np.asarray(b, np.int64)]]      # (N, 3, 3)
    d = [point_triangle_distances(S[:, k], T[:, 0], T[:, 1], T[:, 2]) for S, T in ((Ta, Tb), (Tb, Ta))
         for k in range(3)]
    d += [segment_distances(Ta[:, i], Ta[:, (i + 1) % 3], Tb[:, j], Tb[:, (j + 1) % 3])
          for i in range(3) for j in range(3)]
    return np.min(d, axis=0) if len(Ta) else np.zeros(0)


def touching_faces(vertices, faces, distance):
    """Pairs of faces sharing no vertex that come within ``distance`` of each other.

    Parameters
    ----------
    vertices : (V, 3) array_like
    faces : (F, 3) array_like of int or MeshTopology
    distance : float
        In the unit of ``vertices`` (callers pass a fraction of the mean edge length, so
        that the same mesh in millimetres or metres gives the same pairs).

    Returns
    -------
    pairs : (P, 2) int64 ndarray
        ``(i, j)`` with ``i < j``, sorted; pairs passing through each other included when
        their corners and edges come that close.

    Examples
    --------
    Two parallel triangles 0.3 apart touch within 0.5, not within 0.2:

    >>> import numpy as np
    >>> from lacore.geometry.proximity import touching_faces
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0.3], [1, 0, 0.3], [0, 1, 0.3]])
    >>> touching_faces(V, [[0, 1, 2], [3, 4, 5]], 0.5)
    array([[0, 1]])
    >>> touching_faces(V, [[0, 1, 2], [3, 4, 5]], 0.2).shape
    (0, 2)
    """
    if isinstance(faces, MeshTopology):
        faces = faces.faces
    X = check_vertices(vertices)
    F = check_faces(faces, len(X))
    distance = float(distance)
    if not (np.isfinite(distance) and distance >= 0):
        raise ValueError(f"distance must be a finite number >= 0, got {distance}")
    if not len(F):
        return np.zeros((0, 2), np.int64)
    T = X[F]
    grow = 0.5 * distance
    a, b = _candidate_pairs(T.min(axis=1) - grow, T.max(axis=1) + grow)
    a, b = a.astype(np.int64), b.astype(np.int64)
    share = (F[a][:, :, None] == F[b][:, None, :]).any(axis=(1, 2))
    a, b = a[~share], b[~share]
    near = triangle_distances(X, F, a, b) <= distance
    pairs = np.stack([a[near], b[near]], axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if len(pairs) else np.zeros((0, 2), np.int64)
