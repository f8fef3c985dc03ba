"""Spanning trees of the dual graph for the frame-based reconstruction (thesis 3.4.2, Algorithms 1 and 2).

The frame-based reconstruction walks over the *dual graph* (faces as nodes,
interior edges as dual edges) along a spanning tree: starting at a root face
it propagates frames ``F_child = F_parent R`` (3.28) and places vertices by
(3.29).  For admissible lengths and angles every tree gives the same immersion;
for non-admissible ones the tree decides where the integrability violation
ends up.  This module builds the trees:

* :func:`bfs_tree` -- breadth-first search, Algorithm 1.  It depends on the
  connectivity and the root only and is cached on the topology.
* :func:`minimal_spanning_tree`, :func:`shortest_path_tree` -- Algorithm 2 with
  edge weights, usually the adaptive weights (3.30) of
  :func:`adaptive_edge_weights`.
* :func:`preassembled_tree` -- the remark after Algorithm 2: the weights are the
  maximum over samples of lengths and angles, so that one tree serves many
  reconstructions.
* :func:`dual_spanning_tree` -- dispatcher by ``kind``.

Conventions
-----------
A tree is a :class:`DualSpanningTree`: ``parent[f]`` is the parent face of
``f`` and ``parent_edge[f]`` the (primal) edge shared with it, both ``-1`` at a
root.  Meshes with several connected components get a spanning *forest* with
one root per component (``roots``); a root given as a single face for a mesh
with several components raises :class:`~lacore.errors.MeshError`.

Default root faces (:func:`default_root_faces`) are central and well shaped:
per component, among the faces whose dual-graph eccentricity (estimated by a
double BFS sweep) is within ``max(2, 10 %)`` of the minimum, the one with the
best shape quality ``4 sqrt(3) a / (l0^2 + l1^2 + l2^2)`` (1 for equilateral).
A central root keeps trees shallow (fewer reconstruction steps, less error
accumulation); a well-shaped root gives a well-conditioned first frame.

The violation ``|tr I_v(z) - 3|`` behind the weights (3.30) is
:func:`lacore.integrability.local.integrability_violation`.

Weights and ties
----------------
``scipy.sparse.csgraph`` drops explicit zeros, and exactly admissible targets
have (numerically) zero weights.  Every dual-edge weight therefore gets
``delta = max(1e-9 max(w), 1e-300)`` added: nothing is dropped, and among
equally good paths the ones with fewer steps are preferred (an SPT of zero
weights is a BFS tree).
"""

from bisect import bisect_left
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from ..cache import DerivedCache
from ..errors import InputError, LengthsAnglesError, MeshError, format_indices
from ..integrability.local import integrability_violation
from ..geometry.lengths_angles import check_z
from ..geometry.trigonometry import triangle_inequality_margin

__all__ = [
    "DualSpanningTree",
    "bfs_tree",
    "minimal_spanning_tree",
    "shortest_path_tree",
    "adaptive_edge_weights",
    "preassembled_tree",
    "dual_spanning_tree",
    "default_root_faces",
    "centroid_root_faces",
    "forest_levels",
    "TREE_KINDS",
    "half_theta",
    "stable_order",
    "check_roots_per_component",
]

TREE_KINDS = ("bfs", "mst", "spt")


