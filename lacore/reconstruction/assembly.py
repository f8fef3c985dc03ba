"""Sparsity pattern and assembly of the Gauss-Newton matrix ``J^T W J`` (thesis 3.4.1).

The pattern of ``J^T W J`` (3x3 blocks for every pair of vertices of an edge's
two triangles) and, for every entry of every local outer product ``g_e g_e^T``
(6x6 for a length row, 12x12 for an angle row), its slot in the
lower-triangular CSC value array are computed once per topology
(:func:`gauss_newton_pattern`).  An iteration forms the outer products
component-major (contiguous over all edges, :func:`upper_outer`) and sums them
with one :func:`numpy.bincount`, directly in the factorization's value order
(timed by ``benchmarks/bench_gauss_newton.py``).

The fixed coordinates keep their rows and columns in the pattern (set to the
identity by the Gauss-Newton loop), so the pattern and its symbolic Cholesky
factorization do not depend on the fixed face.
"""

import numpy as np
import scipy.sparse as sp

from ..geometry.lengths_angles import jacobian_pattern
from ..linalg.sparse_cholesky import vertex_ordering

__all__ = ["gauss_newton_pattern", "upper_outer", "dof_ordering", "coupled_vertex_graph"]

_I6, _J6 = np.triu_indices(6)
_I12, _J12 = np.triu_indices(12)


def gauss_newton_pattern(topology):
    """Sparsity pattern of the Gauss-Newton matrix and the assembly slots (cached per topology).

    Returns
    -------
    dict with
        ``indptr, indices, cols`` : lower-triangular CSC structure of the
        ``(3V, 3V)`` matrix (sorted rows per column, full diagonal) and the
        column of every entry; ``matrix``: the pattern as a CSC matrix of ones;
        ``local_order``: gather from the CSR data of
        :func:`~lacore.geometry.lengths_angles.lengths_and_angles_jacobian` to the local
        gradients in component-major layout, ``(6, E)`` (length rows: ``x0, x1``
        times ``xyz``) followed by ``(12, E_int)`` (angle rows: ``x0..x3``);
        ``slots``: position in the value array of every upper-triangle pair
        ``(i <= j)`` of every local outer product, in the same layout: ``(21, E)``
        then ``(78, E_int)``, pairs in ``np.triu_indices`` order; ``nnz``, ``n``;
        ``len_cols`` ``(6, E)`` and ``ang_cols`` ``(12, E_int)``: the global
        coordinate of every local coordinate of the length and angle rows.
    """
    def compute():
        n = 3 * topology.n_vertices
        E, Ei = topology.n_edges, len(topology.interior_edges)
        jp = jacobian_pattern(topology)
        inv = np.empty_like(jp["order"])
        inv[jp["order"]] = np.arange(len(jp["order"]))  # CSR position of local value k (edge-major)
        local_order = np.concatenate([inv[: 6 * E].reshape(E, 6).T.ravel(), inv[6 * E:].reshape(Ei, 12).T.ravel()])
        xyz = np.arange(3)
        len_cols = (3 * topology.edges[:, [0, 0, 0, 1, 1, 1]] + np.tile(xyz, 2)).T   # (6, E)
        ang_cols = (3 * np.repeat(jp["quad"], 3, axis=1) + np.tile(xyz, 4)).T     # (12, E_int)
        V = topology.n_vertices
        # the quad of an interior edge couples its ends and opposite vertices: the mesh edges and the pair of
        # opposite vertices; the slots of both element kinds fill one array (no concatenated copy)
        structure = _VertexBlockStructure(V, (np.r_[topology.edges[:, 0], jp["quad"][:, 2]],
                                              np.r_[topology.edges[:, 1], jp["quad"][:, 3]]))
        slots = np.empty(len(_I6) * E + len(_I12) * Ei, np.intp)
        structure.slots(topology.edges, _I6, _J6, out=slots[:len(_I6) * E].reshape(len(_I6), E))
        structure.slots(jp["quad"], _I12, _J12, out=slots[len(_I6) * E:].reshape(len(_I12), Ei))
        indptr, indices, ucols = structure.indptr, structure.indices, structure.cols
        matrix = sp.csc_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
        return {"indptr": indptr, "indices": indices, "cols": ucols, "matrix": matrix, "slots": slots,
                "local_order": local_order, "nnz": len(indices), "n": n, "len_cols": len_cols, "ang_cols": ang_cols,
                "vertex_pairs": structure.pairs()}
    return topology.cache.get((__name__, "gauss_newton_pattern"), compute)


