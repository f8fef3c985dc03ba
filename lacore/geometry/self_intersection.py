"""Self-intersections of a triangle mesh: the pairs of faces that pass through each other.

A pair of faces *intersects* when one passes through the other: no plane separates
the two closed triangles, not even one touching both.  Faces that merely
touch (a vertex or an edge lying on the other face, two faces lying flat on each
other) are not reported, nor are faces sharing an edge (which meet along it).
Faces sharing one vertex are reported when they meet beyond that vertex (a fold
of the surface through itself).

The search is vectorized; the faces sharing a vertex and the faces sharing none are
handled apart:

1. *Faces sharing one vertex* ``v`` (known from the connectivity alone) are tested
   only where the fan of faces around ``v`` is not a *graph*: when every face of a
   closed, consistently oriented fan faces the same side as the vertex normal ``n``
   and the fan winds once around ``n`` (the angles of the faces projected on the
   plane normal to ``n`` sum to one turn), the projected faces overlap only at ``v``,
   so no two faces of the fan meet beyond it.  On a smooth surface this leaves the
   fans of folds and sharp creases.
2. *Broad phase* for the faces sharing no vertex: the faces' axis-aligned bounding
   boxes are binned in columns along the longest axis of the mesh (a square grid of
   side the mean box extent on the other two axes); within a column, boxes sorted by
   their low end pair with those starting before their high end (sort and sweep).
   A pair is kept in the column holding the low corner of its boxes' overlap (each
   pair once) if the boxes overlap and the faces share no vertex.
3. *Plane test*: a pair whose one face lies on one side of the other's plane
   (within a tolerance relative to the faces' size) does not intersect.
4. *Exact test*: faces with no common vertex are separated by one of the nine
   cross products of their edges or not at all (the separating-axis theorem for
   two triangles that the plane test did not separate); faces with one common
   vertex intersect when the edge opposite that vertex in one face crosses the
   interior of the other.

The connectivity-only part (the faces around each vertex, which fans are closed) is
computed once per :class:`~lacore.geometry.topology.MeshTopology` when one is given
for ``faces`` (kept in its :attr:`~lacore.geometry.topology.MeshTopology.cache`), else
once per call.  Everything is relative: the same mesh in millimetres or metres gives
the same pairs.
"""

import numpy as np

from .topology import MeshTopology, check_faces, check_vertices

__all__ = ["self_intersections", "intersecting_faces"]

#: Relative tolerance: a distance below ``TOLERANCE`` times the faces' size counts as contact, not crossing.
TOLERANCE = 1e-9

#: A face of a fan counts as facing the side of the vertex normal when the cosine of their angle exceeds this.
FAN_MARGIN = 1e-6