# --------------------------------------------------------------------------- the tree
@dataclass(eq=False, repr=False)
class DualSpanningTree:
    """A rooted spanning tree (forest) of the dual graph.

    Build with :func:`bfs_tree`, :func:`minimal_spanning_tree`,
    :func:`shortest_path_tree`, :func:`preassembled_tree` or
    :meth:`from_parents`.  All arrays are read-only.

    Attributes
    ----------
    kind : str
        ``"bfs"``, ``"mst"``, ``"spt"`` or ``"custom"``.
    roots : (C,) int64
        Root face of every connected component (``C = topology.n_components``).
    parent : (F,) int64
        Parent face, ``-1`` at the roots.
    parent_edge : (F,) int64
        Primal edge shared with the parent (the dual tree edge), ``-1`` at the roots.
    depth : (F,) int64
        Number of reconstruction steps from the root (0 at the roots).
    order : (F,) int64
        Faces in level order (breadth-first order of the tree): by depth, the
        roots first; every face comes after its parent.
    level_starts : (max_depth + 2,) int64
        ``order[level_starts[d]:level_starts[d + 1]]`` are the faces of depth ``d``.
    """

    kind: str
    roots: np.ndarray
    parent: np.ndarray
    parent_edge: np.ndarray
    depth: np.ndarray
    order: np.ndarray
    level_starts: np.ndarray
    cache: DerivedCache = field(default_factory=DerivedCache, repr=False, compare=False)

    def __repr__(self):
        return (f"DualSpanningTree(kind={self.kind!r}, n_faces={self.n_faces}, roots={self.roots.tolist()[:4]}"
                f"{'...' if len(self.roots) > 4 else ''}, max_depth={self.max_depth})")

    @classmethod
    def from_parents(cls, topology, parent, kind="custom", roots=None):
        """Build a tree from a parent array, checking that it spans the dual graph.

        Parameters
        ----------
        topology : MeshTopology
        parent : (F,) array_like of int
            Parent face of every face, negative at the roots.
        kind : str
        roots : array_like of int, optional
            Expected roots (one per component); checked against ``parent``.

        Raises
        ------
        MeshError
            If a parent is not adjacent to its child, the parents contain a
            cycle, or the roots are not exactly one face per component.
        """
        F = topology.n_faces
        parent = np.asarray(parent).astype(np.int64, copy=True)
        if parent.shape != (F,):
            raise MeshError(f"parent must have shape ({F},), got {parent.shape}")
        parent[parent < 0] = -1
        if np.any(parent >= F):
            raise MeshError(f"parent faces out of range at faces {format_indices(np.flatnonzero(parent >= F))}")
        found_roots = np.flatnonzero(parent < 0)
        if roots is not None:
            roots = np.atleast_1d(np.asarray(roots, np.int64))
            if not np.array_equal(np.sort(roots), found_roots):
                raise MeshError(f"the tree's roots {format_indices(found_roots)} differ from the requested "
                                f"root faces {format_indices(roots)}")
        else:
            roots = found_roots
        check_roots_per_component(topology, roots)
        child = np.flatnonzero(parent >= 0)
        nbr = _face_neighbors(topology)
        hit = nbr[child] == parent[child, None]
        bad = ~hit.any(1)
        if np.any(bad):
            raise MeshError(f"faces {format_indices(child[bad])} are not adjacent to their parent faces")
        parent_edge = np.full(F, -1, np.int64)
        parent_edge[child] = topology.face_edges[child, np.argmax(hit, axis=1)]
        order, level_starts, depth = forest_levels(parent, roots)
        return cls._assemble(kind, parent, parent_edge, depth, order, level_starts, len(roots))

    @classmethod
    def _assemble(cls, kind, parent, parent_edge, depth, order, level_starts, n_roots):
        roots = order[:n_roots].copy()
        for a in (roots, parent, parent_edge, depth, order, level_starts):
            a.setflags(write=False)
        return cls(kind=kind, roots=roots, parent=parent, parent_edge=parent_edge, depth=depth,
                   order=order, level_starts=level_starts)

    # ------------------------------------------------------------------ views
    @property
    def n_faces(self):
        return len(self.parent)

    @property
    def root_face(self):
        """The root face (the first root if the mesh has several components)."""
        return int(self.roots[0])

    @property
    def max_depth(self):
        """Maximal number of reconstruction steps leading to a face."""
        return len(self.level_starts) - 2

    def level(self, d):
        """Faces at depth ``d``, ``(n_d,)``."""
        return self.order[self.level_starts[d]:self.level_starts[d + 1]]

    def levels(self):
        """List of the per-level face arrays, from the roots down."""
        return [self.level(d) for d in range(self.max_depth + 1)]

    @property
    def edges(self):
        """The primal edges crossed by the tree, in level order of their child faces, ``(F - C,)``."""
        return self.parent_edge[self.order[len(self.roots):]]

    def total_weight(self, edge_weights):
        """Sum of ``edge_weights`` (per primal edge, ``(E,)``) over the tree edges."""
        return float(np.asarray(edge_weights, float)[self.edges].sum())

# --------------------------------------------------------------------------- dual graph structures
def _face_neighbors(topology):
    """(F, 3) face across the edge opposite local vertex ``i`` (``-1`` on the boundary)."""
    def compute():
        ef = topology.edge_faces[topology.face_edges]                     # (F, 3, 2)
        me = np.arange(topology.n_faces)[:, None]
        return np.where(ef[..., 0] == me, ef[..., 1], ef[..., 0])
    return topology.cache.get((__name__, "face_neighbors"), compute)


def _dual_patterns(topology):
    """CSR patterns of the dual graph: symmetric (both directions) and one entry per dual edge.

    Each is ``(indptr, indices, slot)`` with ``slot`` the row of ``topology.dual_edges``
    (index into ``interior_edges``) of every stored entry, so a weighted graph is
    ``csr_matrix((w_int[slot], indices, indptr))`` without sorting.
    """
    def compute():
        F = topology.n_faces
        d = topology.dual_edges
        k = len(d)

        def pattern(rows, cols, ids):
            m = sp.csr_matrix((ids + 1.0, (rows, cols)), shape=(F, F))
            m.sort_indices()
            slot = (m.data.astype(np.int64) - 1) % max(k, 1)
            out = (m.indptr.astype(np.int32), m.indices.astype(np.int32), slot)
            for a in out:
                a.setflags(write=False)
            return out

        ids = np.arange(k, dtype=float)
        sym = pattern(np.r_[d[:, 0], d[:, 1]], np.r_[d[:, 1], d[:, 0]], np.r_[ids, ids + k])
        one = pattern(d[:, 0], d[:, 1], ids)
        return {"sym": sym, "one": one}
    return topology.cache.get((__name__, "dual_patterns"), compute)


