"""The two solvers of discrete geodesics (thesis 4.1, eq. 4.6) behind :func:`.geodesics.discrete_geodesic`.

Both minimize the path energy of :mod:`lacore.shapes.path_energy` over the
interior points ``z_1..z_{K-1}`` of a path with fixed end points, subject to
admissibility: the Euler integrability conditions ``I~(z_i) = 0`` (3.13) and, on
meshes with holes or handles, the global conditions of Theorem 3.2 (the holonomy
and accumulated translation of every homology loop vanish,
:mod:`lacore.integrability.global_conditions`) -- and the triangle inequalities
``T_f(z_i) > 0``, which are checked, not imposed: they define an open set and
only the line search keeps iterates inside it.  Without the global conditions
the interior points of a geodesic on an annulus or a torus would close at every
vertex but not around the hole or the handles.

Two solvers compute the same geodesic:

``method="sqp"``
    Equality-constrained sequential quadratic programming in ``z``.  Every
    iteration solves the KKT system::

        [ H   A^T ] [ p  ]   [ -g - A^T lambda ]
        [ A  -d I ] [ dl ] = [ -c              ]

    with ``g``, ``H`` the gradient and Hessian of the path energy in the interior
    points (for ``W_q`` the constant ``H = kron(T, D)``, ``D = diag(2 K w)``,
    ``T = tridiag(-1, 2, -1)`` of size ``K - 1``: block-tridiagonal in time),
    ``A`` the block-diagonal constraint Jacobians (Euler,
    :func:`~lacore.integrability.local.euler_integrability_jacobian`, stacked on the
    global conditions,
    :func:`~lacore.integrability.global_conditions.global_integrability_jacobian`)
    and ``c`` the stacked constraint maps.  It is solved through the Schur complement
    ``A H^-1 A^T + d I`` (block ``(i, j)`` is ``(T^-1)_ij A_i D^-1 A_j^T``,
    ``(T^-1)_ij = min(i, j) (K - max(i, j)) / K``), factorized by sparse
    Cholesky (:class:`lacore.linalg.sparse_cholesky.SparseCholesky`, symbolic analysis
    once per solve); ``p = H^-1 (r - A^T dl)`` is a tridiagonal solve in time.
    The small ``d > 0`` is a proximal regularization of the multipliers (the
    fixed point still has ``c = 0``); it keeps the system nonsingular on closed
    meshes, where the Euler Jacobian only has rank ``3V - 6`` (Conjecture 1).
    Steps are globalized by the augmented Lagrangian merit function
    ``f + lambda.c + rho/2 |c|^2`` along ``(p, dl)`` with Armijo backtracking
    (``rho`` raised so that the step is a descent direction).  The constraint
    curvature is left out of ``H`` (a Gauss-Newton-type SQP), so convergence is
    linear; when full steps are rejected, the time Laplacian is damped,
    ``T -> T + mu I`` (Levenberg-type, ``mu`` reset once full steps are
    accepted again).  Converged when ``max |c| <= constraint_tol`` and the KKT
    residual ``|g + A^T lambda|_inf <= tol |g|_inf`` (or the predicted merit
    decrease is at round-off level).
    Only lengths and interior dihedral angles are variables; boundary-edge angles
    are 0 by convention (:mod:`lacore.geometry.lengths_angles`) and stay so.

``method="vertices"``
    Parametrize every interior point by vertex positions, ``z_i = Z(X_i)``
    (admissible by construction), fix the rigid motion of every ``X_i`` by the
    3-2-1 rule on one triangle (the gauge of
    :class:`lacore.reconstruction.ReconstructionContext`: one vertex fixed, the
    second on a ray, the third in a plane; only the six rigid motions are
    removed) and minimize the path energy by Gauss-Newton in the free
    coordinates: normal matrix ``J^T H J`` (block-tridiagonal in time: diagonal
    blocks ``4 K J_i^T W J_i``, off-diagonal ``-2 K J_i^T W J_{i+1}``) with the
    block-diagonal Jacobian ``J = diag(dZ/dX_i)``, gradient ``J^T g``, sparse
    Cholesky, Armijo backtracking.  For ``W_q`` this is exactly Gauss-Newton
    for the nonlinear least-squares problem with residuals
    ``sqrt(K w) (Z(X_{i+1}) - Z(X_i))``.
"""

import numpy as np
import scipy.sparse as sp

from ..geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian
from ..integrability.global_conditions import admissibility_jacobian, admissibility_map
from ..integrability.homology import homology_basis
from ..integrability.transitions import triangle_inequality_map
from ..linalg.sparse_cholesky import SparseCholesky
from ..progress import report

__all__ = ["solve_sqp", "solve_vertices", "min_triangle_margin", "max_constraint_violation"]


