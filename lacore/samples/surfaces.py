"""Surfaces of any genus with any number of holes, and lengths and angles that are no mesh's.

Sample data for the tests, benchmarks and demos of :mod:`lacore.integrability`
(Theorem 3.2's conditions around holes and handles).  Everything is
deterministic.

Meshes
------
* :func:`pretzel` -- a closed surface of genus ``g``: a slab of unit cubes with
  ``g`` square holes in a row, its boundary triangulated, rounded by Laplacian
  smoothing and bent (every triangle well shaped, all dihedral angles nonzero
  somewhere).  ``pretzel(0)`` is a rounded box (a sphere).
* :func:`open_holes` -- cut holes: drop the faces with a vertex in given balls
  (then faces at pinched vertices and every component but the largest).
* :func:`pretzel_with_holes` -- :func:`pretzel` with ``n`` holes on its top side:
  genus ``g`` with ``n`` boundary loops (``pretzel_with_holes(0, 1)`` is a disk,
  ``(0, 2)`` an annulus, ``(0, 3)`` a pair of pants).

Non-integrable lengths and angles
---------------------------------
Each returns ``(faces, z)`` (``z`` in the edge order of
``MeshTopology.from_faces(faces)``) of a surface whose every vertex condition
holds (every vertex ring closes) while a loop around a hole or a handle does not:

* :func:`cone_strip` -- the lengths of one strip of a cone frustum with all
  dihedral angles 0 (an annulus without interior vertices); the frames turn by
  (about) the cone's angle deficit around the hole.
* :func:`developed_cone` -- the same with several rings: the lengths of the
  planar development of a cone frustum (every interior vertex flat), all
  angles 0; the frames turn by exactly the angle deficit.
* :func:`helical_torus` -- a torus whose lengths and angles are those of a tube
  around a helix making one full turn: the frames close around both loops, the
  positions are off by the helix' pitch along the tube.
* :func:`flat_torus` -- a periodic grid with the lengths of a planar
  parallelogram and all angles 0: the frames close, the positions are off by
  the periods around both loops.
* :func:`twisted_band` -- an annulus with the lengths and angles of a straight
  band twisted by ``twist`` over its length: around the hole the frames turn by
  ``twist`` (unless it is a multiple of ``2 pi``) and the positions are off by
  the band's length.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..geometry.lengths_angles import lengths_and_angles
from ..geometry.topology import MeshTopology

__all__ = ["pretzel", "open_holes", "pretzel_with_holes", "cone_strip", "developed_cone", "helical_torus",
           "flat_torus", "twisted_band"]


# --------------------------------------------------------------------------- clean-up
def _compact(X, F, keep=None):
    """Drop unreferenced vertices: ``(vertices, faces, kept vertex indices)``."""
    used = np.zeros(len(X), bool)
    used[F.ravel()] = True
    new = np.full(len(X), -1, np.int64)
    new[used] = np.arange(np.count_nonzero(used))
    kept = np.flatnonzero(used)
    return np.ascontiguousarray(X[used]), new[F], (kept if keep is None else keep[kept])


def _pinched_faces(F, V):
    """Faces at vertices whose faces form more than one fan (edge-connected around the vertex)."""
    nF = len(F)
    # corners (f, i) and (g, j) of one vertex are linked when f and g share an edge at that vertex
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()              # half-edge (f, i): F[f, i] -> F[f, i+1]
    key = np.minimum(a, b) * V + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    same = np.flatnonzero(key[order][1:] == key[order][:-1])
    h, k = order[same], order[same + 1]                           # paired half-edges
    f, i, g, j = h // 3, h % 3, k // 3, k % 3
    # corner of the half-edge's start vertex in f pairs with the corner of the same vertex in g
    c1 = np.r_[3 * f + i, 3 * f + (i + 1) % 3]
    start_g = np.where(F[g, j] == F[f, i], j, (j + 1) % 3)
    end_g = np.where(start_g == j, (j + 1) % 3, j)
    c2 = np.r_[3 * g + start_g, 3 * g + end_g]
    n, labels = connected_components(sp.coo_matrix((np.ones(len(c1)), (c1, c2)), shape=(3 * nF, 3 * nF)),
                                     directed=False)
    fan_vertex = np.empty(n, np.int64)
    fan_vertex[labels] = F.ravel()
    pinched = np.flatnonzero(np.bincount(fan_vertex, minlength=V) > 1)
    return np.flatnonzero(np.isin(F, pinched).any(axis=1))


def _largest_component(F, V):
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    n, labels = connected_components(sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(V, V)), directed=False)
    flab = labels[F[:, 0]]
    return F[flab == np.argmax(np.bincount(flab, minlength=n))]


def open_holes(vertices, faces, centers, radius):
    """Cut holes: drop the faces with a vertex within ``radius`` of any center.

    Faces at vertices left pinched (two fans) are dropped as well, then every
    connected component but the largest; unreferenced vertices are removed.

    Returns
    -------
    vertices : (V', 3) ndarray
    faces : (F', 3) int64 ndarray
    kept : (V',) int64 ndarray
        Index of every remaining vertex in ``vertices``.
    """
    X = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    inside = np.zeros(len(X), bool)
    for c in np.atleast_2d(np.asarray(centers, float)):
        inside |= np.einsum("ij,ij->i", X - c, X - c) < radius * radius
    F = F[~inside[F].any(axis=1)]
    for _ in range(len(F)):
        bad = _pinched_faces(F, len(X))
        if bad.size == 0:
            break
        F = np.delete(F, bad, axis=0)
    return _compact(X, _largest_component(F, len(X)))


# --------------------------------------------------------------------------- closed surfaces of any genus
def _voxel_surface(mask):
    """Outward-oriented triangulated boundary of a union of unit cubes ``mask[i, j, k]``."""
    M = np.pad(np.asarray(mask, bool), 1)
    I, J, K = np.nonzero(M)
    quads = []
    for axis in range(3):
        for s in (1, -1):
            d = np.zeros(3, np.int64)
            d[axis] = s
            free = ~M[I + d[0], J + d[1], K + d[2]]
            base = np.stack([I[free], J[free], K[free]], 1) + (d > 0)
            u, v = np.zeros(3, np.int64), np.zeros(3, np.int64)
            u[(axis + 1) % 3], v[(axis + 2) % 3] = 1, 1
            if s < 0:
                u, v = v, u
            quads.append(np.stack([base, base + u, base + u + v, base + v], 1))
    Q = np.concatenate(quads)
    points, inverse = np.unique(Q.reshape(-1, 3), axis=0, return_inverse=True)
    Qi = inverse.reshape(-1, 4)
    alt = (Q[:, 0].sum(axis=1) % 2).astype(bool)[:, None]          # alternate the diagonals
    F = np.concatenate([np.where(alt, Qi[:, [0, 1, 2]], Qi[:, [0, 1, 3]]),
                        np.where(alt, Qi[:, [0, 2, 3]], Qi[:, [1, 2, 3]])])
    return points.astype(float), F.astype(np.int64)


def _smooth(X, F, iterations, lam=0.5):
    V = len(X)
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    A = sp.csr_matrix((np.ones(2 * len(a)), (np.r_[a, b], np.r_[b, a])), shape=(V, V))
    A.data[:] = 1.0
    deg = np.asarray(A.sum(axis=1)).ravel()
    for _ in range(iterations):
        X = (1.0 - lam) * X + lam * (A @ X) / deg[:, None]
    return X


def pretzel(genus, cells=6, thickness=2, smoothing=8):
    """A closed surface of genus ``genus``: ``(vertices (V, 3), faces (F, 3))``, outward oriented.

    A slab of ``(2 genus + 1) cells x 3 cells x thickness`` unit cubes with
    ``genus`` square holes of ``cells x cells`` in a row, its surface split into
    triangles, smoothed (``smoothing`` Laplacian steps), scaled to unit width and
    bent.  The vertex count grows like ``cells^2`` (``cells=6``: about 400 per
    handle; ``pretzel(3, cells=30)``: about 25k).
    """
    h = int(cells)
    mask = np.ones(((2 * genus + 1) * h, 3 * h, int(thickness)), bool)
    for g in range(genus):
        mask[h + 2 * h * g:2 * h + 2 * h * g, h:2 * h, :] = False
    X, F = _voxel_surface(mask)
    X = _smooth(X, F, smoothing)
    X = (X - X.mean(axis=0)) / (3 * h)
    x, y, z = X.T
    X = np.stack([x + 0.05 * np.sin(3 * y), y + 0.1 * x * x, z + 0.2 * np.cos(1.3 * x) + 0.05 * np.sin(4 * y)], 1)
    return np.ascontiguousarray(X), F


def pretzel_with_holes(genus, n_holes, cells=6, radius=0.04):
    """:func:`pretzel` with ``n_holes`` holes cut on its top side, spread along its length.

    ``radius`` is relative to the diagonal of the bounding box.  Returns
    ``(vertices, faces)``: genus ``genus`` with ``n_holes`` boundary loops.
    """
    X, F = pretzel(genus, cells)
    top = np.flatnonzero(X[:, 2] > np.percentile(X[:, 2], 70))
    xs = X[top, 0]
    centers = [X[top[np.argmin(np.abs(xs - np.quantile(xs, q)))]] for q in np.linspace(0.1, 0.9, n_holes)]
    Xo, Fo, _ = open_holes(X, F, centers, radius * np.linalg.norm(X.max(axis=0) - X.min(axis=0)))
    return Xo, Fo


# --------------------------------------------------------------------------- non-integrable lengths and angles
def _grid_faces(rows, cols, wrap_rows, wrap_cols, index):
    """Two triangles per grid cell ``(i, j)``; ``index(i, j)`` numbers the vertices."""
    ni, nj = rows - (0 if wrap_rows else 1), cols - (0 if wrap_cols else 1)
    i, j = np.meshgrid(np.arange(ni), np.arange(nj), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a00, a10, a01, a11 = index(i, j), index(i + 1, j), index(i, j + 1), index(i + 1, j + 1)
    return np.concatenate([np.stack([a00, a10, a11], 1), np.stack([a00, a11, a01], 1)]).astype(np.int64)


def _z_from_cover(faces, cover_vertices, cover_faces, cover_to_base):
    """Lengths and angles on ``faces`` read off a covering mesh (interior edges from interior covering edges)."""
    topo = MeshTopology.from_faces(faces)
    ct = MeshTopology.from_faces(cover_faces, n_vertices=len(cover_vertices))
    zc = lengths_and_angles(cover_vertices, ct)
    E, Ec, V = topo.n_edges, ct.n_edges, topo.n_vertices
    ce = cover_to_base[ct.edges]
    ckey = np.minimum(ce[:, 0], ce[:, 1]) * V + np.maximum(ce[:, 0], ce[:, 1])
    bkey = np.minimum(topo.edges[:, 0], topo.edges[:, 1]) * V + np.maximum(topo.edges[:, 0], topo.edges[:, 1])
    order = np.argsort(bkey)
    pos = np.minimum(np.searchsorted(bkey[order], ckey), E - 1)
    hit = bkey[order][pos] == ckey
    z = np.full(2 * E, np.nan)
    for use in (hit, hit & ~ct.is_boundary_edge):            # interior representatives win
        z[order[pos[use]]] = zc[:Ec][use]
        z[E + order[pos[use]]] = zc[Ec:][use]
    z[E + topo.boundary_edges] = 0.0
    if not np.all(np.isfinite(z)):
        raise RuntimeError("the covering mesh misses edges")
    return z


def _periodic(n_rows, n_cols, wrap_cols, rows_of_cover, cover):
    """Faces of an ``n_rows`` x ``n_cols`` grid periodic in the rows (and in the columns if ``wrap_cols``), and
    ``z`` from ``cover(row, col) -> (..., 3)`` evaluated on rows ``rows_of_cover`` (beyond the period)."""
    faces = _grid_faces(n_rows, n_cols, True, wrap_cols, lambda i, j: (i % n_rows) * n_cols + j % n_cols)
    cols = np.arange(-1, n_cols + 2) if wrap_cols else np.arange(n_cols)
    R, Cc = np.meshgrid(rows_of_cover, cols, indexing="ij")
    Xc = cover(R, Cc).reshape(-1, 3)
    nr, nc = R.shape
    cover_faces = _grid_faces(nr, nc, False, False, lambda i, j: i * nc + j)
    base = (np.mod(R, n_rows) * n_cols + np.mod(Cc, n_cols)).ravel()
    return faces, _z_from_cover(faces, Xc, cover_faces, base)


def cone_strip(n_around=24, r0=1.0, r1=2.0, height=1.0):
    """One strip of a cone frustum (two rings, no interior vertex) with all dihedral angles set to 0.

    Returns ``(faces, z)``.  No vertex condition applies; the frames turn by
    about the cone's angle deficit ``2 pi (1 - (r1 - r0) / slant)`` around the hole.
    """
    phi = 2.0 * np.pi * np.arange(n_around) / n_around
    X = np.concatenate([np.stack([r * np.cos(phi + 0.5 * t), r * np.sin(phi + 0.5 * t), np.full(n_around, height * t)],
                                 1) for t, r in ((0.0, r0), (1.0, r1))])
    faces = _grid_faces(n_around, 2, True, False, lambda i, j: j * n_around + i % n_around)
    topo = MeshTopology.from_faces(faces)
    z = lengths_and_angles(X, topo)
    z[topo.n_edges:] = 0.0
    return faces, z


def developed_cone(n_around=24, n_rings=5, r0=1.0, r1=2.0, height=1.0):
    """An annulus with the lengths of a developed cone frustum and all angles 0: ``(faces, z, deficit)``.

    The planar development of the frustum (an annular sector of angle
    ``2 pi sin(a)``, ``sin(a) = (r1 - r0) / slant``) is triangulated on a polar
    grid, so every interior vertex is flat; glued to an annulus the frames turn
    by ``deficit = 2 pi (1 - sin(a))`` around the hole.
    """
    sin_a = (r1 - r0) / np.hypot(r1 - r0, height)
    rho = np.linspace(r0, r1, n_rings) / sin_a
    sector = 2.0 * np.pi * sin_a

    def cover(j, i):
        p = sector * j / n_around
        r = rho[i]
        return np.stack([r * np.cos(p), r * np.sin(p), np.zeros_like(p)], -1)
    faces, z = _periodic(n_around, n_rings, False, np.arange(-1, n_around + 2), cover)
    return faces, z, 2.0 * np.pi - sector


def helical_torus(n_along=48, n_around=12, radius=0.3, helix_radius=1.0, pitch=1.5, turns=1.0):
    """A torus with the lengths and angles of a tube around a helix (``turns`` turns per period): ``(faces, z)``.

    Vertex ``i n_around + j`` is point ``j`` of ring ``i`` along the tube.  With
    a whole number of turns the frames close around both loops and only the
    positions are off (by ``turns * pitch`` along the helix axis).
    """
    def cover(i, j):
        s = 2.0 * np.pi * turns * i / n_along
        c = np.stack([helix_radius * np.cos(s), helix_radius * np.sin(s), pitch * turns * i / n_along], -1)
        t = np.stack([-helix_radius * np.sin(s), helix_radius * np.cos(s),
                      np.full_like(s, pitch / (2.0 * np.pi))], -1)
        t /= np.linalg.norm(t, axis=-1, keepdims=True)
        nrm = np.stack([-np.cos(s), -np.sin(s), np.zeros_like(s)], -1)
        b = np.cross(t, nrm)
        p = 2.0 * np.pi * j / n_around
        return c + radius * (np.cos(p)[..., None] * nrm + np.sin(p)[..., None] * b)
    return _periodic(n_along, n_around, True, np.arange(-1, n_along + 2), cover)


def flat_torus(n_rows=16, n_cols=12, period_rows=(4.0, 0.3), period_cols=(0.0, 2.1)):
    """A periodic grid with the lengths of a planar lattice and all angles 0: ``(faces, z)``.

    The frames close around both loops; the positions are off by the periods.
    """
    a, b = np.asarray(period_rows, float), np.asarray(period_cols, float)

    def cover(i, j):
        p = (i / n_rows)[..., None] * a + (j / n_cols)[..., None] * b
        return np.concatenate([p, np.zeros(p.shape[:-1] + (1,))], -1)
    return _periodic(n_rows, n_cols, True, np.arange(-1, n_rows + 2), cover)


def twisted_band(n_along=40, n_across=4, length=6.0, width=1.0, twist=np.pi / 2):
    """An annulus with the lengths and angles of a straight band twisted by ``twist`` over its length:
    ``(faces, z)``.  With ``twist = 0`` (a flat strip) the frames close and only the positions are off."""
    u = np.linspace(-0.5 * width, 0.5 * width, n_across)

    def cover(i, j):
        s = i / n_along
        return np.stack([length * s, np.cos(twist * s) * u[j], np.sin(twist * s) * u[j]], -1)
    return _periodic(n_along, n_across, False, np.arange(-1, n_along + 2), cover)