def _dual_csr(topology, w_int=None, which="sym"):
    """Dual graph as CSR with per-dual-edge weights ``w_int`` (``(E_int,)``, default 1)."""
    indptr, indices, slot = _dual_patterns(topology)[which]
    data = np.ones(len(indices)) if w_int is None else np.take(w_int, slot)
    F = topology.n_faces
    return sp.csr_matrix((data, indices, indptr), shape=(F, F))


def _csr_from_pairs(rows, cols, n):
    """Unit-weight ``(n, n)`` CSR from index pairs (stable sort by row; columns keep their order)."""
    perm = stable_order(rows)
    indptr = np.zeros(n + 1, np.int32)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return sp.csr_matrix((np.ones(len(rows)), cols[perm].astype(np.int32), indptr), shape=(n, n))


def _with_super_root(graph, roots):
    """Append a node ``F`` with directed arcs to all ``roots`` (one search covers every component)."""
    F = graph.shape[0]
    indptr = np.r_[graph.indptr, graph.indptr[-1] + len(roots)].astype(np.int32)
    indices = np.r_[graph.indices, roots].astype(np.int32)
    data = np.r_[graph.data, np.ones(len(roots))]
    return sp.csr_matrix((data, indices, indptr), shape=(F + 1, F + 1))


def _bfs_forest(graph, roots, what="faces", directed=True):
    """Breadth-first order and predecessors (``-1`` at roots) from ``roots`` over a CSR graph.

    ``directed=False`` (one root only) follows the stored entries in both directions.
    """
    F = graph.shape[0]
    if len(roots) == 1:
        order, pred = csgraph.breadth_first_order(graph, int(roots[0]), directed=directed,
                                                  return_predecessors=True)
    else:
        order, pred = csgraph.breadth_first_order(_with_super_root(graph, roots), F, directed=True,
                                                  return_predecessors=True)
        order, pred = order[1:], pred[:F]
    pred = pred.astype(np.int64)
    pred[(pred < 0) | (pred >= F)] = -1
    if len(order) != F:
        missing = np.setdiff1d(np.arange(F), order)
        raise MeshError(f"{what} {format_indices(missing)} are not reachable from the roots "
                        "(the parents do not form a spanning forest)")
    return order.astype(np.int64), pred


def _levels_from_bfs(order, pred, n_roots):
    """Level starts and depths of a breadth-first order (parents' positions are nondecreasing).

    Level ``d + 1`` consists of the nodes whose parents lie in level ``d``, so
    its end is one binary search in the parents' positions per level.
    """
    F = len(order)
    pos = np.empty(F, np.int64)
    pos[order] = np.arange(F)
    ppos = pos.take(pred.take(order[n_roots:])).tolist()
    starts = [0, n_roots]
    while starts[-1] < F:
        nx = n_roots + bisect_left(ppos, starts[-1])
        if nx <= starts[-1]:
            raise MeshError("inconsistent breadth-first order")
        starts.append(nx)
    level_starts = np.asarray(starts, np.int64)
    depth = np.empty(F, np.int64)
    depth[order] = np.repeat(np.arange(len(level_starts) - 1), np.diff(level_starts))
    return level_starts, depth


def forest_levels(parent, roots):
    """Level order of a forest given by ``parent`` (``-1`` at the roots).

    Parameters
    ----------
    parent : (n,) int array
    roots : (C,) int array
        The nodes with ``parent == -1`` (searched from, in this order).

    Returns
    -------
    order : (n,) int64
        Breadth-first order (by depth; the roots first).
    level_starts : (max_depth + 2,) int64
    depth : (n,) int64

    Raises
    ------
    MeshError
        If some node is not reachable from the roots (the parents contain a cycle).
    """
    n = len(parent)
    child = np.flatnonzero(parent >= 0)
    graph = _csr_from_pairs(parent[child], child, n)
    order, pred = _bfs_forest(graph, np.asarray(roots, np.int64), what="nodes")
    level_starts, depth = _levels_from_bfs(order, pred, len(roots))
    return order, level_starts, depth


