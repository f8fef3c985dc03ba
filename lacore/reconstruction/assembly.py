"""Sparsity pattern and assembly of the Gauss-Newton matrix ``J^T W J`` (thesis 3.4.1).

The pattern of ``J^T W J`` (3x3 blocks for every pair of vertices of an edge's
two triangles) and, for every entry of every local outer product ``g_e g_e^T``
(6x6 for a length row, 12x12 for an angle row), its slot in the
lower-triangular CSC value array are computed once per topology
(:func:`gauss_newton_pattern`).  An iteration forms the outer products
component-major (contiguous over all edges, :func:`upper_outer`) and sums them
with one :func:`numpy.bincount`, directly in the factorization's value order
(timings: ``benchmarks/bench_gauss_newton.py``, README "Reconstruction").

The fixed coordinates keep their rows and columns in the pattern (set to the
identity by the Gauss-Newton loop), so the pattern and its symbolic Cholesky
factorization do not depend on the fixed face.
"""

import numpy as np
import scipy.sparse as sp

from ..lengths_angles import jacobian_pattern
from ..sparse_cholesky import nested_dissection

__all__ = ["gauss_newton_pattern", "upper_outer", "dof_ordering"]

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
        :func:`~lacore.lengths_angles.lengths_and_angles_jacobian` to the local
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
        rows = np.concatenate([np.maximum(len_cols[_I6], len_cols[_J6]).ravel(),
                               np.maximum(ang_cols[_I12], ang_cols[_J12]).ravel()])
        cols = np.concatenate([np.minimum(len_cols[_I6], len_cols[_J6]).ravel(),
                               np.minimum(ang_cols[_I12], ang_cols[_J12]).ravel()])
        keys = cols * n + rows
        diag = np.arange(n) * (n + 1)  # every coordinate gets a diagonal entry
        ukeys, inverse = np.unique(np.concatenate([keys, diag]), return_inverse=True)
        slots = inverse.ravel()[: len(keys)].astype(np.intp)
        indices = (ukeys % n).astype(np.int64)
        ucols = ukeys // n
        indptr = np.r_[0, np.cumsum(np.bincount(ucols, minlength=n))].astype(np.int64)
        matrix = sp.csc_matrix((np.ones(len(ukeys)), indices, indptr), shape=(n, n))
        return {"indptr": indptr, "indices": indices, "cols": ucols, "matrix": matrix, "slots": slots,
                "local_order": local_order, "nnz": len(ukeys), "n": n, "len_cols": len_cols, "ang_cols": ang_cols}
    return topology.cache.get((__name__, "gauss_newton_pattern"), compute)


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


def dof_ordering(topology, pattern, vertices):
    """Nested-dissection ordering of the coordinates: vertex order from the mesh geometry, 3 coordinates each."""
    V = topology.n_vertices
    rows, cols = pattern["indices"] // 3, pattern["cols"] // 3
    G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(V, V))
    order = nested_dissection(G + G.T, vertices)
    return (3 * order[:, None] + np.arange(3)).ravel()