class _SchurKKT:
    """Solver of the SQP KKT system through the Schur complement of ``H = kron(T, D)``.

    ``[[H, A^T], [A, -delta I]] [p; y] = [r1; r2]`` is solved as::

        (A H^-1 A^T + delta I) y = A H^-1 r1 - r2,     p = H^-1 (r1 - A^T y)

    where block ``(i, j)`` of ``A H^-1 A^T`` is ``(T^-1)_ij A_i D^-1 A_j^T``.  The
    Schur complement is symmetric positive definite (``delta > 0``) and factorized
    by :class:`lacore.linalg.sparse_cholesky.SparseCholesky`, whose symbolic analysis is
    done once (the pattern does not change between iterations).
    """

    def __init__(self, model, d, regularization):
        self.model = model
        self.d = d
        self.dinv = 1.0 / d
        self.regularization = regularization
        self.chol = None
        self.delta = 0.0
        self.damping = 0.0

    def factorize(self, blocks, damping=0.0):
        """Assemble and factorize ``A H^-1 A^T + delta I``; Jacobian blocks ``A_i``, ``H = kron(T + mu I, D)``."""
        m = len(blocks)
        self.damping = float(damping)
        Ti = self.model.time_inverse(self.damping)
        G = [A.multiply(self.dinv[None, :]).tocsr() for A in blocks]
        grid = [[None] * m for _ in range(m)]
        for i in range(m):
            for j in range(i, m):
                P = (G[i] @ blocks[j].T).tocsr()
                grid[i][j] = Ti[i, j] * P
                if j > i:
                    grid[j][i] = grid[i][j].T
        S = sp.bmat(grid, format="csc")
        diag = S.diagonal()
        self.delta = self.regularization * (float(diag.max()) if diag.size else 1.0)
        S = (S + sp.identity(S.shape[0], format="csc") * self.delta).tocsc()
        S.sum_duplicates()
        S.sort_indices()
        if self.chol is None:
            # structural pattern (sparse products drop exact zeros, so S's own pattern may vary)
            ones = [sp.csr_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape) for A in blocks]
            pattern = sp.bmat([[ones[i] @ ones[j].T for j in range(m)] for i in range(m)], format="csc")
            self.chol = SparseCholesky(pattern + sp.identity(S.shape[0], format="csc"))
        self.chol.factorize(S)
        self.delta += self.chol.shift
        self.blocks = blocks

    def _apply_A(self, P):
        return np.concatenate([A @ p for A, p in zip(self.blocks, P, strict=True)])

    def _apply_AT(self, y):
        nc = self.blocks[0].shape[0]
        return np.stack([A.T @ y[i * nc:(i + 1) * nc] for i, A in enumerate(self.blocks)])

    def solve(self, r1, r2):
        """``r1`` of shape ``(K-1, n)``, ``r2`` stacked ``(sum nc,)``; returns ``p (K-1, n)`` and ``y``."""
        b = self._apply_A(self.model.solve_hessian(r1, self.d, self.damping)) - r2
        y = self.chol.solve(b)
        p = self.model.solve_hessian(r1 - self._apply_AT(y), self.d, self.damping)
        return p, y


def min_triangle_margin(z, topology):
    return float(triangle_inequality_map(z, topology).min())


def max_constraint_violation(zs, topology):
    """Largest ``|c|`` of :func:`~lacore.integrability.admissibility_map` over the points ``zs`` (0 for none)."""
    if len(zs) == 0:
        return 0.0
    return max(float(np.abs(admissibility_map(z, topology)).max(initial=0.0)) for z in zs)


