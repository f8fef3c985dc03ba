"""Connectivity of an oriented triangle mesh (thesis section 1.2).

Conventions
-----------
* ``faces[f] = (p0, p1, p2)`` is counter-clockwise seen from the side the
  normal ``(X[p1]-X[p0]) x (X[p2]-X[p0])`` points to.
* Half-edge ``i`` of face ``f`` is the edge *opposite* local vertex ``i``; it runs
  from ``faces[f, (i+1) % 3]`` to ``faces[f, (i+2) % 3]``.  ``face_edges[f, i]``
  is the index of its (undirected) edge.  This matches the thesis' edge vectors
  ``E_i = X_{i-1} - X_{i+1}`` up to sign.
* Every edge ``e`` is stored oriented, ``edges[e] = (a, b)``, such that
  ``edge_faces[e, 0]`` (the *left* face) traverses it from ``a`` to ``b`` and
  ``edge_faces[e, 1]`` (the *right* face) from ``b`` to ``a``; on a boundary edge
  ``edge_faces[e, 1] == -1``.
* The one-ring of an interior vertex ``v`` is ordered counter-clockwise: if
  ``f_k = (v, a, b)`` (rotated so that ``v`` comes first), then ``f_{k+1}`` is the
  other face of the edge ``{v, b}``.
"""

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..cache import DerivedCache
from ..errors import MeshError, format_indices

__all__ = ["MeshTopology", "check_vertices", "check_faces"]