def stable_order(keys):
    """``argsort(keys, kind="stable")``, by radix sort for small nonnegative integer keys."""
    if keys.size and keys.min() >= 0 and keys.max() < 65536:
        return np.argsort(keys.astype(np.uint16), kind="stable")
    return np.argsort(keys, kind="stable")


def check_roots_per_component(topology, roots):
    """Check that ``roots`` are face indices, exactly one per connected component; MeshError otherwise."""
    n, labels = topology.face_components()
    roots = np.asarray(roots, np.int64)
    if roots.ndim != 1 or np.any(roots < 0) or np.any(roots >= topology.n_faces):
        raise MeshError(f"root faces must be face indices in [0, {topology.n_faces}), got {roots}")
    got = np.bincount(labels[roots], minlength=n)
    if len(roots) != n or np.any(got != 1):
        if n > 1:
            raise MeshError(f"the mesh has {n} connected components; give one root face per component "
                            f"(got {len(roots)} root faces: {format_indices(roots)}) or root_face=None")
        raise MeshError(f"a connected mesh needs exactly one root face, got {format_indices(roots)}")


def _normalize_roots(topology, root_face, z=None, vertices=None):
    """Root faces ``(C,)`` from ``root_face`` (int, sequence or None for the default)."""
    if root_face is None:
        return default_root_faces(topology, z=z, vertices=vertices)
    roots = np.atleast_1d(np.asarray(root_face))
    if not np.issubdtype(roots.dtype, np.integer):
        raise MeshError(f"root_face must be an integer face index (or one per component), got {root_face!r}")
    roots = roots.astype(np.int64)
    check_roots_per_component(topology, roots)
    return roots


# --------------------------------------------------------------------------- default root
ROOT_QUALITY_TIE = 1e-9
"""Shape qualities (in ``[0, 1]``) closer than this to the best are equal for :func:`default_root_faces`."""

ROOT_DISTANCE_TIE = 1e-6
"""Distances to the centroid closer than this fraction of the diagonal are equal for :func:`centroid_root_faces`
(mesh files often hold 7 significant digits: a symmetric mesh's mirror images are equal to about ``1e-7``)."""


def _center_scores(topology):
    """Estimated dual-graph eccentricity of every face (double BFS sweep), ``(F,)`` int64."""
    def compute():
        n, labels = topology.face_components()
        G = _dual_csr(topology)
        first = np.unique(labels, return_index=True)[1]

        def dist_from(sources):
            order, pred = _bfs_forest(G, sources)
            return _levels_from_bfs(order, pred, len(sources))[1]

        def farthest(dist):
            key = dist * (topology.n_faces + 1) - np.arange(topology.n_faces)   # max dist, then min index
            best = np.full(n, -1, np.int64)
            idx = np.lexsort((-key, labels))
            starts = np.searchsorted(labels[idx], np.arange(n))
            best[:] = idx[starts]
            return best

        a = farthest(dist_from(first))
        da = dist_from(a)
        b = farthest(da)
        db = dist_from(b)
        return np.maximum(da, db)
    return topology.cache.get((__name__, "center_scores"), compute)


def _face_quality_from_lengths(L):
    """Shape quality ``4 sqrt(3) a / sum l^2`` in ``[0, 1]`` (1 equilateral, 0 degenerate/invalid)."""
    s = -np.sort(-L, axis=1)
    a, b, c = s[:, 0], s[:, 1], s[:, 2]
    prod = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    area = 0.25 * np.sqrt(np.maximum(prod, 0.0))
    return 4.0 * np.sqrt(3.0) * area / np.maximum((L * L).sum(1), np.finfo(float).tiny)


def _central_candidates(topology):
    """Central faces per component (z-independent, cached): ``(faces, labels, scores)`` sorted by label."""
    def compute():
        score = _center_scores(topology)
        n, labels = topology.face_components()
        best = np.full(n, np.iinfo(np.int64).max)
        np.minimum.at(best, labels, score)
        slack = np.maximum(2, np.ceil(0.1 * best)).astype(np.int64)
        cand = np.flatnonzero(score <= best[labels] + slack[labels])
        cand = cand[np.lexsort((cand, score[cand], labels[cand]))]
        # at most 64 per component (the most central ones)
        first = np.searchsorted(labels[cand], np.arange(n))
        cand = cand[np.arange(len(cand)) - first[labels[cand]] < 64]
        out = (cand, labels[cand], score[cand])
        for x in out:
            x.setflags(write=False)
        return out
    return topology.cache.get((__name__, "central_candidates"), compute)