def solve_sqp(zs, topology, model, options, progress=None):
    """SQP iterations on the interior points of ``zs`` (modified in place); returns a dict of results."""
    max_iterations, tol, constraint_tol = options.max_iterations, options.tol, options.constraint_tol
    m = model.m
    E = topology.n_edges
    free = np.r_[np.arange(E), E + topology.interior_edges]            # lengths and interior angles
    nc = 3 * len(topology.interior_vertices) + 6 * homology_basis(topology).n_loops
    d = model.hessian_diagonal(free)
    kkt = _SchurKKT(model, d, options.regularization)
    lam = np.zeros(m * nc)
    rho = 0.0
    mu = 0.0
    history = {"path_energy": [], "constraint_violation": [], "stationarity": [], "step": [], "damping": []}

    def constraints(Z):
        return np.concatenate([admissibility_map(z, topology) for z in Z])

    def triangles_ok(Z):
        return all(min_triangle_margin(z, topology) > 0 for z in Z)

    # round-off levels of the path energy and its gradient (16 ulp of every entry; angles of pi)
    scale = np.r_[np.abs(zs[:, :E]).max(0), np.full(E, np.pi)]
    f_noise = model.K * float(np.sum(model.w * (16 * np.finfo(float).eps * scale) ** 2))
    g_noise = 2.0 * model.K * float(np.max(model.w * 16 * np.finfo(float).eps * scale))
    status, message, iterations = 1, "maximum number of iterations reached", 0
    for it in range(1, max_iterations + 1):
        report(progress, it - 1, max_iterations, f"iteration {it} (at most {max_iterations})")
        iterations = it
        inner = zs[1:-1]
        lin = [admissibility_jacobian(z, topology, return_value=True) for z in inner]
        c = np.concatenate([v for _, v in lin])
        blocks = [J[:, free].tocsr() for J, _ in lin]
        f = model.value(zs)
        g = model.gradient(zs)[:, free]
        cmax = float(np.abs(c).max(initial=0.0))
        history["path_energy"].append(f)
        history["constraint_violation"].append(cmax)
        kkt.factorize(blocks, mu)
        history["damping"].append(mu)
        ATlam = kkt._apply_AT(lam)
        p, dlam = kkt.solve(-g - ATlam, -c)
        lam_new = lam + dlam
        stationarity = float(np.abs(g + kkt._apply_AT(lam_new)).max())
        history["stationarity"].append(stationarity)
        stat_tol = max(tol * float(np.abs(g).max()), g_noise)
        if cmax <= constraint_tol and stationarity <= stat_tol:
            history["step"].append(0.0)
            lam = lam_new
            status, message = 0, "converged: constraints satisfied and KKT conditions met"
            break
        # augmented Lagrangian merit phi(z, lam) = f + lam.c + rho/2 |c|^2 along (p, dlam)
        Ap = kkt._apply_A(p)
        pHp = float(np.sum(p * model.apply_hessian(p, d, mu)))
        d0 = float(np.sum((g + ATlam) * p) + c @ dlam)
        cAp = float(c @ Ap)
        if cAp < 0.0 and d0 + rho * cAp > -0.5 * pHp:
            rho = max(2.0 * rho, (d0 + 0.5 * pHp) / -cAp)
        slope = d0 + rho * cAp
        phi0 = f + float(lam @ c) + 0.5 * rho * float(c @ c)
        if cmax <= constraint_tol and -slope <= 1e-15 * max(f, f_noise):
            history["step"].append(0.0)
            lam = lam_new
            status, message = 0, "converged: constraints satisfied, predicted decrease at round-off level"
            break
        alpha, accepted = 1.0, False
        while alpha > 1e-12:
            trial = zs.copy()
            trial[1:-1, free] += alpha * p
            if triangles_ok(trial[1:-1]):
                ct = constraints(trial[1:-1])
                lt = lam + alpha * dlam
                phi = model.value(trial) + float(lt @ ct) + 0.5 * rho * float(ct @ ct)
                if phi <= phi0 + 1e-4 * alpha * min(slope, 0.0):
                    accepted = True
                    break
            alpha *= 0.5
        # a cut step (alpha < 1) that changes the merit by a few ulps only and does not halve the constraint
        # violation, where the constraints hold and the KKT residual is near its tolerance, is round-off: stop as
        # when no step is accepted (the damping would otherwise grow and the same tiny steps repeat to the
        # iteration limit); full steps still reduce the KKT residual below what the merit resolves
        stalled = (accepted and alpha < 1.0 and cmax <= constraint_tol and stationarity <= 1e3 * stat_tol
                   and phi0 - phi <= 64 * np.finfo(float).eps * max(abs(phi0), f_noise)
                   and float(np.abs(ct).max(initial=0.0)) > 0.5 * cmax)
        if not accepted or stalled:
            if cmax <= constraint_tol and stationarity <= 1e3 * stat_tol:
                status, message = 0, "converged to round-off: constraints satisfied, no further merit decrease"
            else:
                status, message = 2, "line search failed: no step decreases the augmented Lagrangian merit"
            history["step"].append(0.0)
            lam = lam_new
            break
        history["step"].append(alpha)
        zs[:] = trial
        lam = lam + alpha * dlam
        # Levenberg-type damping of the time Laplacian: shorter tangential steps where the constraint
        # curvature (missing from H) makes full steps overshoot, none once full steps are accepted
        if alpha < 1.0:
            mu = min(max(10.0 * mu, 1e-2), 1e4)
        else:
            mu = 0.0 if mu <= 1e-6 else 0.1 * mu
    return {"status": status, "message": message, "iterations": iterations, "history": history,
            "multipliers": lam.reshape(m, nc)}