class _VertexBlockStructure:
    """Lower-CSC structure of a ``(3V, 3V)`` matrix made of 3x3 blocks, one per coupled vertex pair.

    Built from the vertex pairs alone (a few per element instead of the 21 or 78
    coordinate pairs of its outer product): every vertex gets its diagonal block;
    column ``3u + a`` holds rows ``3u + a .. 3u + 2`` of the diagonal block, then
    the 3 rows of every coupled vertex ``w > u`` in increasing ``w``.
    """

    def __init__(self, n_vertices, pairs):
        V = n_vertices
        lo, hi = np.minimum(pairs[0], pairs[1]), np.maximum(pairs[0], pairs[1])
        keys = np.concatenate([lo.astype(np.int64) * V + hi, np.arange(V, dtype=np.int64) * (V + 1)])
        keys.sort()                                   # a sort and a comparison: faster than np.unique here
        keys = keys[np.r_[True, keys[1:] != keys[:-1]]]
        self.V, self.keys = V, keys
        pu, pw = keys // V, keys % V
        self.group_start = np.searchsorted(pu, np.arange(V))          # index of (u, u) in keys
        degree = np.bincount(pu, minlength=V) - 1                     # coupled vertices w > u
        counts = (3 - np.arange(3))[None, :] + 3 * degree[:, None]    # (V, 3) entries of column 3u + a
        self.indptr = np.r_[0, np.cumsum(counts.ravel())].astype(np.int64)
        indices = np.empty(int(self.indptr[-1]), np.int64)
        for alpha in range(3):
            for beta in range(3):   # every entry of an off-diagonal block, the lower triangle of a diagonal one
                sel = np.flatnonzero((pu != pw) | (beta >= alpha))
                indices[self.position(sel, pu[sel], pw[sel], alpha, beta)] = 3 * pw[sel] + beta
        self.indices = indices
        self.cols = np.repeat(np.arange(3 * V), counts.ravel())

    def position(self, pair, u, w, alpha, beta):
        """Value-array position of row ``3 w + beta``, column ``3 u + alpha`` (``u <= w``; ``beta >= alpha`` if
        ``u == w``) of the vertex pair with index ``pair`` in :attr:`keys`."""
        start = self.indptr[3 * u + alpha]
        return np.where(u == w, start + beta - alpha, start + (3 - alpha) + 3 * (pair - self.group_start[u] - 1)
                        + beta)

    def pairs(self):
        """``(2, P)`` the coupled vertex pairs ``u < w`` (the off-diagonal blocks), in column order."""
        u, w = self.keys // self.V, self.keys % self.V
        off = u != w
        return np.stack([u[off], w[off]])

    def slots(self, element_vertices, ii, jj, out=None):
        """Positions of the upper-triangle pairs ``(ii, jj)`` of every element's local outer product.

        ``element_vertices`` ``(m, k)``: the vertices of ``m`` elements, whose local coordinate ``3 a + c``
        is coordinate ``c`` of vertex ``a``; ``ii <= jj`` index local coordinates.  Returns
        ``(len(ii), m)`` (into ``out`` when given).  Works per vertex pair of an element (one search each),
        then per coordinate pair with vectors over the elements.
        """
        el = np.asarray(element_vertices, np.int64)
        m = el.shape[0]
        out = np.empty((len(ii), m), np.intp) if out is None else out
        bases = {}
        for r, (p, q) in enumerate(zip(ii, jj, strict=True)):
            a, b, cp, cq = p // 3, q // 3, p % 3, q % 3
            if (a, b) not in bases:
                va, vb = el[:, a], el[:, b]
                u, w = np.minimum(va, vb), np.maximum(va, vb)
                if a == b:   # diagonal block of vertex u: column 3u + alpha starts with rows 3u + alpha..
                    bases[a, b] = (None, [self.indptr[3 * u + c] - c for c in range(3)])
                else:
                    rank = np.searchsorted(self.keys, u * self.V + w) - self.group_start[u] - 1
                    bases[a, b] = (va < vb, [self.indptr[3 * u + c] + (3 - c) + 3 * rank for c in range(3)])
            less, base = bases[a, b]
            if less is None:
                out[r] = base[min(cp, cq)] + max(cp, cq)
            else:
                out[r] = np.where(less, base[cp] + cq, base[cq] + cp)
        return out


def upper_outer(g, gw, out):
    """Upper triangles of the outer products of the columns of ``gw`` and ``g`` into ``out``.

    ``g, gw`` have shape ``(k, m)`` (component-major: row ``i`` holds local
    component ``i`` of all ``m`` gradients); ``out`` gets shape
    ``(k (k + 1) / 2, m)`` with rows in ``np.triu_indices(k)`` order,
    ``out[(i, j)] = gw[i] * g[j]``.  Loops over the ``k`` (6 or 12) components,
    vectorized and contiguous over all gradients.
    """
    k = g.shape[0]
    r = 0
    for i in range(k):
        np.multiply(gw[i], g[i:], out=out[r:r + k - i])
        r += k - i
    return out


def dof_ordering(topology, pattern, vertices, method=None):
    """Fill-reducing ordering of the coordinates, 3 per vertex, from a vertex ordering of the coupled vertices.

    The vertex order is :func:`lacore.linalg.sparse_cholesky.vertex_ordering` (``method``: ``"metis"``,
    ``"geometric"``, default METIS when pymetis is importable) of the graph of vertex pairs the pattern
    couples; the geometric one dissects ``vertices``.

    Returns
    -------
    order : (3V,) int64 ndarray
    method : str
        The method used.
    """
    order, method = vertex_ordering(coupled_vertex_graph(pattern, topology.n_vertices), vertices, method)
    return (3 * order[:, None] + np.arange(3)).ravel(), method


def coupled_vertex_graph(pattern, n_vertices):
    """``(V, V)`` symmetric CSR adjacency of the vertices a Gauss-Newton pattern couples (diagonal included)."""
    if "vertex_pairs" not in pattern:
        rows, cols = pattern["indices"] // 3, pattern["cols"] // 3
        G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
        return (G + G.T).tocsr()
    u, w = pattern["vertex_pairs"]
    diagonal = np.arange(n_vertices)
    rows, cols = np.r_[u, w, diagonal], np.r_[w, u, diagonal]
    order = np.lexsort((cols, rows))               # CSR order without scipy summing duplicates (there are none)
    indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n_vertices))]
    G = sp.csr_matrix((np.ones(len(rows)), cols[order], indptr), shape=(n_vertices, n_vertices))
    G.has_sorted_indices = True
    return G