def default_root_faces(topology, z=None, vertices=None):
    """Default root face of every connected component, ``(C,)`` int64.

    Central faces first (estimated dual eccentricity within ``max(2, 10 %)`` of
    the component's minimum, at most the 64 most central ones; cached per
    topology), then the best shape quality
    ``4 sqrt(3) a / sum l^2`` among them, measured on ``vertices`` if given, else
    on the lengths of ``z``, else (no geometry) the most central face.  Using the
    reference vertices keeps the root (and thus the rigid placement) stable over
    a sequence of targets.  Qualities within :data:`ROOT_QUALITY_TIE` of the
    component's best are ties: on a regular grid every face has the same quality
    up to round-off, which would otherwise pick the face and make the placement
    depend on the unit of length and the CPU.  Ties go to the more central face
    in the dual graph: the smaller sum of dual distances to all faces of the
    component (the mean depth of a breadth-first tree from there; the tied faces
    searched 64 at a time, cached), then the smaller estimated eccentricity, then the lower
    index.  The estimate alone does not rank a grid: on a triangulated square
    grid a whole diagonal, corners included, has the least eccentricity.  Every
    comparison is between integers or within a tolerance, so the choice is the
    same in any unit and on any CPU.

    Parameters
    ----------
    topology : MeshTopology
    z : (2E,) array_like, optional
    vertices : (V, 3) array_like, optional

    Returns
    -------
    (C,) int64
        One face per connected component, in the order of the component labels.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.topology import MeshTopology
    >>> topo = MeshTopology.from_faces(np.array([[0, 1, 2], [0, 2, 3]]))
    >>> default_root_faces(topo).tolist()
    [0]
    """
    cand, labels, score = _central_candidates(topology)
    f = topology.faces[cand]
    if vertices is not None:
        quality = _face_quality(np.asarray(vertices, float), f)[0]
    elif z is not None:
        lengths = np.asarray(z, float)[:topology.n_edges]
        quality = _face_quality_from_lengths(lengths[topology.face_edges[cand]])
    else:
        quality = np.zeros(len(cand))
    quality = np.where(np.isfinite(quality), quality, -1.0)
    n = topology.n_components
    best = np.full(n, -np.inf)
    np.maximum.at(best, labels, quality)
    tied = quality >= best[labels] - ROOT_QUALITY_TIE
    total = np.zeros(len(cand))
    several = tied & (np.bincount(labels[tied], minlength=n)[labels] > 1)
    if several.any():
        total[several] = _total_distances(topology, cand[several])
    idx = np.lexsort((cand, score, total, ~tied, labels))
    starts = np.searchsorted(labels[idx], np.arange(n))
    return cand[idx[starts]].astype(np.int64)


def centroid_root_faces(topology, vertices):
    """Root face of every connected component nearest its middle, ``(C,)`` int64.

    Of the faces as well shaped as the default root (:func:`default_root_faces`,
    qualities within :data:`ROOT_QUALITY_TIE`), the one whose centroid is nearest
    the component's area-weighted centroid: among them, the face that minimizes
    the area-weighted mean squared distance to the surface.  On a regular grid
    or tube every face ties, and this is its middle (counted in steps of the
    dual graph, the most central face of a box-shaped tube lies off its middle,
    at an edge of the box); on an irregular mesh few faces tie (the default root
    and its mirror image on a symmetric one).  Distances within
    :data:`ROOT_DISTANCE_TIE` of the diagonal of the component's face centroids
    are ties, which go to the default root, else to the lower index, so the
    choice is the same in any unit and on any CPU.  Unlike
    :func:`default_root_faces` it needs vertices.

    Parameters
    ----------
    topology : MeshTopology
    vertices : (V, 3) array_like

    Returns
    -------
    (C,) int64
        One face per connected component, in the order of the component labels.

    Examples
    --------
    >>> from lacore.samples.bar import bar_mesh
    >>> from lacore.geometry.topology import MeshTopology
    >>> X, faces = bar_mesh(n_along=40, n_side=3)        # a box tube 4 x 1 x 1 along x
    >>> f = centroid_root_faces(MeshTopology.from_faces(faces), X)
    >>> abs(float(X[faces[f[0]], 0].mean() - X[:, 0].mean())) < 0.1
    True
    """
    X = np.asarray(vertices, float)
    X = X - X.mean(axis=0)                     # sums of small numbers: the same face far from the origin
    faces = topology.faces
    n, labels = topology.face_components()
    root = default_root_faces(topology, vertices=X)
    quality, area2 = _face_quality(X, faces)
    quality = np.where(np.isfinite(quality), quality, -1.0)
    area2 = np.where(np.isfinite(area2), area2, 0.0)
    C = X[faces].mean(axis=1)                                      # (F, 3) face centroids
    mass = np.maximum(np.bincount(labels, area2, n), np.finfo(float).tiny)
    centre = np.stack([np.bincount(labels, area2 * C[:, i], n) for i in range(3)], axis=1) / mass[:, None]
    d = np.linalg.norm(C - centre[labels], axis=1)
    d[~(np.abs(quality - quality[root][labels]) <= ROOT_QUALITY_TIE)] = np.inf    # (the root itself stays)
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    np.minimum.at(lo, labels, C)
    np.maximum.at(hi, labels, C)
    near = np.full(n, np.inf)
    np.minimum.at(near, labels, d)
    tied = np.flatnonzero(d <= near[labels] + ROOT_DISTANCE_TIE * np.linalg.norm(hi - lo, axis=1)[labels])
    out = np.full(n, topology.n_faces, np.int64)
    np.minimum.at(out, labels[tied], tied)
    keep = np.isin(root, tied)
    out[keep] = root[keep]
    return out