def check_faces(faces, n_vertices=None):
    """Validate a triangle index array and return it as ``(F, 3)`` int64.

    Raises
    ------
    MeshError
        For a wrong shape, out-of-range indices, repeated vertices in a face
        (degenerate faces) or faces listed twice.
    """
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"faces must have shape (F, 3), got {faces.shape}")
    if faces.shape[0] == 0:
        raise MeshError("the mesh has no faces")
    if not np.issubdtype(faces.dtype, np.integer):
        if not np.all(np.isfinite(faces)) or np.any(faces != np.round(faces)):
            raise MeshError("faces must hold integer vertex indices")
    faces = faces.astype(np.int64)
    bad = np.flatnonzero((faces < 0).any(1) | ((faces >= n_vertices).any(1) if n_vertices is not None else False))
    if bad.size:
        has = f" (mesh has {n_vertices} vertices)" if n_vertices is not None else ""
        raise MeshError(f"faces with out-of-range vertex indices{has}: faces {format_indices(bad)}")
    degenerate = np.flatnonzero((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
                                | (faces[:, 2] == faces[:, 0]))
    if degenerate.size:
        raise MeshError(f"degenerate faces (a vertex repeated): faces {format_indices(degenerate)}")
    key = np.sort(faces, axis=1)
    order = np.lexsort(key.T[::-1])
    skey = key[order]
    same = np.flatnonzero((skey[1:] == skey[:-1]).all(1))
    if same.size:
        dup = np.unique(np.r_[order[same], order[same + 1]])
        raise MeshError(f"repeated faces (same three vertices listed twice): faces {format_indices(dup)}")
    return faces


def check_vertices(vertices, n_vertices=None, name="vertices"):
    """Validate vertex coordinates and return them as ``(V, 3)`` float64.

    Raises
    ------
    MeshError
        For a wrong shape, a vertex count different from ``n_vertices`` or
        NaN/inf coordinates.

    Examples
    --------
    >>> from lacore import check_vertices
    >>> check_vertices([[0, 0, 0], [1, 0, 0], [0, 1, 0]], 3).dtype
    dtype('float64')
    """
    X = np.asarray(vertices, dtype=np.float64)
    if X.ndim == 1 and X.size % 3 == 0 and n_vertices is not None and X.size == 3 * n_vertices:
        X = X.reshape(-1, 3)
    if X.ndim != 2 or X.shape[1] != 3:
        raise MeshError(f"{name} must have shape (V, 3), got {X.shape}")
    if n_vertices is not None and X.shape[0] != n_vertices:
        raise MeshError(f"{name} has {X.shape[0]} vertices but the mesh has {n_vertices} "
                        "(meshes must be in dense correspondence)")
    bad = np.flatnonzero(~np.isfinite(X).all(1))
    if bad.size:
        raise MeshError(f"{name} has NaN or infinite coordinates at vertices {format_indices(bad)}")
    return X


@dataclass(eq=False)
class MeshTopology:
    """Edges, adjacency and one-rings of a manifold, consistently oriented triangle mesh.

    Build with :meth:`from_faces`.  All arrays are read-only views of the
    connectivity; geometry is passed separately to the functions of
    :mod:`lacore.geometry.lengths_angles`.

    Attributes
    ----------
    n_vertices, n_edges, n_faces : int
    faces : (F, 3) int64
    edges : (E, 2) int64
        Oriented edges, see the module docstring.
    edge_faces : (E, 2) int64
        Left and right face of every edge, ``-1`` for the missing right face of a boundary edge.
    face_edges : (F, 3) int64
        ``face_edges[f, i]`` is the edge opposite local vertex ``i``.
    face_edge_is_left : (F, 3) bool
        True where face ``f`` is the left face of ``face_edges[f, i]`` (traverses it along its orientation).
    is_boundary_edge : (E,) bool
    interior_edges : (E_int,) int64
    boundary_edges : (E_b,) int64
    is_boundary_vertex : (V,) bool
    interior_vertices, boundary_vertices : int64 arrays
    cache : lacore.cache.DerivedCache
        Data derived from the connectivity by lacore's modules (patterns,
        stencils, trees, contexts), keyed ``(owner module, name, *params)``.

    Examples
    --------
    Two triangles sharing the edge (1, 2):

    >>> from lacore import MeshTopology
    >>> topo = MeshTopology.from_faces([[0, 1, 2], [2, 1, 3]])
    >>> topo.n_vertices, topo.n_edges, topo.n_faces
    (4, 5, 2)
    >>> topo.edges[topo.interior_edges].tolist()
    [[1, 2]]
    >>> topo.is_closed
    False
    """

    n_vertices: int
    faces: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray
    face_edges: np.ndarray
    face_edge_is_left: np.ndarray
    corner_next: np.ndarray = field(repr=False)
    cache: DerivedCache = field(default_factory=DerivedCache, repr=False, compare=False)

    # ------------------------------------------------------------------ build
    @classmethod
    def from_faces(cls, faces, edges=None, n_vertices=None, allow_unreferenced=False):
        """Build the topology of a triangle mesh.

        Parameters
        ----------
        faces : (F, 3) array_like of int
            Triangles, consistently oriented.
        edges : (E, 2) array_like of int, optional
            A caller-given edge list whose order is kept (for instance a Blender
            mesh's edges followed by triangulation diagonals).  It must contain
            every triangle edge exactly once and nothing else.  The two vertices
            of an edge may be swapped to follow the orientation convention.
        n_vertices : int, optional
            Number of vertices; defaults to ``faces.max() + 1``.
        allow_unreferenced : bool
            If False (default) a vertex not used by any face is an error.

        Raises
        ------
        MeshError
            For out-of-range indices, degenerate or repeated faces, non-manifold
            edges or vertices, inconsistent winding, unreferenced vertices, or an
            ``edges`` list that does not match the faces.
        """
        if n_vertices is not None:
            n_vertices = int(n_vertices)
        faces = check_faces(faces, n_vertices)
        if n_vertices is None:
            n_vertices = int(faces.max()) + 1
        V, F = n_vertices, len(faces)
        if not allow_unreferenced:
            used = np.zeros(V, bool)
            used[faces.ravel()] = True
            if not used.all():
                raise MeshError(f"unreferenced vertices (used by no face): {format_indices(np.flatnonzero(~used))}")

        # half-edges: index h = 3 f + i, from faces[f, i+1] to faces[f, i+2]
        h_from = faces[:, [1, 2, 0]].ravel()
        h_to = faces[:, [2, 0, 1]].ravel()
        lo, hi = np.minimum(h_from, h_to), np.maximum(h_from, h_to)
        key = lo * V + hi
        order = np.argsort(key, kind="stable")
        skey = key[order]
        starts = np.flatnonzero(np.r_[True, skey[1:] != skey[:-1]])
        counts = np.diff(np.r_[starts, len(skey)])
        if np.any(counts > 2):
            bad = starts[counts > 2]
            pairs = np.stack([lo[order[bad]], hi[order[bad]]], 1)
            raise MeshError(f"non-manifold edges (shared by more than two faces): {format_indices(pairs)}; keep at "
                            "most two faces on each edge (delete the extra faces or split them off)")
        unique_keys = skey[starts]
        E = len(unique_keys)
        h_edge = np.empty(3 * F, np.int64)
        h_edge[order] = np.repeat(np.arange(E), counts)
        first_h = order[starts]
        second_h = np.full(E, -1, np.int64)
        two = counts == 2
        second_h[two] = order[starts[two] + 1]
        # winding: the two half-edges of an interior edge must run in opposite directions
        same_dir = two & (h_from[first_h] == h_from[np.maximum(second_h, 0)])
        if np.any(same_dir):
            bad = np.flatnonzero(same_dir)
            pairs = np.stack([lo[first_h[bad]], hi[first_h[bad]]], 1)
            raise MeshError("inconsistent winding: neighbouring faces traverse edges "
                            f"{format_indices(pairs)} in the same direction (flip faces to orient the mesh)")
        # orientation: left half-edge = the one running lo -> hi for interior edges,
        # the only one for boundary edges
        left_h = first_h.copy()
        swap = two & (h_from[first_h] != lo[first_h])
        left_h[swap] = second_h[swap]
        right_h = np.where(two, np.where(swap, first_h, second_h), -1)

        if edges is not None:
            perm = _match_edge_order(edges, unique_keys, V)
            # perm[new] = old unique index
            inv = np.empty(E, np.int64)
            inv[perm] = np.arange(E)
            h_edge = inv[h_edge]
            left_h, right_h = left_h[perm], right_h[perm]

        edge_arr = np.stack([h_from[left_h], h_to[left_h]], 1)
        edge_faces = np.stack([left_h // 3, np.where(right_h >= 0, right_h // 3, -1)], 1)
        face_edges = h_edge.reshape(F, 3)
        is_left = np.zeros(3 * F, bool)
        is_left[left_h] = True
        face_edge_is_left = is_left.reshape(F, 3)

        # corners: c = 3 f + i is vertex faces[f, i] in face f.  Next corner
        # counter-clockwise around the vertex: across half-edge (i+1) (which runs
        # from faces[f, i+2] to faces[f, i]).
        # The twin of that half-edge, in the other face g, runs from v; so it is
        # half-edge j of g with faces[g, j+1] == v, and v's corner in g is 3 g + (j+1) % 3.
        twin = np.full(3 * F, -1, np.int64)
        has = right_h >= 0
        twin[left_h[has]] = right_h[has]
        twin[right_h[has]] = left_h[has]
        across = twin[(np.arange(3 * F) // 3) * 3 + (np.arange(3 * F) + 1) % 3]
        corner_next = np.where(across >= 0, across - across % 3 + (across % 3 + 1) % 3, -1)

        topo = cls(n_vertices=V, faces=faces, edges=edge_arr, edge_faces=edge_faces,
                   face_edges=face_edges, face_edge_is_left=face_edge_is_left, corner_next=corner_next)
        topo._check_manifold_vertices()
        for a in (topo.faces, topo.edges, topo.edge_faces, topo.face_edges, topo.face_edge_is_left,
                  topo.corner_next):
            a.setflags(write=False)
        return topo

    def _check_manifold_vertices(self):
        """Raise if a vertex's incident faces form more than one fan."""
        F = self.n_faces
        src = np.flatnonzero(self.corner_next >= 0)
        g = sp.coo_matrix((np.ones(len(src)), (src, self.corner_next[src])), shape=(3 * F, 3 * F))
        n_fans, labels = connected_components(g, directed=False)
        # corners are only linked to corners of the same vertex, so each fan has one vertex
        fan_vertex = np.empty(n_fans, np.int64)
        fan_vertex[labels] = self.faces.ravel()
        fans = np.bincount(fan_vertex, minlength=self.n_vertices)
        bad = np.flatnonzero(fans > 1)
        if bad.size:
            raise MeshError("non-manifold vertices (their faces form several separate fans): "
                            f"{format_indices(bad)}; split each into one vertex per fan, or join its fans with faces")

    # ------------------------------------------------------------- counts
    @property
    def n_faces(self):
        return len(self.faces)

    @property
    def n_edges(self):
        return len(self.edges)

    # ------------------------------------------------------------- edges
    @property
    def is_boundary_edge(self):
        return self.cache.get((__name__, "is_boundary_edge"), lambda: self.edge_faces[:, 1] < 0)

    @property
    def interior_edges(self):
        return self.cache.get((__name__, "interior_edges"), lambda: np.flatnonzero(~self.is_boundary_edge))

    @property
    def boundary_edges(self):
        return self.cache.get((__name__, "boundary_edges"), lambda: np.flatnonzero(self.is_boundary_edge))

    @property
    def edge_opposite_vertices(self):
        """(E, 2) vertex opposite each edge in its left and right face (``-1`` if no right face)."""
        def compute():
            out = np.full((self.n_edges, 2), -1, np.int64)
            e = self.face_edges.ravel()
            side = np.where(self.face_edge_is_left.ravel(), 0, 1)
            out[e, side] = self.faces.ravel()
            return out
        return self.cache.get((__name__, "edge_opposite_vertices"), compute)

    @property
    def edge_local_index(self):
        """(E, 2) local index ``i`` with ``face_edges[edge_faces[e, s], i] == e`` (``-1`` if no face)."""
        def compute():
            out = np.full((self.n_edges, 2), -1, np.int64)
            e = self.face_edges.ravel()
            side = np.where(self.face_edge_is_left.ravel(), 0, 1)
            out[e, side] = np.tile(np.arange(3), self.n_faces)
            return out
        return self.cache.get((__name__, "edge_local_index"), compute)

    # ------------------------------------------------------------- vertices
    @property
    def is_boundary_vertex(self):
        def compute():
            m = np.zeros(self.n_vertices, bool)
            m[self.edges[self.boundary_edges].ravel()] = True
            return m
        return self.cache.get((__name__, "is_boundary_vertex"), compute)

    @property
    def boundary_vertices(self):
        return self.cache.get((__name__, "boundary_vertices"), lambda: np.flatnonzero(self.is_boundary_vertex))

    @property
    def interior_vertices(self):
        return self.cache.get((__name__, "interior_vertices"), lambda: np.flatnonzero(~self.is_boundary_vertex))

    @property
    def vertex_valence(self):
        """Number of faces around each vertex, (V,)."""
        return self.cache.get((__name__, "vertex_valence"),
                              lambda: np.bincount(self.faces.ravel(), minlength=self.n_vertices))

    @property
    def euler_characteristic(self):
        """``V - E + F``."""
        return self.n_vertices - self.n_edges + self.n_faces

    @property
    def is_closed(self):
        return self.boundary_edges.size == 0

    # ------------------------------------------------------------- one-rings
    def vertex_rings(self):
        """Ordered one-ring corners of all interior vertices, grouped by valence.

        Returns
        -------
        dict
            ``{n: (vertices (m,), corners (m, n))}`` where ``corners[j, k] = 3 f + i``
            is the corner of vertex ``vertices[j]`` in the k-th face of its
            counter-clockwise face loop (see module docstring).
        """
        def compute():
            inner = self.interior_vertices
            if inner.size == 0:
                return {}
            c_vertex = self.faces.ravel()
            first_corner = np.full(self.n_vertices, -1, np.int64)
            first_corner[c_vertex[::-1]] = np.arange(3 * self.n_faces)[::-1]
            valence = self.vertex_valence[inner]
            start = first_corner[inner]
            nmax = int(valence.max())
            ring = np.empty((len(inner), nmax), np.int64)
            ring[:, 0] = start
            for k in range(1, nmax):  # loop over ring position, vectorized over vertices
                ring[:, k] = self.corner_next[ring[:, k - 1]]
            groups = {}
            for n in np.unique(valence):
                sel = valence == n
                corners = np.ascontiguousarray(ring[sel, :n])
                corners.setflags(write=False)
                groups[int(n)] = (inner[sel], corners)
            return groups
        return self.cache.get((__name__, "vertex_rings"), compute)

    # ------------------------------------------------------------- dual graph
    @property
    def dual_edges(self):
        """(E_int, 2) face pairs (left, right) of the interior edges; row ``k`` is edge ``interior_edges[k]``."""
        return self.cache.get((__name__, "dual_edges"), lambda: self.edge_faces[self.interior_edges])

    def dual_graph(self, weights=None):
        """Face adjacency as a symmetric ``(F, F)`` CSR matrix.

        Parameters
        ----------
        weights : (E,) array_like, optional
            Weight per (primal) edge; default 1.  Only interior edges are used.
        """
        d = self.dual_edges
        w = np.ones(len(d)) if weights is None else np.asarray(weights, float)[self.interior_edges]
        F = self.n_faces
        return sp.csr_matrix((np.r_[w, w], (np.r_[d[:, 0], d[:, 1]], np.r_[d[:, 1], d[:, 0]])), shape=(F, F))

    # ------------------------------------------------------------- components, boundary loops
    def face_components(self):
        """Connected components of the faces: ``(n_components, labels (F,))``."""
        def compute():
            n, labels = connected_components(self.dual_graph(), directed=False)
            return n, labels
        return self.cache.get((__name__, "face_components"), compute)

    @property
    def n_components(self):
        return self.face_components()[0]

    def boundary_loops(self):
        """Boundary loops as a list of ordered vertex index arrays.

        Each loop follows the boundary edges in the direction of their faces
        (so the surface lies to the left).
        """
        def compute():
            b = self.boundary_edges
            if b.size == 0:
                return []
            start_v = self.edges[b, 0]
            end_v = self.edges[b, 1]
            pos = np.full(self.n_vertices, -1, np.int64)
            pos[start_v] = np.arange(len(b))
            nxt = pos[end_v]
            n = len(b)
            g = sp.coo_matrix((np.ones(n), (np.arange(n), nxt)), shape=(n, n))
            ncomp, labels = connected_components(g, directed=False)
            # list ranking by pointer jumping: break every cycle before its smallest member
            head = np.full(ncomp, n, np.int64)
            np.minimum.at(head, labels, np.arange(n))
            succ = nxt.copy()
            succ[np.isin(nxt, head)] = -1
            rank = (succ >= 0).astype(np.int64)
            while np.any(succ >= 0):
                has = succ >= 0
                rank[has] += rank[succ[has]]
                succ[has] = succ[succ[has]]
            order = np.lexsort((-rank, labels))
            bounds = np.searchsorted(labels[order], np.arange(ncomp + 1))
            return [start_v[order[bounds[i]:bounds[i + 1]]] for i in range(ncomp)]
        return self.cache.get((__name__, "boundary_loops"), compute)

    def genus(self):
        """Genus per face component, ``(n_components,)``, from ``chi = 2 - 2g - b``."""
        n, labels = self.face_components()
        fc = np.bincount(labels, minlength=n)
        vlab = np.zeros(self.n_vertices, np.int64)
        vlab[self.faces.ravel()] = np.repeat(labels, 3)
        vc = np.bincount(vlab, minlength=n)
        ec = np.bincount(labels[self.edge_faces[:, 0]], minlength=n)
        loops = self.boundary_loops()
        bc = np.bincount([vlab[lp[0]] for lp in loops], minlength=n) if loops else np.zeros(n, np.int64)
        chi = vc - ec + fc
        return (2 - chi - bc) // 2


def _match_edge_order(edges, unique_keys, V):
    """Permutation mapping a caller-given edge order onto the sorted unique edges."""
    edges = np.asarray(edges)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise MeshError(f"edges must have shape (E, 2), got {edges.shape}")
    edges = edges.astype(np.int64)
    if np.any(edges < 0) or np.any(edges >= V):
        raise MeshError(f"edges hold vertex indices outside [0, {V})")
    lo, hi = np.minimum(edges[:, 0], edges[:, 1]), np.maximum(edges[:, 0], edges[:, 1])
    k = lo * V + hi
    uk, cnt = np.unique(k, return_counts=True)
    if np.any(cnt > 1):
        dup = uk[cnt > 1]
        raise MeshError(f"the edge list repeats edges {format_indices(np.stack([dup // V, dup % V], 1))}")
    idx = np.searchsorted(unique_keys, k)
    idx_c = np.minimum(idx, len(unique_keys) - 1)
    missing = unique_keys[idx_c] != k
    if np.any(missing):
        bad = np.flatnonzero(missing)
        raise MeshError(f"the edge list has edges that belong to no triangle: {format_indices(edges[bad])}")
    if len(k) != len(unique_keys):
        absent = np.setdiff1d(unique_keys, k)
        raise MeshError("the edge list lacks triangle edges "
                        f"{format_indices(np.stack([absent // V, absent % V], 1))}")
    return idx
