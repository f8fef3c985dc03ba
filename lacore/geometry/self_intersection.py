"""Self-intersections of a triangle mesh: the pairs of faces that pass through each other.

A pair of faces *intersects* when one passes through the other: no plane separates
the two closed triangles, not even one touching both.  Faces that merely
touch (a vertex or an edge lying on the other face, two faces lying flat on each
other) are not reported, nor are faces sharing an edge (which meet along it).
Faces sharing one vertex are reported when they meet beyond that vertex (a fold
of the surface through itself).

The search is vectorized in three stages, each on the survivors of the one before:

1. *Broad phase*: the faces' axis-aligned bounding boxes are binned in a uniform
   grid whose cell is the mean box extent; the pairs sharing a cell whose boxes
   overlap are kept, each pair once (in the cell holding the low corner of the
   boxes' overlap).
2. *Plane test*: a pair whose one face lies on one side of the other's plane
   (within a tolerance relative to the faces' size) does not intersect.
3. *Exact test*: faces with no common vertex are separated by one of the nine
   cross products of their edges or not at all (the separating-axis theorem for
   two triangles that the plane test did not separate); faces with one common
   vertex intersect when the edge opposite that vertex in one face crosses the
   interior of the other.

Everything is relative: the same mesh in millimetres or metres gives the same pairs.
"""

import numpy as np

from .topology import check_faces, check_vertices

__all__ = ["self_intersections", "intersecting_faces"]

#: Relative tolerance: a distance below ``TOLERANCE`` times the faces' size counts as contact, not crossing.
TOLERANCE = 1e-9


def self_intersections(vertices, faces, *, check=True):
    """The pairs of faces of a triangle mesh that pass through each other.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex positions (any unit).
    faces : (F, 3) array_like of int
        Triangles.
    check : bool
        Validate the inputs (:func:`~lacore.geometry.topology.check_vertices`,
        :func:`~lacore.geometry.topology.check_faces`); ``False`` for a caller that
        already did, e.g. once per take rather than once per frame.

    Returns
    -------
    pairs : (P, 2) int64 ndarray
        Intersecting faces ``(i, j)`` with ``i < j``, sorted by ``i`` then ``j``.  Faces
        sharing an edge are never reported; faces sharing one vertex are reported when
        they meet beyond it.  Contact without crossing (touching vertices, edges or
        coplanar overlaps) is not reported.

    Notes
    -----
    Cost is about linear in ``F`` for meshes whose faces are of comparable size
    (a uniform grid of the bounding boxes); a face far larger than the others
    falls into many cells.  Degenerate faces (zero area) never intersect.

    Examples
    --------
    Two triangles crossing like the links of a chain, and the same two moved apart:

    >>> import numpy as np
    >>> from lacore.geometry.self_intersection import self_intersections
    >>> V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0],         # in the plane z = 0
    ...               [0.5, 0.5, -1], [0.5, 0.5, 1], [3, 0.5, 0]])  # pierces the first one
    >>> F = np.array([[0, 1, 2], [3, 4, 5]])
    >>> self_intersections(V, F)
    array([[0, 1]])
    >>> V[3:, 0] += 5
    >>> self_intersections(V, F).shape
    (0, 2)
    """
    if check:
        X = check_vertices(vertices)
        F = check_faces(faces, len(X))
    else:
        X, F = np.asarray(vertices, float), np.asarray(faces, np.int64)
    return _exact(X, F, _Candidates(X, F))


class _Candidates:
    """The broad phase: face pairs with overlapping boxes, split by the number of common vertices."""

    def __init__(self, X, F):
        T = X[F]
        i, j = _candidate_pairs(T.min(axis=1), T.max(axis=1)) if len(F) > 1 else (np.zeros(0, int),) * 2
        same = F[i][:, :, None] == F[j][:, None, :]                 # (P, 3, 3)
        shared = same.sum(axis=(1, 2))
        k = np.flatnonzero(shared == 0)
        self.disjoint = (i[k], j[k])
        k = np.flatnonzero(shared == 1)
        sm = same[k]
        # faces with one common vertex: its corner in face i and in face j
        self.one = (i[k], np.argmax(sm.any(axis=2), axis=1), j[k], np.argmax(sm.any(axis=1), axis=1))