def _face_quality(X, faces):
    """Shape quality ``4 sqrt(3) a / sum l^2`` and twice the area of ``faces`` ``(k, 3)`` on ``X``, ``(k,)`` each."""
    P = X[faces]                                                   # (k, 3, 3)
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    e3 = e2 - e1
    quality = 2.0 * np.sqrt(3.0) * area2 / np.maximum(np.einsum("ij,ij->i", e1, e1) + np.einsum(
        "ij,ij->i", e2, e2) + np.einsum("ij,ij->i", e3, e3), np.finfo(float).tiny)
    return quality, area2


def _total_distances(topology, faces):
    """Sum of the dual distances from each of ``faces`` to all faces of its component, ``(k,)`` float.

    The mean depth of a breadth-first tree rooted there.  Cached per face on the
    topology (:func:`_distance_sums` for the faces not seen before).
    """
    known = topology.cache.get((__name__, "total_distances"), dict)
    new = np.array(sorted({int(f) for f in faces} - known.keys()), np.int64)
    if len(new):
        known.update(zip(new.tolist(), _distance_sums(_dual_csr(topology), new).tolist(), strict=True))
    return np.array([known[int(f)] for f in faces])


#: Each byte value's 8 bits, least significant first, ``(256, 8)`` float.
_BYTE_BITS = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1, bitorder="little").astype(float)


def _distance_sums(graph, sources):
    """Sum of the unweighted graph distances from each of ``sources`` to all nodes it reaches, ``(k,)`` float.

    A breadth-first search from 64 sources at once: every node holds a 64-bit mask of the sources that have
    reached it, and a level passes on only the bits that arrived at the level before, so nodes reached by
    all the sources within a few levels (sources close together, like the central faces of
    :func:`default_root_faces`) are visited a few times instead of 64.  Exact (integer sums); nodes a source does
    not reach count 0.

    Parameters
    ----------
    graph : scipy.sparse matrix, shape (n, n)
        Symmetric adjacency (nonzeros are edges).
    sources : (k,) array_like of int

    Examples
    --------
    >>> import scipy.sparse as sp
    >>> path = sp.diags([np.ones(3), np.ones(3)], [-1, 1], shape=(4, 4))    # 0 - 1 - 2 - 3
    >>> _distance_sums(path, [0, 1]).tolist()
    [6.0, 4.0]
    """
    G = sp.csr_matrix(graph)
    n = G.shape[0]
    deg = np.diff(G.indptr)
    nb = np.full((n + 1, max(int(deg.max()) if n else 0, 1)), n, np.int64)      # padded neighbours; n: none
    rows = np.repeat(np.arange(n), deg)
    nb[rows, np.arange(len(G.indices)) - G.indptr[rows]] = G.indices
    sources = np.asarray(sources, np.int64)
    out = np.zeros(len(sources))
    mark = np.zeros(n + 1, bool)
    for a in range(0, len(sources), 64):
        chunk = sources[a:a + 64]
        reached = np.zeros(n + 1, np.uint64)
        np.bitwise_or.at(reached, chunk, np.left_shift(np.uint64(1), np.arange(len(chunk), dtype=np.uint64)))
        arrived = reached.copy()                     # the bits that arrived at the last level
        frontier = np.unique(chunk)
        sums = np.zeros((8, 256))                   # per byte of the masks: level-weighted counts of its values
        level = 0
        while frontier.size:
            level += 1
            mark[nb[frontier]] = True
            mark[n] = False
            nxt = np.flatnonzero(mark)
            mark[nxt] = False
            bits = np.bitwise_or.reduce(arrived[nb[nxt]], axis=1) & ~reached[nxt]
            arrived[frontier] = 0
            nxt, bits = nxt[bits != 0], bits[bits != 0]
            reached[nxt] |= bits
            arrived[nxt] = bits
            octets = bits.astype("<u8").view(np.uint8).reshape(-1, 8)
            for j in range(8):
                sums[j] += level * np.bincount(octets[:, j], minlength=256)
            frontier = nxt
        out[a:a + len(chunk)] = (sums @ _BYTE_BITS).ravel()[:len(chunk)]
    return out


