"""Two-level preconditioner for the fine Gauss-Newton system (coarse Galerkin correction + block Jacobi).

The fine Gauss-Newton matrix ``A = 2 J^T W J`` (``3V x 3V``, gauge
coordinates fixed) is never factorized.  Conjugate gradients are
preconditioned by one symmetric two-level cycle (algebraic multigrid with a
geometric interpolation)::

    x  = S(r)                        nu sweeps of damped block Jacobi, from 0
    x += P A_c^{-1} P^T (r - A x)    coarse-grid correction, A_c = P^T A P
    x += S(r - A x)                  nu sweeps of damped block Jacobi

``P = I_3 (x) P_s`` interpolates coarse vertex displacements to fine ones:
``P_s`` (``V x Vc``, :func:`interpolation_matrix`) is the identity on the kept
vertices and gives every removed vertex the mean displacement of its ring at
the time of its collapse (recursively, in the order :class:`~.prolongation.
Prolongation` re-inserts them: the linear part of that prolongation without
the rotation of the detail).  The smoother is ``omega D^{-1}`` with ``D`` the
3x3 diagonal blocks of ``A``.  Pre- and post-smoothing are the same
symmetric operator, so the cycle is a symmetric positive definite
preconditioner as long as the smoother converges (``omega`` below
``2 / rho(D^{-1} A)``).  ``A_c`` (``3 Vc``) is factorized per Gauss-Newton
step, its symbolic analysis once.
"""

import numpy as np
import scipy.sparse as sp

from ..linalg.sparse_cholesky import SparseCholesky

__all__ = ["interpolation_matrix", "TwoLevelPreconditioner"]


def interpolation_matrix(coarsening, levels, max_row_entries=4):
    """Scalar interpolation ``P_s`` (V, Vc) of coarse vertex values to fine vertices.

    Parameters
    ----------
    coarsening : Coarsening
    levels : list
        ``Prolongation._level_data``: per insertion level the collapse indices,
        removed vertices ``u``, ring corner pairs and segment offsets.
    max_row_entries : int
        Every row is truncated to its largest entries (then rescaled to sum
        1) after each level: the recursive ring means spread over ~27 coarse
        vertices per row on a bar, which makes ``P^T A P`` dense; with 4 the
        Galerkin product and the coarse factorization are several times
        cheaper.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (V, Vc)
        Rows sum to 1 (constants are reproduced); row ``vertex_indices[i]`` is
        the unit vector ``e_i``.
    """
    c = coarsening
    V, Vc = c.n_fine_vertices, c.n_vertices
    P = sp.csr_matrix((np.ones(Vc), (c.vertex_indices, np.arange(Vc))), shape=(V, Vc))
    for _, u, _, pr, _seg, sizes in levels:
        k = len(u)
        rows = np.repeat(np.repeat(np.arange(k), sizes), 2)
        w = np.repeat(np.repeat(0.5 / sizes, sizes), 2)
        avg = sp.csr_matrix((w, (rows, pr.ravel())), shape=(k, V))
        new = (avg @ P).tocsr()
        new = _truncate_rows(new, max_row_entries).tocoo()
        P = P + sp.csr_matrix((new.data, (u[new.row], new.col)), shape=(V, Vc))
    return P.tocsr()


def _truncate_rows(M, m):
    """Keep the ``m`` largest entries of every row of a CSR matrix with non-negative entries; rows sum to 1."""
    M.sort_indices()
    counts = np.diff(M.indptr)
    row = np.repeat(np.arange(M.shape[0]), counts)
    order = np.lexsort((-M.data, row))  # by row, largest first
    rank = np.arange(len(order)) - np.repeat(M.indptr[:-1], counts)
    keep = order[rank < m]
    data = M.data[keep]
    rows = row[keep]
    sums = np.bincount(rows, weights=data, minlength=M.shape[0])
    return sp.csr_matrix((data / sums[rows], (rows, M.indices[keep])), shape=M.shape)


class TwoLevelPreconditioner:
    """``r -> M^{-1} r`` by one symmetric two-level cycle (see the module docstring).

    Parameters
    ----------
    interpolation : (V, Vc) sparse matrix
        Scalar interpolation ``P_s`` (:func:`interpolation_matrix`).
    fixed : (k,) int array
        Fixed fine coordinates (flat ``3 v + axis``).
    smoothing_steps : int
        Block-Jacobi sweeps before and after the coarse correction.
    omega : float
        Jacobi damping.
    backend : str, optional
        Sparse Cholesky backend of the coarse matrix.

    Notes
    -----
    :meth:`update` takes the fine matrix of each Gauss-Newton step and
    factorizes ``A_c``; the coarse symbolic analysis is made on the first call
    and reused (the pattern of ``P^T A P`` depends only on the meshes).
    """

    def __init__(self, interpolation, fixed, *, smoothing_steps=2, omega=0.6, backend=None):
        Ps = sp.csr_matrix(interpolation)
        V, Vc = Ps.shape
        self.n = 3 * V
        P = sp.kron(Ps, sp.eye(3), format="csr")
        keep = np.ones(3 * V)
        keep[np.asarray(fixed, np.int64)] = 0.0
        self.P = sp.diags(keep) @ P
        self.PT = self.P.T.tocsr()
        self.fixed = np.asarray(fixed, np.int64)
        self.smoothing_steps = int(smoothing_steps)
        self.omega = float(omega)
        self.backend = backend
        self._coarse = None
        self.A = None

    def update(self, A):
        """Set the fine matrix (full symmetric, fixed rows/columns = identity) and factorize ``P^T A P``.

        Parameters
        ----------
        A : (3V, 3V) sparse matrix
        """
        A = sp.csr_matrix(A)
        self.A = A
        n = self.n
        # 3x3 diagonal blocks, inverted
        Acoo = A.tocoo()
        blk = (Acoo.row // 3) == (Acoo.col // 3)
        D = np.zeros((n // 3, 3, 3))
        np.add.at(D, (Acoo.row[blk] // 3, Acoo.row[blk] % 3, Acoo.col[blk] % 3), Acoo.data[blk])
        self._Dinv = np.linalg.inv(D)
        Ac = (self.PT @ A @ self.P).tocsc()
        empty = np.flatnonzero(Ac.diagonal() <= 0.0)  # coarse coordinates whose support is all fixed
        if len(empty):
            Ac = Ac + sp.csc_matrix((np.ones(len(empty)), (empty, empty)), shape=Ac.shape)
        if self._coarse is None:
            self._coarse = SparseCholesky(Ac, backend=self.backend)
        self._coarse.factorize(self._coarse.values_from_matrix(Ac))

    def _smooth(self, r):
        y = self.omega * np.einsum("vij,vj->vi", self._Dinv, r.reshape(-1, 3)).ravel()
        y[self.fixed] = 0.0
        return y

    def __call__(self, r):
        A = self.A
        x = np.zeros_like(r)
        for _ in range(self.smoothing_steps):
            x += self._smooth(r - A @ x)
        x += self.P @ self._coarse.solve(self.PT @ (r - A @ x))
        for _ in range(self.smoothing_steps):
            x += self._smooth(r - A @ x)
        x[self.fixed] = 0.0
        return x