def _exact(X, F, cand):
    """The candidate pairs that pass through each other at positions ``X``, sorted ``(P, 2)``."""
    T = X[F]                                                        # (F, 3, 3)
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    normal /= np.where(area2 > 0, area2, 1.0)[:, None]
    offset = np.einsum("fc,fc->f", normal, T[:, 0])
    e = np.roll(T, -1, axis=1) - T
    size = np.sqrt(np.einsum("fkc,fkc->fk", e, e).max(axis=1))    # longest edge
    faces_ = _Faces(T, normal, offset, area2 > 0, size)
    i, j = cand.disjoint
    hit = _triangles_cross(faces_, i, j)
    a, ca, b, cb = cand.one
    hit1 = _edge_crosses(faces_, a, ca, b) | _edge_crosses(faces_, b, cb, a)
    out = np.concatenate([np.stack([i[hit], j[hit]], axis=1), np.stack([a[hit1], b[hit1]], axis=1)]).astype(np.int64)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def intersecting_faces(vertices, faces):
    """Boolean mask ``(F,)`` of the faces in at least one pair of :func:`self_intersections`.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.self_intersection import intersecting_faces
    >>> V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [3, 0.5, 0],
    ...               [9.0, 9, 9], [10, 9, 9], [9, 10, 9]])
    >>> intersecting_faces(V, [[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    array([ True,  True, False])
    """
    F = check_faces(faces, len(np.asarray(vertices)))
    mask = np.zeros(len(F), bool)
    mask[self_intersections(vertices, F).ravel()] = True
    return mask


# ----------------------------------------------------------------------------- broad phase