# --------------------------------------------------------------------------- trees
def bfs_tree(topology, root_face=None):
    """Breadth-first dual spanning tree (Algorithm 1, line 1), cached on the topology.

    Parameters
    ----------
    topology : MeshTopology
    root_face : int or sequence of int, optional
        Root face (one per connected component); default :func:`default_root_faces`
        without geometry (a central face).

    Returns
    -------
    DualSpanningTree
    """
    roots = _normalize_roots(topology, root_face)
    key = (__name__, "bfs_tree", tuple(roots.tolist()))

    def compute():
        order, pred = _bfs_forest(_dual_csr(topology), roots)
        level_starts, depth = _levels_from_bfs(order, pred, len(roots))
        return DualSpanningTree._assemble("bfs", pred, _parent_edges(topology, pred), depth, order, level_starts,
                                          len(roots))
    return topology.cache.get(key, compute)


def _parent_edges(topology, parent):
    """Primal edge shared by every face and its parent (``-1`` at the roots), ``(F,)`` int64."""
    nbr = _face_neighbors(topology)
    local = np.argmax(nbr == parent[:, None], axis=1)
    pe = topology.face_edges.ravel().take(3 * np.arange(len(parent)) + local)
    pe[parent < 0] = -1
    return pe


def _interior_weights(topology, edge_weights):
    """Validated weights of the interior edges plus the tie-breaking ``delta`` (see module docstring)."""
    w = np.asarray(edge_weights, float)
    if w.shape != (topology.n_edges,):
        raise InputError(f"edge_weights must have shape ({topology.n_edges},) (one per edge), got {w.shape}")
    wi = w[topology.interior_edges]
    bad = np.flatnonzero(~np.isfinite(wi) | (wi < 0))
    if bad.size:
        raise InputError("edge_weights must be finite and nonnegative; bad at edges "
                         f"{format_indices(topology.interior_edges[bad])}")
    top = float(wi.max()) if wi.size else 0.0
    return wi + max(1e-9 * top, 1e-300)


def minimal_spanning_tree(topology, root_face, edge_weights):
    """Minimal spanning tree of the dual graph (Algorithm 2, alternative 1).

    The tree minimizes the sum of ``edge_weights`` over its dual edges
    (Kruskal, :func:`scipy.sparse.csgraph.minimum_spanning_tree`); it is then
    rooted at ``root_face`` by a breadth-first search over the tree.

    Parameters
    ----------
    topology : MeshTopology
    root_face : int, sequence of int or None
        One root per connected component (None: :func:`default_root_faces`).
    edge_weights : (E,) array_like
        Nonnegative weight per primal edge (only interior edges are used),
        e.g. :func:`adaptive_edge_weights`.

    Returns
    -------
    DualSpanningTree
    """
    roots = _normalize_roots(topology, root_face)
    wi = _interior_weights(topology, edge_weights)
    F = topology.n_faces
    mst = csgraph.minimum_spanning_tree(_dual_csr(topology, wi, "one"))
    if len(roots) == 1:
        # one component: search the (one-directional) tree undirected, no symmetric copy needed
        order, pred = _bfs_forest(mst, roots, directed=False)
    else:
        rows = np.repeat(np.arange(F, dtype=np.int64), np.diff(mst.indptr))
        cols = mst.indices.astype(np.int64)
        order, pred = _bfs_forest(_csr_from_pairs(np.r_[rows, cols], np.r_[cols, rows], F), roots)
    level_starts, depth = _levels_from_bfs(order, pred, len(roots))
    return DualSpanningTree._assemble("mst", pred, _parent_edges(topology, pred), depth, order, level_starts,
                                      len(roots))


def shortest_path_tree(topology, root_face, edge_weights):
    """Shortest path tree of the dual graph (Algorithm 2, alternative 2).

    Every face is reached along a dual path of minimal total weight from its
    component's root (Dijkstra, :func:`scipy.sparse.csgraph.dijkstra`).

    Parameters
    ----------
    topology : MeshTopology
    root_face : int, sequence of int or None
        One root per connected component (None: :func:`default_root_faces`).
    edge_weights : (E,) array_like
        Nonnegative weight per primal edge (only interior edges are used).

    Returns
    -------
    DualSpanningTree
    """
    roots = _normalize_roots(topology, root_face)
    wi = _interior_weights(topology, edge_weights)
    G = _dual_csr(topology, wi, "sym")
    pred = csgraph.dijkstra(G, directed=True, indices=roots, return_predecessors=True, min_only=True)[1]
    pred = pred.astype(np.int64)
    pred[pred < 0] = -1
    unreached = np.setdiff1d(np.flatnonzero(pred < 0), roots)
    if unreached.size:
        raise MeshError(f"faces {format_indices(unreached)} are not reachable from the root faces")
    order, level_starts, depth = forest_levels(pred, roots)
    return DualSpanningTree._assemble("spt", pred, _parent_edges(topology, pred), depth, order, level_starts,
                                      len(roots))