def self_intersections(vertices, faces, *, check=True):
    """The pairs of faces of a triangle mesh that pass through each other.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex positions (any unit).
    faces : (F, 3) array_like of int or MeshTopology
        Triangles.  A :class:`~lacore.geometry.topology.MeshTopology` keeps the
        connectivity-only part of the search in its cache, for a caller testing many
        poses of one mesh (e.g. every frame of a take).
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
    topology = faces if isinstance(faces, MeshTopology) else None
    if topology is not None:
        faces = topology.faces
    if check:
        X = check_vertices(vertices)
        F = check_faces(faces, len(X))
    else:
        X, F = np.asarray(vertices, float), np.asarray(faces, np.int64)
    if topology is not None and topology.n_vertices == len(X):
        stars = topology.cache.get((__name__, "stars"), lambda: _Stars(F, len(X)))
    else:
        stars = _Stars(F, len(X))
    return _search(X, F, stars)


def intersecting_faces(vertices, faces):
    """Boolean mask ``(F,)`` of the faces in at least one pair of :func:`self_intersections`.

    ``faces`` may be a :class:`~lacore.geometry.topology.MeshTopology` (see there).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.self_intersection import intersecting_faces
    >>> V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [3, 0.5, 0],
    ...               [9.0, 9, 9], [10, 9, 9], [9, 10, 9]])
    >>> intersecting_faces(V, [[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    array([ True,  True, False])
    """
    if isinstance(faces, MeshTopology):
        n_faces = faces.n_faces
    else:
        faces = check_faces(faces, len(np.asarray(vertices)))
        n_faces = len(faces)
    mask = np.zeros(n_faces, bool)
    mask[self_intersections(vertices, faces).ravel()] = True
    return mask


# ----------------------------------------------------------------------------- connectivity


class _Stars:
    """Connectivity-only data: the faces around each vertex and which of them form one closed fan.

    Attributes
    ----------
    corner : (3F,) int64 ndarray
        Corners ``3 f + k`` (vertex ``faces[f, k]`` of face ``f``) grouped by vertex, from
        ``start[v]`` to ``start[v] + valence[v]``.
    start, valence : (V,) int64 ndarray
    closed : (V,) bool ndarray
        Vertices whose faces form one closed, consistently oriented fan: the links
        ``a -> b`` of the faces ``(v, a, b)`` are one permutation of the neighbours
        (a union of cycles; more than one cycle fails the winding test of
        :meth:`_Faces.graph_fans`).
    """

    def __init__(self, F, n_vertices):
        n = int(n_vertices)
        F = np.asarray(F, np.int64)
        self.Ft = np.ascontiguousarray(F.T, dtype=np.int32 if n < 2 ** 31 else np.int64)   # (3, F)
        v = F.ravel()
        a = F[:, [1, 2, 0]].ravel()
        b = F[:, [2, 0, 1]].ravel()
        key_a = v * n + a
        corner = _argsort(key_a, n * n)                             # corners grouped by vertex
        sorted_a = key_a[corner]
        self.valence = np.bincount(v, minlength=n)
        self.start = np.cumsum(self.valence) - self.valence
        self.corner = corner
        closed = self.valence >= 3
        closed[v[corner[1:][sorted_a[1:] == sorted_a[:-1]]]] = False          # a neighbour twice as a start
        sorted_b = np.sort(v * n + b)                               # the same groups: equal iff the same ends
        closed[sorted_a[sorted_a != sorted_b] // n] = False
        degenerate = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
        closed[F[degenerate].ravel()] = False
        self.closed = closed

    def pairs(self, F, vertices):
        """Faces ``i, j`` whose only common vertex is one of ``vertices``, and its corner in each ``(4, Q)``."""
        val = self.valence[vertices]
        val = np.where(val > 1, val, 0)
        corner = self.corner[np.repeat(self.start[vertices] - np.cumsum(val) + val, val) + np.arange(val.sum())]
        end = np.repeat(np.cumsum(val), val)
        count = end - np.arange(len(corner)) - 1
        p = np.repeat(np.arange(len(corner)), count)
        q = p + 1 + np.arange(len(p)) - np.repeat(np.cumsum(count) - count, count)
        cp, cq = corner[p], corner[q]
        fp, kp, fq, kq = cp // 3, cp % 3, cq // 3, cq % 3
        ap, bp, aq, bq = F[fp, (kp + 1) % 3], F[fp, (kp + 2) % 3], F[fq, (kq + 1) % 3], F[fq, (kq + 2) % 3]
        one = ~((ap == aq) | (ap == bq) | (bp == aq) | (bp == bq)) & (fp != fq)   # else they share an edge
        return np.stack([fp[one], kp[one], fq[one], kq[one]])


def _argsort(key, bound):
    """Stable ``argsort`` of non-negative integers ``key < bound`` (two 16-bit radix passes when they fit 32 bits)."""
    if bound > 2 ** 32:
        return np.argsort(key, kind="stable")
    low = np.argsort((key & 0xFFFF).astype(np.uint16), kind="stable")
    return low[np.argsort((key >> 16).astype(np.uint16)[low], kind="stable")]


# ----------------------------------------------------------------------------- search


def _search(X, F, stars):
    """The intersecting face pairs at positions ``X``, sorted ``(P, 2)``."""
    Ft = stars.Ft
    fc = _Faces(X, Ft)
    # faces sharing one vertex, where the fan around it is not a graph
    i, ci, j, cj = stars.pairs(F, np.flatnonzero(~fc.graph_fans(Ft, stars.closed)))
    hit1 = _edge_crosses(fc, i, ci, j) | _edge_crosses(fc, j, cj, i)
    # faces sharing no vertex
    a, b = _candidate_pairs(fc.lo, fc.hi) if len(F) > 1 else (np.zeros(0, np.int64),) * 2
    A, B = [np.take(f, a) for f in Ft], [np.take(f, b) for f in Ft]
    shared = np.zeros(len(a), bool)
    for s in range(3):
        for t in range(3):
            shared |= A[s] == B[t]
    a, b = a[~shared], b[~shared]
    hit = _triangles_cross(fc, a, b)
    out = np.concatenate([np.stack([a[hit], b[hit]], axis=1), np.stack([i[hit1], j[hit1]], axis=1)])
    out = np.sort(out, axis=1).astype(np.int64)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def _dot(a, b):
    """Dot products over the first axis of ``a, b (3, ...)``."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    """Cross products over the first axis of ``a, b (3, ...)``."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


class _Faces:
    """Per-face data of the tests, coordinates first (each row contiguous).

    ``P (3, 3, F)``: coordinate ``c`` of corner ``k`` of face ``f`` is ``P[k, c, f]``;
    ``E (3, 3, F)``: the edges ``x_{k+1} - x_k``; boxes ``lo, hi (F, 3)``; ``cross (3, F)``:
    ``(x1 - x0) x (x2 - x0)``; unit ``normal (3, F)``, plane ``offset``, longest edge ``size``
    and ``ok`` (non-degenerate) ``(F,)``.
    """

    def __init__(self, X, Ft):
        Xt = np.ascontiguousarray(X.T)
        P = np.empty((3, 3, Ft.shape[1]))
        for k in range(3):
            for c in range(3):
                np.take(Xt[c], Ft[k], out=P[k, c])
        self.P = P
        self.lo = np.minimum(np.minimum(P[0], P[1]), P[2]).T
        self.hi = np.maximum(np.maximum(P[0], P[1]), P[2]).T
        E = np.empty_like(P)
        for k in range(3):
            np.subtract(P[(k + 1) % 3], P[k], out=E[k])
        self.E = E
        cross = _cross(E[0], -E[2])
        area2 = np.sqrt(_dot(cross, cross))
        self.cross, self.area2 = cross, area2
        self.ok = area2 > 0
        self.normal = cross / np.where(self.ok, area2, 1.0)
        self.offset = _dot(self.normal, P[0])
        self.sq_edges = np.stack([_dot(E[k], E[k]) for k in range(3)])          # (3, F)
        self.size = np.sqrt(self.sq_edges.max(axis=0))

    def graph_fans(self, Ft, closed):
        """Vertices ``(V,)`` whose closed fan is a graph over the plane normal to the vertex normal.

        Every face ``(v, a, b)`` of the fan faces the side of the (area-weighted) vertex
        normal ``n`` and the projected angles ``a v b`` sum to one turn (they are all in
        ``(0, pi)`` and sum to a whole number of turns).
        """
        n_vertices = len(closed)
        N, E = self.cross, self.E
        normal = np.zeros((3, n_vertices))
        for c in range(3):
            for k in range(3):
                normal[c] += np.bincount(Ft[k], N[c], n_vertices)
        nn = np.sqrt(_dot(normal, normal))
        unit = normal / np.where(nn > 0, nn, 1.0)
        turn = np.zeros(n_vertices)
        flat = np.zeros(n_vertices)
        for k in range(3):
            u = np.take(unit, Ft[k], axis=1)                        # (3, F): the vertex normal at corner k
            e1, e2 = E[k], -E[(k + 2) % 3]                          # x_{k+1} - x_k, x_{k+2} - x_k
            y = _dot(u, N)                                          # n . (e1 x e2)
            x = _dot(e1, e2) - _dot(e1, u) * _dot(e2, u)            # projected e1 . projected e2
            turn += np.bincount(Ft[k], np.arctan2(y, x), n_vertices)
            flat += np.bincount(Ft[k], y <= FAN_MARGIN * self.area2, n_vertices)
        return closed & (flat == 0) & (turn < 3 * np.pi) & (nn > 0)


# ----------------------------------------------------------------------------- broad phase


def _candidate_pairs(lo, hi):
    """Pairs ``(a, b)`` of the boxes ``lo, hi (F, 3)`` that overlap (each pair once; module docstring)."""
    empty = np.zeros(0, np.int32), np.zeros(0, np.int32)
    h = float((hi - lo).max(axis=1).mean())
    span = hi.max(axis=0) - lo.min(axis=0)
    if not (np.isfinite(h) and np.isfinite(span).all()) or h <= 0:
        return empty
    x, y, z = np.argsort(-span, kind="stable")                     # sweep along the longest axis
    h = max(h, float(span[y]) / 2048, float(span[z]) / 2048)       # at most 2048 x 2048 columns
    origin = lo.min(axis=0)
    ylo, yhi = np.ascontiguousarray(lo[:, y]), np.ascontiguousarray(hi[:, y])
    zlo, zhi = np.ascontiguousarray(lo[:, z]), np.ascontiguousarray(hi[:, z])
    y0, y1 = ((ylo - origin[y]) / h).astype(np.int32), ((yhi - origin[y]) / h).astype(np.int32)
    z0, z1 = ((zlo - origin[z]) / h).astype(np.int32), ((zhi - origin[z]) / h).astype(np.int32)
    nz = z1 - z0 + 1
    n = (y1 - y0 + 1) * nz                                          # columns per box
    rows = int(z1.max()) + 1
    by_x = np.argsort(lo[:, x]).astype(np.int32)                   # boxes by their low end along x
    n = n[by_x]
    face = np.repeat(by_x, n)
    k = np.arange(len(face), dtype=np.int32) - np.repeat((np.cumsum(n) - n).astype(np.int32), n)
    nzf = np.take(nz, face)
    ky, kz = k // nzf, k % nzf                                      # the column within the box
    column = (np.take(y0, face) + ky) * rows + np.take(z0, face) + kz
    first = (ky == 0).view(np.uint8) | ((kz == 0).view(np.uint8) << 1)   # the box starts there (per axis)
    # sort and sweep along x in each column: keys column + [0, 1/2], a monotone map (safe under rounding)
    order = _argsort(column, (int(y1.max()) + 1) * rows)          # stable: by column, then along x
    column, face, first = np.take(column, order), np.take(face, order), np.take(first, order)
    scale = 0.5 / float(span[x]) if span[x] > 0 else 0.0
    key = column + np.take((lo[:, x] - origin[x]) * scale, face)
    bound = column + np.take((hi[:, x] - origin[x]) * scale, face)
    count = np.searchsorted(key, bound, side="right") - np.arange(len(key)) - 1
    # the pairs (p, p + d) of the sweep, kept in the column of the low corner of the boxes' overlap (each
    # pair once) if the boxes overlap on the other two axes: the offsets d that at least a tenth of the
    # entries have on whole shifted arrays (no gathers), the larger ones pair by pair
    ylo_, yhi_, zlo_, zhi_ = (np.take(v, face) for v in (ylo, yhi, zlo, zhi))   # per entry, in sweep order
    out_a, out_b = [], []
    active = np.cumsum(np.bincount(count)[::-1])[::-1]              # active[d]: entries with count >= d
    D = 1
    while D + 1 < len(active) and active[D + 1] >= 0.1 * len(count):
        D += 1
    for d in range(1, min(D, len(active) - 1) + 1):
        e = len(count) - d
        k = np.flatnonzero((count[:e] >= d) & ((first[:e] | first[d:]) == 3)
                           & (ylo_[:e] <= yhi_[d:]) & (ylo_[d:] <= yhi_[:e])
                           & (zlo_[:e] <= zhi_[d:]) & (zlo_[d:] <= zhi_[:e]))
        out_a.append(np.take(face, k))
        out_b.append(np.take(face, k + d))
    p = np.flatnonzero(count > D).astype(np.int32)
    if len(p):
        c = count[p] - D
        q = np.repeat(p + D, c) + 1 + np.arange(c.sum(), dtype=np.int32) - np.repeat(np.cumsum(c) - c, c)
        p = np.repeat(p, c)
        t = np.take
        k = np.flatnonzero(((t(first, p) | t(first, q)) == 3) & (t(ylo_, p) <= t(yhi_, q)) & (t(ylo_, q) <= t(yhi_, p))
                           & (t(zlo_, p) <= t(zhi_, q)) & (t(zlo_, q) <= t(zhi_, p)))
        out_a.append(t(face, t(p, k)))
        out_b.append(t(face, t(q, k)))
    a, b = np.concatenate(out_a or [empty[0]]), np.concatenate(out_b or [empty[0]])
    return np.minimum(a, b), np.maximum(a, b)


# ----------------------------------------------------------------------------- exact tests


def _plane_distances(fc, f, Q):
    """Signed distances ``(K, P)`` of the points ``Q (K, 3, P)`` to the planes of faces ``f (P,)``."""
    n = np.take(fc.normal, f, axis=1)
    return Q[:, 0] * n[0] + Q[:, 1] * n[1] + Q[:, 2] * n[2] - np.take(fc.offset, f)


def _crosses_plane(d, eps):
    """Whether the points of each column of ``d (3, P)`` lie strictly on both sides of the plane (beyond eps)."""
    lo = np.minimum(np.minimum(d[0], d[1]), d[2])
    hi = np.maximum(np.maximum(d[0], d[1]), d[2])
    return (lo < -eps) & (hi > eps)


def _triangles_cross(fc, i, j):
    """Whether faces ``i`` and ``j`` ``(P,)`` with no common vertex pass through each other ``(P,)``."""
    out = np.zeros(len(i), bool)
    if not len(i):
        return out
    # a degenerate face has a zero normal and offset: no point crosses its plane
    eps = TOLERANCE * np.maximum(np.take(fc.size, i), np.take(fc.size, j))
    B = np.take(fc.P, j, axis=2)                                    # (3, 3, P)
    idx = np.flatnonzero(_crosses_plane(_plane_distances(fc, i, B), eps))
    i, j, eps, B = np.take(i, idx), np.take(j, idx), np.take(eps, idx), np.take(B, idx, axis=2)
    A = np.take(fc.P, i, axis=2)
    keep = np.flatnonzero(_crosses_plane(_plane_distances(fc, j, A), eps))
    idx, i, j, eps = np.take(idx, keep), np.take(i, keep), np.take(j, keep), np.take(eps, keep)
    A, B = np.take(A, keep, axis=2), np.take(B, keep, axis=2)
    # the separating-axis test on the nine axes edge of A x edge of B, all at once
    eA, eB = np.take(fc.E, i, axis=2)[:, None], np.take(fc.E, j, axis=2)[None]   # (3 s, 1, 3, P), (1, 3 t, 3, P)
    axis = np.stack([eA[:, :, 1] * eB[:, :, 2] - eA[:, :, 2] * eB[:, :, 1],
                     eA[:, :, 2] * eB[:, :, 0] - eA[:, :, 0] * eB[:, :, 2],
                     eA[:, :, 0] * eB[:, :, 1] - eA[:, :, 1] * eB[:, :, 0]], axis=2)   # (3, 3, 3, P)
    norm = np.sqrt(_dot(np.moveaxis(axis, 2, 0), np.moveaxis(axis, 2, 0)))            # (3, 3, P)
    lengths = np.sqrt(fc.sq_edges[:, i])[:, None] * np.sqrt(fc.sq_edges[:, j])[None]  # (3, 3, P)
    usable = norm > TOLERANCE * lengths
    pa = [A[k, 0] * axis[:, :, 0] + A[k, 1] * axis[:, :, 1] + A[k, 2] * axis[:, :, 2] for k in range(3)]
    pb = [B[k, 0] * axis[:, :, 0] + B[k, 1] * axis[:, :, 1] + B[k, 2] * axis[:, :, 2] for k in range(3)]
    tol = eps * norm
    gap = ((np.maximum(np.maximum(pa[0], pa[1]), pa[2]) <= np.minimum(np.minimum(pb[0], pb[1]), pb[2]) + tol)
           | (np.maximum(np.maximum(pb[0], pb[1]), pb[2]) <= np.minimum(np.minimum(pa[0], pa[1]), pa[2]) + tol))
    separated = (usable & gap).any(axis=(0, 1))
    out[idx] = ~separated
    return out


def _edge_crosses(fc, i, corner, j):
    """Whether the edge of face ``i`` opposite its corner ``corner`` crosses the interior of face ``j`` ``(P,)``.

    Both ends strictly on opposite sides of ``j``'s plane, and the crossing point strictly
    inside ``j`` (contact with its boundary does not count).
    """
    out = np.zeros(len(i), bool)
    if not len(i):
        return out
    Q = np.stack([fc.P[(corner + 1) % 3, :, i].T, fc.P[(corner + 2) % 3, :, i].T])   # (2, 3, P): the edge's ends
    eps = TOLERANCE * np.maximum(fc.size[i], fc.size[j])
    d = _plane_distances(fc, j, Q)
    cross = fc.ok[j] & (((d[0] > eps) & (d[1] < -eps)) | ((d[0] < -eps) & (d[1] > eps)))
    idx = np.flatnonzero(cross)
    if not len(idx):
        return out
    d, B, Q = d[:, idx], fc.P[:, :, j[idx]], Q[:, :, idx]
    t = d[0] / (d[0] - d[1])
    x = Q[0] + t * (Q[1] - Q[0])                                    # (3, P): the crossing point
    n = fc.cross[:, j[idx]]
    nn = _dot(n, n)
    inside = np.ones(len(idx), bool)
    for k in range(3):
        w = _dot(_cross(B[(k + 1) % 3] - B[k], x - B[k]), n) / nn   # barycentric weight of the opposite corner
        inside &= w > TOLERANCE
    out[idx] = inside
    return out