def _candidate_pairs(lo, hi):
    """Pairs ``(i, j)``, ``i < j``, of the boxes ``lo, hi (F, 3)`` that overlap (each pair once)."""
    ext = (hi - lo).max(axis=1)
    h = float(ext.mean())
    if not np.isfinite(h) or h <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    origin = lo.min(axis=0)
    clo = np.floor((lo - origin) / h).astype(np.int64)
    chi = np.floor((hi - origin) / h).astype(np.int64)
    n3 = chi - clo + 1                                              # cells per axis of each box
    n = n3.prod(axis=1)
    dims = chi.max(axis=0) + 1
    face = np.repeat(np.arange(len(lo)), n)
    start = np.cumsum(n) - n
    k = np.arange(len(face)) - np.repeat(start, n)                  # index of the cell within the box
    nx, ny = n3[face, 0], n3[face, 1]
    cx = clo[face, 0] + k % nx
    cy = clo[face, 1] + (k // nx) % ny
    cz = clo[face, 2] + k // (nx * ny)
    key = (cx * dims[1] + cy) * dims[2] + cz
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    # all pairs within each run of equal keys: element p pairs with p+1 .. end of its run - 1
    bounds = np.flatnonzero(np.diff(key)) + 1
    run_end = np.repeat(np.append(bounds, len(key)), np.diff(np.concatenate(([0], bounds, [len(key)]))))
    count = run_end - np.arange(len(key)) - 1
    p = np.repeat(np.arange(len(key)), count)
    q = p + 1 + (np.arange(len(p)) - np.repeat(np.cumsum(count) - count, count))
    a, b = face[p], face[q]
    for ax in range(3):                                             # box overlap, one axis at a time
        lo_, hi_ = lo[:, ax], hi[:, ax]
        keep = (lo_[a] <= hi_[b]) & (lo_[b] <= hi_[a])
        a, b, p = a[keep], b[keep], p[keep]
    # report a pair only in the cell holding the low corner of the boxes' overlap (floor is monotone)
    c = np.maximum(clo[a], clo[b])
    mine = (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2] == key[p]
    a, b = a[mine], b[mine]
    return np.minimum(a, b), np.maximum(a, b)


# ----------------------------------------------------------------------------- exact tests


class _Faces:
    """Per-face data of the exact tests: corners ``T (F, 3, 3)``, unit normals, plane offsets, size."""

    def __init__(self, T, normal, offset, ok, size):
        self.T, self.normal, self.offset, self.ok, self.size = T, normal, offset, ok, size

    def distances(self, f, points):
        """Signed distances ``(P, K)`` of ``points (P, K, 3)`` to the planes of faces ``f (P,)``."""
        return np.einsum("pkc,pc->pk", points, self.normal[f]) - self.offset[f][:, None]


def _one_side(d, eps):
    """Whether every row of ``d (P, K)`` is >= -eps or <= eps (the points do not cross the plane)."""
    return (d.min(axis=1) >= -eps) | (d.max(axis=1) <= eps)


def _triangles_cross(fc, i, j):
    """Whether faces ``i`` and ``j`` ``(P,)`` with no common vertex pass through each other ``(P,)``."""
    out = np.zeros(len(i), bool)
    if not len(i):
        return out
    eps = TOLERANCE * np.maximum(fc.size[i], fc.size[j])
    keep = fc.ok[i] & fc.ok[j] & ~_one_side(fc.distances(i, fc.T[j]), eps)
    idx, i, j, eps = np.flatnonzero(keep), i[keep], j[keep], eps[keep]
    keep = ~_one_side(fc.distances(j, fc.T[i]), eps)
    idx, i, j, eps = idx[keep], i[keep], j[keep], eps[keep]
    A, B = fc.T[i], fc.T[j]
    eA = np.roll(A, -1, axis=1) - A                                  # (P, 3, 3) edges
    eB = np.roll(B, -1, axis=1) - B
    separated = np.zeros(len(idx), bool)
    for s in range(3):                                               # the separating-axis test, edge x edge axes
        for t in range(3):
            axis = np.cross(eA[:, s], eB[:, t])
            norm = np.linalg.norm(axis, axis=1)
            usable = norm > TOLERANCE * np.linalg.norm(eA[:, s], axis=1) * np.linalg.norm(eB[:, t], axis=1)
            pa = np.einsum("pkc,pc->pk", A, axis)
            pb = np.einsum("pkc,pc->pk", B, axis)
            tol = eps * norm
            gap = (pa.max(axis=1) <= pb.min(axis=1) + tol) | (pb.max(axis=1) <= pa.min(axis=1) + tol)
            separated |= usable & gap
    out[idx] = ~separated
    return out


def _edge_crosses(fc, i, corner, j):
    """Whether the edge of face ``i`` opposite its corner ``corner`` crosses the interior of face ``j`` ``(P,)``.

    Both ends strictly on opposite sides of ``j``'s plane, and the crossing point strictly
    inside ``j`` (contact with its boundary does not count).
    """
    rows = np.arange(len(i))
    pq = np.stack([fc.T[i, (corner + 1) % 3], fc.T[i, (corner + 2) % 3]], axis=1)   # (P, 2, 3)
    eps = TOLERANCE * np.maximum(fc.size[i], fc.size[j])
    d = fc.distances(j, pq)
    cross = fc.ok[j] & (((d[:, 0] > eps) & (d[:, 1] < -eps)) | ((d[:, 0] < -eps) & (d[:, 1] > eps)))
    out = np.zeros(len(i), bool)
    idx = rows[cross]
    if not len(idx):
        return out
    d, B, pq = d[idx], fc.T[j[idx]], pq[idx]
    t = d[:, 0] / (d[:, 0] - d[:, 1])
    x = pq[:, 0] + t[:, None] * (pq[:, 1] - pq[:, 0])
    n = np.cross(B[:, 1] - B[:, 0], B[:, 2] - B[:, 0])
    nn = np.einsum("pc,pc->p", n, n)
    inside = np.ones(len(idx), bool)
    for k in range(3):
        e = B[:, (k + 1) % 3] - B[:, k]
        w = np.einsum("pc,pc->p", np.cross(e, x - B[:, k]), n) / nn    # barycentric weight of the opposite corner
        inside &= w > TOLERANCE
    out[idx] = inside
    return out
