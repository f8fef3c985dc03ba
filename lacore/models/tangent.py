"""Tangent vectors of a shape model: angles on the circle, the projection onto ``T_z Z`` (thesis 4.1, 4.3).

:func:`wrap_angles` takes the angle half of lengths-and-angles vectors modulo
``2 pi``, so that differences and sums of dihedral angles (the tangent vectors
``z^i - zbar`` (4.18), ``zbar + sum_j alpha_j u_j``) stay meaningful across the
branch cut at ``+-pi``.  :class:`TangentProjector` is the linear projection onto
the tangent space ``T_z Z = ker D Ĩ`` (4.4) of the projected tangent vectors (4.17),
without an explicit basis.
"""

import time

import numpy as np
import scipy.sparse as sp

from ..geometry.lengths_angles import wrap_angle
from ..integrability.global_conditions import admissibility_jacobian
from ..linalg.sparse_cholesky import SparseCholesky
from .settings import PROJECTION_METRICS

__all__ = ["TangentProjector", "wrap_angles"]


def wrap_angles(z, topology):
    """``z (..., 2E)`` with its angle half wrapped to ``(-pi, pi]``
    (:func:`~lacore.geometry.lengths_angles.wrap_angle`); lengths unchanged.

    Dihedral angles live on the circle: differences of angles and sums like
    ``zbar + sum alpha_j u_j`` are taken modulo ``2 pi``.  This changes nothing
    unless angles straddle the branch cut at ``+-pi`` (nearly folded skin).
    """
    z = np.array(z, float)
    E = topology.n_edges
    z[..., E:] = wrap_angle(z[..., E:])
    return z



class TangentProjector:
    """Linear projection onto the tangent space ``T_z Z = ker D_z Ĩ`` (4.4), (4.17), without an explicit basis.

    ``P u = u - C A^T (A C A^T)^-1 A u`` with ``A = D_z Ĩ`` (Jacobian of the
    Euler integrability map and, on meshes with holes or handles, of the global
    conditions: :func:`~lacore.integrability.admissibility_jacobian`,
    ``(3 V_int + 6 n_loops, 2E)``) and ``C = Id`` (Euclidean, the
    thesis' formula) or ``C = M^-1`` (``g``-orthogonal; entries of zero weight,
    the angles of boundary edges, are held at their value, which is 0).

    ``A C A^T`` is singular on closed meshes (the ``3 V`` conditions have rank
    ``3 V - 6``, (4.3)), so it is equilibrated to unit diagonal, factorized
    with a tiny diagonal shift ``delta = shift`` and the projection is
    refined: each step applies the shifted projection to the remainder, which
    shrinks ``|A v|`` by about ``delta / sigma_min^2``, until
    ``|A v| <= rtol |A u|`` or no further progress.  The factorization is one
    :class:`~lacore.linalg.sparse_cholesky.SparseCholesky` whose symbolic
    analysis is cached on the topology.

    Parameters
    ----------
    z : (2E,) array_like
        Point of ``Z`` (admissible lengths and angles), e.g. the mean.
    topology : MeshTopology
    metric_weights : (2E,) array_like, optional
        Diagonal of ``M``; required for ``metric="g"``.
    metric : {"euclidean", "g"}
    shift : float
        Diagonal shift of the equilibrated ``A C A^T`` (default ``1e-14``).
    max_refinements : int
        At most this many refinement steps after the first projection (default 8).
    rtol : float
        Target of ``|A v| / |A u|`` per vector (default ``1e-13``).
    solver : {"cholmod", "scipy"}, optional
        Sparse Cholesky backend.

    Attributes
    ----------
    jacobian : (3 V_int + 6 n_loops, 2E) sparse matrix
        ``A = D_z Ĩ``.
    timings : dict
        ``jacobian``, ``factorization`` (seconds).
    last_refinements : int
        Refinement steps of the last call.
    """

    def __init__(self, z, topology, metric_weights=None, metric="euclidean", shift=1e-14, max_refinements=8,
                 rtol=1e-13, solver=None):
        if metric not in PROJECTION_METRICS:
            raise ValueError(f"unknown projection metric {metric!r}; use 'euclidean' or 'g'")
        t0 = time.perf_counter()
        A = admissibility_jacobian(z, topology)
        t1 = time.perf_counter()
        n = 2 * topology.n_edges
        if metric == "g":
            if metric_weights is None:
                raise ValueError("metric='g' needs metric_weights")
            w = np.asarray(metric_weights, float)
            c = np.divide(1.0, w, out=np.zeros(n), where=w > 0)
        else:
            c = np.ones(n)
        self.metric = metric
        self.jacobian = A
        self._c = c
        self._AC = (A @ sp.diags(c)).tocsr()
        S = (self._AC @ A.T).tocsc()
        cache = topology.cache.get((__name__, "tangent_cholesky"), dict)
        key = (metric, solver)
        chol = cache.get(key)
        if chol is None:
            # structural pattern of A A^T (a product of values may cancel to an exact zero and be dropped)
            B = sp.csr_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape)
            chol = SparseCholesky((B @ B.T).tocsc(), backend=solver)
            cache[key] = chol
        # symmetric diagonal equilibration D S D (unit diagonal): the shift then acts evenly (one solve less)
        diag = S.diagonal()
        self._d = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 1.0)
        Dm = sp.diags(self._d)
        values = chol.values_from_matrix((Dm @ S @ Dm).tocsc())
        self.shift = float(shift)
        values[chol.diagonal] += self.shift
        chol.factorize(values)  # adds a larger shift itself if rounding made a pivot non-positive
        self.shift += chol.shift
        self._chol = chol
        self.max_refinements = int(max_refinements)
        self.rtol = float(rtol)
        self.last_refinements = 0
        t2 = time.perf_counter()
        self.timings = {"jacobian": t1 - t0, "factorization": t2 - t1}

    def __call__(self, u):
        """Project ``u`` of shape ``(2E,)`` or ``(N, 2E)`` (rows) onto the tangent space."""
        u = np.asarray(u, float)
        U = np.atleast_2d(u).T.copy()  # (2E, N)
        if self._chol.n == 0:
            return u.copy()
        A = self.jacobian
        AU = np.asarray(A @ U)
        r0 = np.linalg.norm(AU, axis=0)
        r0 = np.where(r0 > 0, r0, 1.0)
        last = np.inf
        for k in range(1 + self.max_refinements):
            x = self._d[:, None] * self._chol.solve(self._d[:, None] * AU)
            U -= self._c[:, None] * np.asarray(A.T @ x)
            AU = np.asarray(A @ U)
            rel = float(np.max(np.linalg.norm(AU, axis=0) / r0))
            self.last_refinements = k
            if rel <= self.rtol or rel > 0.5 * last:  # converged, or stagnating at round-off
                break
            last = rel
        out = U.T
        return out[0] if u.ndim == 1 else out

    def residual(self, v):
        """``|A v|_2`` per row of ``v`` (0 for tangent vectors)."""
        v = np.atleast_2d(np.asarray(v, float))
        return np.linalg.norm(np.asarray(self.jacobian @ v.T), axis=0)