def _assemble_normal_matrix(Js, K, w):
    """Gauss-Newton matrix ``J^T H J`` of the path energy in vertex coordinates (block tridiagonal), CSC.

    Diagonal blocks ``4 K J_i^T W J_i``, off-diagonal ``-2 K J_i^T W J_{i+1}``, ``W = diag(w)``.
    """
    m = len(Js)
    WJ = [J.multiply(w[:, None]).tocsr() for J in Js]
    grid = [[None] * m for _ in range(m)]
    for i in range(m):
        grid[i][i] = (4.0 * K) * (Js[i].T @ WJ[i])
        if i + 1 < m:
            grid[i][i + 1] = (-2.0 * K) * (Js[i].T @ WJ[i + 1])
            grid[i + 1][i] = grid[i][i + 1].T
    return sp.bmat(grid, format="csc")


def _vertex_path_linearization(Xc, zs, topology, model, cols):
    """Path energy, its gradient and Gauss-Newton matrix in the vertex coordinates ``cols`` of the interior points.

    Parameters
    ----------
    Xc : (K-1, V, 3) ndarray
        Interior immersions.
    zs : (K+1, 2E) ndarray
        The path; its interior rows are overwritten with ``Z(Xc)``.
    topology : MeshTopology
    model : QuadraticPathModel
    cols : (n,) int
        Free coordinates (indices into ``X.ravel()``), the same for every point.

    Returns
    -------
    f : float
    grad : ((K-1) n,) ndarray
        ``J^T g`` with ``J = diag(dZ/dX_i[:, cols])`` and ``g`` the path-energy gradient in ``z``.
    N : scipy.sparse.csc_matrix
        ``J^T H J`` (:func:`_assemble_normal_matrix`).
    Js : list of CSR Jacobians ``(2E, n)``
    """
    out = [lengths_and_angles_jacobian(x, topology, return_z=True) for x in Xc]
    zs[1:-1] = [o[1] for o in out]
    Js = [o[0][:, cols].tocsr() for o in out]
    G = model.gradient(zs)
    grad = np.concatenate([J.T @ gi for J, gi in zip(Js, G, strict=True)])
    return model.value(zs), grad, _assemble_normal_matrix(Js, model.K, model.w), Js


def solve_vertices(zs, Xc, topology, model, context, options, progress=None):
    """Gauss-Newton in the free vertex coordinates of the interior points; ``zs``/``Xc`` updated in place.

    ``Xc (K-1, V, 3)`` are canonical coordinates of ``context`` (fixed coordinates 0).
    """
    max_iterations, tol = options.max_iterations, options.tol
    K, m = model.K, model.m
    n3 = 3 * topology.n_vertices
    cols = np.setdiff1d(np.arange(n3), context.fixed_dofs)
    nx = len(cols)
    history = {"path_energy": [], "constraint_violation": [], "stationarity": [], "step": []}
    size = context.size

    f, grad, N, Js = _vertex_path_linearization(Xc, zs, topology, model, cols)
    chol = None
    status, message, iterations = 1, "maximum number of iterations reached", 0
    for it in range(1, max_iterations + 1):
        report(progress, it - 1, max_iterations, f"iteration {it} (at most {max_iterations})")
        iterations = it
        history["path_energy"].append(f)
        history["constraint_violation"].append(0.0)
        history["stationarity"].append(float(np.abs(grad).max()))
        if chol is None:
            # structural pattern (sparse products drop exact zeros, so N's own pattern may vary)
            ones = [sp.csr_matrix((np.ones(J.nnz), J.indices, J.indptr), shape=J.shape) for J in Js]
            pattern = _assemble_normal_matrix(ones, K, np.ones(len(model.w)))
            chol = SparseCholesky(abs(pattern) + sp.identity(N.shape[0], format="csc"))
        chol.factorize(N)
        dx = chol.solve(-grad)
        slope = float(grad @ dx)
        if -0.5 * slope <= 1e-16 * max(f, 1e-300):
            status, message = 0, "converged: predicted Gauss-Newton decrease at round-off level"
            history["step"].append(0.0)
            break
        alpha, accepted = 1.0, False
        while alpha > 1e-12:
            Xt = Xc.copy()
            Xt.reshape(m, -1)[:, cols] += alpha * dx.reshape(m, nx)
            zt = zs.copy()
            zt[1:-1] = [lengths_and_angles(x, topology, check=False) for x in Xt]
            ft = model.value(zt) if np.all(np.isfinite(zt)) else np.inf
            if ft <= f + 1e-4 * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            status, message = 2, "line search failed: no step decreases the path energy"
            history["step"].append(0.0)
            break
        history["step"].append(alpha)
        Xc[:] = Xt
        f, grad, N, Js = _vertex_path_linearization(Xc, zs, topology, model, cols)
        if alpha * float(np.abs(dx).max()) <= tol * size:
            status, message = 0, "converged: Gauss-Newton step below tolerance"
            break
    return {"status": status, "message": message, "iterations": iterations, "history": history, "multipliers": None}