# --------------------------------------------------------------------------- adaptive weights (3.30)
def half_theta(theta):
    """``(cos(theta / 2), sin(theta / 2))`` via ``t = tan(theta / 4)`` (vectorized tangent is fast)."""
    t = np.tan(0.25 * theta)
    t2 = t * t
    inv = 1.0 / (1.0 + t2)
    return (1.0 - t2) * inv, 2.0 * t * inv


def adaptive_edge_weights(z, topology):
    """Adaptive dual-edge weights (3.30), ``(E,)``.

    ``w_e = (|tr I_v(z) - 3| + |tr I_v'(z) - 3|) / 2`` for ``e = (v, v')``.  The
    violation is ``inf`` next to triangles violating the triangle inequality;
    such weights, and all three edges of such triangles, get the finite value
    ``10 max(finite w) + 1`` so that those triangles are visited last (remark
    after Algorithm 2) while the weights stay usable by the graph algorithms.

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology

    Raises
    ------
    LengthsAnglesError
        For a ``z`` of the wrong size, with NaN/inf or non-positive lengths.
    """
    z = check_z(z, topology)
    viol = integrability_violation(z, topology)
    bad = triangle_inequality_margin(z[:topology.n_edges].take(topology.face_edges)) <= 0
    ed = topology.edges
    w = viol.take(ed[:, 0])
    w += viol.take(ed[:, 1])
    w *= 0.5
    if bad.any():
        fin = np.isfinite(w)
        big = 10.0 * (float(w[fin].max()) if fin.any() else 0.0) + 1.0
        w[~fin] = big
        w[topology.face_edges[bad].ravel()] = big
    return w


def preassembled_tree(z_samples, topology, root_face=None, kind="mst"):
    """A tree reasonable for many targets: weights are the maximum over samples (remark after Algorithm 2).

    ``w~_e = max_i w_e(z_i)`` with :func:`adaptive_edge_weights`; then a minimal
    spanning or shortest path tree.  Build it once for, say, samples of an
    interpolation path and reuse it for every frame (the walk then only does
    arithmetic; its index arrays are cached on the tree).

    Parameters
    ----------
    z_samples : (n_s, 2E) array_like
        Sampled lengths and angles (e.g. the extremes of an affine subspace).
    topology : MeshTopology
    root_face : int, sequence of int or None
    kind : {"mst", "spt"}

    Returns
    -------
    DualSpanningTree
        With ``kind`` ``"mst"`` or ``"spt"``.
    """
    Z = np.asarray(z_samples, float)
    if Z.ndim == 1:
        Z = Z[None]
    if Z.ndim != 2 or Z.shape[0] == 0:
        raise LengthsAnglesError(f"z_samples must have shape (n_samples, {2 * topology.n_edges}), got {Z.shape}")
    w = np.max([adaptive_edge_weights(zi, topology) for zi in Z], axis=0)
    if kind == "mst":
        return minimal_spanning_tree(topology, root_face, w)
    if kind == "spt":
        return shortest_path_tree(topology, root_face, w)
    raise InputError(f"kind must be 'mst' or 'spt' for a preassembled tree, got {kind!r}")


def dual_spanning_tree(topology, root_face=None, kind="bfs", z=None, edge_weights=None):
    """Build a dual spanning tree of the given kind.

    Parameters
    ----------
    topology : MeshTopology
    root_face : int, sequence of int or None
        One root per connected component; None: :func:`default_root_faces`
        (quality measured on ``z`` if given).
    kind : {"bfs", "mst", "spt"}
    z : (2E,) array_like, optional
        Target lengths and angles; needed for ``"mst"``/``"spt"`` unless
        ``edge_weights`` are given (then the adaptive weights (3.30) are used).
    edge_weights : (E,) array_like, optional

    Returns
    -------
    DualSpanningTree
    """
    if kind not in TREE_KINDS:
        raise InputError(f"kind must be one of {TREE_KINDS}, got {kind!r}")
    if root_face is None:
        root_face = default_root_faces(topology, z=z)
    if kind == "bfs":
        return bfs_tree(topology, root_face)
    if edge_weights is None:
        if z is None:
            raise InputError(f"a {kind!r} tree needs the target z (for the adaptive weights 3.30) or edge_weights")
        edge_weights = adaptive_edge_weights(z, topology)
    if kind == "mst":
        return minimal_spanning_tree(topology, root_face, edge_weights)
    return shortest_path_tree(topology, root_face, edge_weights)

