"""Discrete geodesics in the space of lengths and angles (thesis 2.2, 4.1, eq. 4.6).

A discrete ``K``-path is a sequence ``z_0, ..., z_K`` of lengths-and-angles
vectors (shape ``(K+1, 2E)``, see :mod:`lacore.geometry.lengths_angles`).  Its discrete
path energy (2.7) for a deformation energy ``W`` is::

    E^K[z_0..z_K] = K * sum_{i=0}^{K-1} W[z_i, z_{i+1}]

and a discrete geodesic minimizes ``E^K`` over the interior points
``z_1..z_{K-1}`` for fixed end points.  The *linear approximation* of section 4.2
minimizes over all of ``R^{2E}`` (4.9) -- for the quadratic energy ``W_q`` the
minimizer is the equidistant linear interpolation -- and then projects every
point onto the admissible set by reconstruction (4.10), see
:func:`lacore.shapes.interpolation.interpolate`.  This module solves the constrained
problem (4.6) itself: the interior points are required to be admissible, i.e. to
satisfy the Euler integrability conditions ``I~(z_i) = 0`` (3.13) (and the
triangle inequalities ``T_f(z_i) > 0``, which are checked, not imposed: they
define an open set and only the line search keeps iterates inside it).

Two solvers compute the same geodesic:

``method="sqp"``
    Equality-constrained sequential quadratic programming in ``z``.  Every
    iteration solves the KKT system::

        [ H   A^T ] [ p  ]   [ -g - A^T lambda ]
        [ A  -d I ] [ dl ] = [ -c              ]

    with ``g``, ``H`` the gradient and Hessian of the path energy in the interior
    points (for ``W_q`` the constant ``H = kron(T, D)``, ``D = diag(2 K w)``,
    ``T = tridiag(-1, 2, -1)`` of size ``K - 1``: block-tridiagonal in time),
    ``A`` the block-diagonal Euler Jacobians
    (:func:`~lacore.integrability.local.euler_integrability_jacobian`) and ``c`` the
    stacked Euler maps.  It is solved through the Schur complement
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

Both start by default from the projected linear path (4.9, 4.10).

Energies
--------
:func:`path_energy` and :func:`path_energy_profile` take any energy with
``value(z_a, z_b)`` (also :class:`lacore.energies.ThinShellsEnergy`).  The
solvers need a quadratic energy -- anything with a ``residual_weights``
attribute ``w`` of shape ``(2E,)``, ``W = sum_j w_j (z_a - z_b)_j^2``, such as
:class:`lacore.energies.QuadraticEnergy` (default: ``W_q`` (3.19) with the
weights (3.20) of the start shape, ``eta = 1e-3``) -- which they use in closed
form; weights of lengths and interior angles must be positive.

Scale
-----
Meant for small and medium meshes: on the 121-vertex plates a geodesic with
``K = 8`` takes about 20 iterations (a few seconds); on the 2046-vertex finger
with ``K = 4`` both solvers take 5-10 iterations of about a second each.  The
SQP Schur complement couples all time steps (``(K-1)^2`` sparse blocks), the
Gauss-Newton matrix only neighbouring ones, so ``"vertices"`` scales better in
``K``.
"""

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..energies import QuadraticEnergy
from ..errors import InputError, LengthsAnglesError
from ..integrability.local import euler_integrability_jacobian, euler_integrability_map, triangle_inequality_map
from .interpolation import interpolate
from ..geometry.lengths_angles import check_z, lengths_and_angles, lengths_and_angles_jacobian
from ..progress import report
from ..reconstruction import ReconstructionSettings, get_context
from ..result import SolverResult
from ..linalg.sparse_cholesky import SparseCholesky
from ..geometry.topology import check_vertices

__all__ = [
    "GeodesicResult",
    "discrete_geodesic",
    "path_energy",
    "path_energy_profile",
    "linear_path",
    "projected_linear_path",
    "default_energy",
]


@dataclass(kw_only=True, repr=False)
class GeodesicResult(SolverResult):
    """Result of :func:`discrete_geodesic` (a :class:`lacore.result.SolverResult`).

    Attributes
    ----------
    z : (K+1, 2E) ndarray
        The discrete geodesic including its end points.
    vertices : (K+1, V, 3) ndarray or None
        Immersions of the path points (``method="vertices"``: the optimized
        positions; ``method="sqp"``: reconstructions of the admissible solution,
        if requested), all in the frame of the reference shape (its fixed
        triangle in place, as in :func:`lacore.shapes.interpolation.interpolate`).
    path_energy : float
        ``E^K = K sum_i W[z_i, z_{i+1}]`` (2.7).
    step_energies : (K,) ndarray
        ``W[z_i, z_{i+1}]``, see :func:`path_energy_profile`.
    initial_path_energy : float
        Path energy of the starting path.
    constraint_violation : float
        ``max |I~(z_i)|`` over the interior points (0 up to round-off for ``"vertices"``).
    min_triangle_margin : float
        ``min T_f(z_i)`` over all faces and path points (3.7); positive iff all
        triangle inequalities hold.
    multipliers : (K-1, 3 V_int) ndarray or None
        Lagrange multipliers of the integrability constraints (``"sqp"`` only).
    success : bool
    status : int
        0 converged, 1 iteration limit, 2 line search failed.
    message : str
    iterations : int
    nit : int
        Same as ``iterations`` (``OptimizeResult`` name).
    timings : dict
        ``total``: wall time (as ``seconds``).
    history : dict of lists
        Per iteration ``path_energy``, ``constraint_violation``, ``stationarity``
        (``"sqp"``: KKT residual ``|g + A^T lambda|_inf``; ``"vertices"``: gradient
        max-norm), ``step`` (accepted step length factor) and, for ``"sqp"``,
        ``damping`` (``mu``).
    seconds : float
    method : str
    n_steps : int
    """

    z: np.ndarray
    vertices: np.ndarray | None = None
    path_energy: float = float("nan")
    step_energies: np.ndarray | None = None
    initial_path_energy: float = float("nan")
    constraint_violation: float = float("nan")
    min_triangle_margin: float = float("nan")
    multipliers: np.ndarray | None = None
    nit: int = 0
    history: dict = field(default_factory=dict)
    seconds: float = 0.0
    method: str = ""
    n_steps: int = 0

    _summary_exclude = ("z", "vertices", "multipliers")



# --------------------------------------------------------------------------- energies
def default_energy(topology, reference, bending_weight=1e-3, weights="frohlich_botsch"):
    """The quadratic energy ``W_q`` (3.19) with weights from ``reference``.

    Parameters
    ----------
    topology : MeshTopology
    reference : (V, 3) vertices or (2E,) lengths and angles
        Reference configuration of the weights (3.20)/(3.21).
    bending_weight : float
        ``eta`` in (3.19).
    weights : {"frohlich_botsch", "heeren", "uniform"}

    Returns
    -------
    lacore.energies.QuadraticEnergy
    """
    reference = np.asarray(reference, float)
    if reference.ndim == 2:
        return QuadraticEnergy(topology, reference_vertices=reference, weights=weights,
                               bending_weight=bending_weight)
    return QuadraticEnergy(topology, reference_z=reference, weights=weights, bending_weight=bending_weight)


def _quadratic_weights(energy, dim):
    w = getattr(energy, "residual_weights", None)
    if w is None:
        raise TypeError(f"{type(energy).__name__} is not supported by the geodesic solvers: they need a quadratic "
                        "energy with a 'residual_weights' attribute (W = sum_j w_j (z_a - z_b)_j^2), "
                        "e.g. lacore.energies.QuadraticEnergy")
    w = np.asarray(w, float)
    if w.shape != (dim,):
        raise LengthsAnglesError(f"energy.residual_weights has shape {w.shape}, expected ({dim},)")
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise InputError("energy.residual_weights must be finite and non-negative")
    return w


def path_energy_profile(zs, energy):
    """Energies of the steps of a discrete path, ``W[z_i, z_{i+1}]``.

    Parameters
    ----------
    zs : (K+1, 2E) array_like
        Discrete path (K >= 1).
    energy : object with ``value(z_a, z_b)``
        Deformation energy ``W`` (e.g. :class:`lacore.energies.QuadraticEnergy`).

    Returns
    -------
    (K,) ndarray
        For a discrete geodesic the entries are (nearly) equal: its points are
        equidistributed (section 2.2, figures 4.1/4.2).
    """
    zs = _check_path(zs)
    return np.array([float(energy.value(zs[i], zs[i + 1])) for i in range(len(zs) - 1)])


def path_energy(zs, energy):
    """Discrete path energy ``E^K = K sum_i W[z_i, z_{i+1}]`` (2.7) of a path ``(K+1, 2E)``."""
    profile = path_energy_profile(zs, energy)
    return len(profile) * float(profile.sum())


def _check_path(zs):
    zs = np.asarray(zs, float)
    if zs.ndim != 2 or zs.shape[0] < 2:
        raise LengthsAnglesError(f"a discrete path must have shape (K+1, 2E) with K >= 1, got {zs.shape}")
    if not np.all(np.isfinite(zs)):
        raise LengthsAnglesError("the discrete path has NaN or infinite entries")
    return zs


def linear_path(z_start, z_end, n_steps):
    """Equidistant linear path ``z_i = (1 - i/K) z_0 + (i/K) z_K``, shape ``(K+1, 2E)``.

    For ``W_q`` this is the unconstrained discrete geodesic (4.9).
    """
    t = np.linspace(0.0, 1.0, int(n_steps) + 1)[:, None]
    return (1.0 - t) * np.asarray(z_start, float)[None] + t * np.asarray(z_end, float)[None]


def _time_laplacian_inverse(m):
    """Inverse of ``T = tridiag(-1, 2, -1)`` of size ``m``: ``min(i, j) (m + 1 - max(i, j)) / (m + 1)`` (1-based)."""
    i = np.arange(1, m + 1)
    return np.minimum.outer(i, i) * (m + 1 - np.maximum.outer(i, i)) / (m + 1.0)


def projected_linear_path(start, end, topology, n_steps, reference_vertices=None, **projection_kw):
    """The approximate discrete geodesic of section 4.2: linear path in ``z`` (4.9), every point projected (4.10).

    Parameters
    ----------
    start, end : (V, 3) vertices or (2E,) lengths and angles
    topology : MeshTopology
    n_steps : int
        ``K >= 1``.
    reference_vertices : (V, 3) array_like, optional
        Reference of the projections; default ``start`` (must then be vertices).
    **projection_kw
        Options of :func:`lacore.shapes.interpolation.interpolate` (method -- default ``"gn"``,
        the projection run to convergence --, bending_weight, ...).

    Returns
    -------
    z : (K+1, 2E) ndarray
        ``Z`` of the projected points (the end points reproduce the inputs up to
        the solver tolerance); its :func:`path_energy_profile` is the energy
        diagram of figure 4.1.
    vertices : (K+1, V, 3) ndarray
        The projected immersions, in the frame of the reference.
    """
    if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
        raise InputError(f"n_steps must be an integer >= 1, got {n_steps!r}")
    K = int(n_steps)
    projection_kw.setdefault("method", "gn")  # the projection P_Z itself: Gauss-Newton run to convergence
    res = interpolate([start, end], topology, np.arange(K + 1) / K, reference_vertices=reference_vertices,
                      **projection_kw)
    X = np.array(res.vertices, float)
    return np.array([lengths_and_angles(x, topology) for x in X]), X


class _QuadraticPathModel:
    """Path energy ``K sum_i sum_j w_j (z_{i+1} - z_i)_j^2`` as a function of the interior points.

    Its Hessian in the interior points ``(z_1..z_{K-1})`` is ``kron(T, diag(2 K w))``
    with ``T = tridiag(-1, 2, -1)`` of size ``K - 1``.
    """

    def __init__(self, weights, n_steps):
        self.w = weights
        self.K = n_steps
        self.m = n_steps - 1
        m = max(self.m, 1)  # K = 1 has no unknowns; keep valid (unused) operators
        self.T = sp.diags([-np.ones(m - 1), 2.0 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1], format="csr")
        self.T_inv = _time_laplacian_inverse(m)

    def value(self, zs):
        d = np.diff(zs, axis=0)
        return self.K * float(np.sum(self.w * d * d))

    def gradient(self, zs):
        """``(K-1, 2E)``: ``2 K w (2 z_i - z_{i-1} - z_{i+1})``."""
        return 2.0 * self.K * self.w * (2.0 * zs[1:-1] - zs[:-2] - zs[2:])

    def hessian_diagonal(self, columns=None):
        """``2 K w`` restricted to ``columns``: the diagonal factor ``D`` of ``H = kron(T, D)``."""
        return 2.0 * self.K * (self.w if columns is None else self.w[columns])

    def apply_hessian(self, P, d, damping=0.0):
        """``H p`` for ``p`` of shape ``(K-1, n)`` and the diagonal factor ``d`` (n,).

        With ``damping = mu > 0`` the damped ``kron(T + mu I, D)``.
        """
        return (self.T @ P + damping * P) * d

    def solve_hessian(self, R, d, damping=0.0):
        """``H^-1 r`` (or the damped ``kron(T + mu I, D)^-1 r``) for ``r`` of shape ``(K-1, n)``."""
        return (self.time_inverse(damping) @ R) / d

    def time_inverse(self, damping=0.0):
        """``(T + mu I)^-1``, dense ``(K-1, K-1)``."""
        if damping == 0.0:
            return self.T_inv
        return np.linalg.inv(self.T.toarray() + damping * np.eye(self.T.shape[0]))


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


# --------------------------------------------------------------------------- input handling
def _as_z(shape, topology, name):
    a = np.asarray(shape, float)
    if a.ndim == 2:
        X = check_vertices(a, topology.n_vertices, name=name)
        return lengths_and_angles(X, topology), X
    return check_z(a, topology, name=name), None


def _initial_path(initial, K, topology):
    """Interior points ``(K-1, 2E)`` and vertices ``(K-1, V, 3)`` (or None) from a user-given start."""
    a = np.asarray(initial, float)
    V, E2 = topology.n_vertices, 2 * topology.n_edges
    if a.ndim == 3:
        if a.shape[1:] != (V, 3) or a.shape[0] not in (K - 1, K + 1):
            raise LengthsAnglesError(f"initial vertices must have shape ({K - 1} or {K + 1}, {V}, 3), got {a.shape}")
        X = a[1:-1] if a.shape[0] == K + 1 else a
        if not np.all(np.isfinite(X)):
            raise LengthsAnglesError("initial vertices have NaN or infinite coordinates")
        return np.array([lengths_and_angles(x, topology) for x in X]).reshape(K - 1, E2), X.copy()
    if a.ndim != 2 or a.shape[1] != E2 or a.shape[0] not in (K - 1, K + 1):
        raise LengthsAnglesError(f"initial path must have shape ({K - 1} or {K + 1}, {E2}), got {a.shape}")
    zs = a[1:-1] if a.shape[0] == K + 1 else a
    for i, z in enumerate(zs):
        check_z(z, topology, name=f"initial path point {i + 1}")
    return zs.copy(), None


# --------------------------------------------------------------------------- solvers
def _min_margin(z, topology):
    return float(triangle_inequality_map(z, topology).min())


def _euler_max(zs, topology):
    if len(topology.interior_vertices) == 0 or len(zs) == 0:
        return 0.0
    return max(float(np.abs(euler_integrability_map(z, topology)).max()) for z in zs)


def _solve_sqp(zs, topology, model, max_iterations, tol, constraint_tol, regularization, progress=None):
    """SQP iterations on the interior points of ``zs`` (modified in place); returns a dict of results."""
    m = model.m
    E = topology.n_edges
    free = np.r_[np.arange(E), E + topology.interior_edges]            # lengths and interior angles
    nc = 3 * len(topology.interior_vertices)
    d = model.hessian_diagonal(free)
    kkt = _SchurKKT(model, d, regularization)
    lam = np.zeros(m * nc)
    rho = 0.0
    mu = 0.0
    history = {"path_energy": [], "constraint_violation": [], "stationarity": [], "step": [], "damping": []}

    def constraints(Z):
        return np.concatenate([euler_integrability_map(z, topology) for z in Z])

    def triangles_ok(Z):
        return all(_min_margin(z, topology) > 0 for z in Z)

    # round-off levels of the path energy and its gradient (16 ulp of every entry; angles of pi)
    scale = np.r_[np.abs(zs[:, :E]).max(0), np.full(E, np.pi)]
    f_noise = model.K * float(np.sum(model.w * (16 * np.finfo(float).eps * scale) ** 2))
    g_noise = 2.0 * model.K * float(np.max(model.w * 16 * np.finfo(float).eps * scale))
    status, message, iterations = 1, "maximum number of iterations reached", 0
    for it in range(1, max_iterations + 1):
        report(progress, it - 1, max_iterations, f"iteration {it} (at most {max_iterations})")
        iterations = it
        inner = zs[1:-1]
        lin = [euler_integrability_jacobian(z, topology, return_value=True) for z in inner]
        c = np.concatenate([v for _, v in lin])
        blocks = [J[:, free].tocsr() for J, _ in lin]
        f = model.value(zs)
        g = model.gradient(zs)[:, free]
        cmax = float(np.abs(c).max())
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
        if not accepted:
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
    model : _QuadraticPathModel
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


def _solve_vertices(zs, Xc, topology, model, context, max_iterations, tol, progress=None):
    """Gauss-Newton in the free vertex coordinates of the interior points; ``zs``/``Xc`` updated in place.

    ``Xc (K-1, V, 3)`` are canonical coordinates of ``context`` (fixed coordinates 0).
    """
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


# --------------------------------------------------------------------------- driver
def discrete_geodesic(start, end, topology, n_steps, energy=None, method="sqp", initial=None,
                      reference_vertices=None, bending_weight=1e-3, weights="frohlich_botsch",
                      max_iterations=200, tol=1e-8, constraint_tol=1e-10, regularization=1e-12,
                      fixed_face=None, reconstruct_vertices=False, projection_kw=None, progress=None):
    """Discrete geodesic in the space of lengths and angles: solve (4.6).

    Minimize ``K sum_{i=0}^{K-1} W[z_i, z_{i+1}]`` over ``z_1..z_{K-1}`` subject to
    ``I~(z_i) = 0`` (3.13), with ``T_f(z_i) > 0`` (3.7) checked on the whole path.

    Parameters
    ----------
    start, end : (V, 3) vertices or (2E,) lengths and angles
        End points ``z_0`` and ``z_K`` (admissible).
    topology : MeshTopology
    n_steps : int
        ``K >= 1``; the path has ``K + 1`` points (``K = 1`` has no unknowns).
    energy : object, optional
        Quadratic deformation energy with ``value(z_a, z_b)`` and
        ``residual_weights (2E,)`` (:class:`lacore.energies.QuadraticEnergy`); all
        weights of lengths and interior angles must be positive.  Default
        :func:`default_energy` (``W_q`` (3.19) with ``weights`` from the reference
        and bending weight ``bending_weight``).
    method : {"sqp", "vertices"}
        Constrained SQP in ``z`` or Gauss-Newton in vertex positions (module docstring).
    initial : optional
        Starting path: ``None`` (default) for the projected linear path
        (4.9)-(4.10) of :func:`lacore.shapes.interpolation.interpolate`; ``"linear"`` for
        the *unprojected* linear path (``"sqp"`` only; it is not admissible); or
        an array of the interior (``K - 1``) or all (``K + 1``) points as lengths
        and angles ``(., 2E)`` or vertices ``(., V, 3)`` (``"vertices"`` needs vertices).
    reference_vertices : (V, 3) array_like, optional
        Reference immersion: weights of the default energy, reference of the
        projections (fixed face, output frame).  Defaults to ``start`` if that
        is a vertex array; required otherwise (unless ``energy`` and ``initial``
        are given and no vertices are wanted).
    bending_weight, weights
        Parameters of the default energy and of the projections.
    max_iterations : int
    tol : float
        ``"sqp"``: relative KKT stationarity ``|g + A^T lambda|_inf <= tol |g|_inf``;
        ``"vertices"``: step ``<= tol * size`` (bounding-box diagonal of the reference).
    constraint_tol : float
        ``max |I~(z_i)|`` required for convergence of ``"sqp"``.
    regularization : float
        Proximal multiplier regularization ``delta`` of the SQP KKT system,
        relative to the largest diagonal entry of ``A H^-1 A^T``.
    fixed_face : int, optional
        Face whose 3-2-1 position fixes the rigid motions (``"vertices"``, and the
        projections); default the reconstruction's default face.
    reconstruct_vertices : bool
        For ``"sqp"``: reconstruct immersions of the (admissible) solution into
        ``result.vertices`` (Gauss-Newton projections, warm-started along the path).
    projection_kw : dict, optional
        Extra keyword arguments of the projections (:func:`lacore.shapes.interpolation.interpolate`).
    progress : callable, optional
        ``progress(done, total, message)`` before every iteration (``total`` =
        ``max_iterations``, :mod:`lacore.progress`); returning True stops with
        :class:`lacore.progress.Cancelled`.

    Returns
    -------
    GeodesicResult

    Raises
    ------
    LengthsAnglesError, MeshError
        Inputs of the wrong size or with NaN entries; a starting path violating
        the triangle inequality.
    ValueError
        ``n_steps < 1``, an unknown method, zero weights.
    """
    t0 = time.perf_counter()
    if method not in ("sqp", "vertices"):
        raise InputError(f"unknown geodesic method {method!r}; use 'sqp' or 'vertices'")
    if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
        raise InputError(f"n_steps must be an integer >= 1, got {n_steps!r}")
    K = int(n_steps)
    z0, X0 = _as_z(start, topology, "start")
    zK, XK = _as_z(end, topology, "end")
    if reference_vertices is not None:
        reference_vertices = check_vertices(reference_vertices, topology.n_vertices, name="reference_vertices")
    elif X0 is not None:
        reference_vertices = X0
    if energy is None:
        energy = default_energy(topology, reference_vertices if reference_vertices is not None else z0,
                                bending_weight=bending_weight, weights=weights)
    E = topology.n_edges
    w = _quadratic_weights(energy, 2 * E)
    free = np.r_[np.arange(E), E + topology.interior_edges]
    if np.any(w[free] <= 0):
        raise InputError("the geodesic solvers need positive energy weights on all lengths and interior angles "
                         "(bending_weight > 0)")
    model = _QuadraticPathModel(w, K)
    projection_kw = dict(projection_kw or {})
    projection_kw.setdefault("method", "gn")  # the projection P_Z itself: Gauss-Newton run to convergence
    projection_kw.setdefault("bending_weight", bending_weight)
    projection_kw.setdefault("weights", weights)
    if fixed_face is not None:
        projection_kw.setdefault("fixed_face", fixed_face)

    def need_reference(what):
        if reference_vertices is None:
            raise InputError(f"{what} needs vertex positions: pass start/end as (V, 3) vertex arrays or give "
                             "reference_vertices")

    zs = np.empty((K + 1, 2 * E))
    zs[0], zs[K] = z0, zK
    Xs = None
    if K >= 2:
        if initial is None:
            need_reference("the projected linear start")
            z_lin, X_lin = projected_linear_path(X0 if X0 is not None else z0, XK if XK is not None else zK,
                                                 topology, K, reference_vertices=reference_vertices,
                                                 **projection_kw)
            zs[1:-1], Xs = z_lin[1:-1], X_lin[1:-1]
        elif isinstance(initial, str):
            if initial != "linear":
                raise InputError(f"unknown initial path {initial!r}; use None, 'linear' or an array")
            if method == "vertices":
                raise InputError("method='vertices' cannot start from the (non-admissible) linear path in z")
            zs[1:-1] = linear_path(z0, zK, K)[1:-1]
        else:
            zs[1:-1], Xs = _initial_path(initial, K, topology)
            if method == "vertices" and Xs is None:
                raise InputError("method='vertices' needs initial vertex positions of shape (K-1, V, 3) (or None)")
    initial_energy = model.value(zs)

    context = None
    if method == "vertices" and K >= 2:
        need_reference("method='vertices'")
        settings = ReconstructionSettings(weights=projection_kw["weights"],
                                          bending_weight=projection_kw["bending_weight"],
                                          fixed_face=projection_kw.get("fixed_face"))
        context = get_context(topology, reference_vertices, settings)

    if K < 2:
        out = {"status": 0, "message": "no interior points (n_steps = 1)", "iterations": 0,
               "history": {"path_energy": [initial_energy], "constraint_violation": [0.0], "stationarity": [],
                           "step": []},
               "multipliers": None}
    elif method == "sqp":
        for i, z in enumerate(zs[1:-1]):
            if _min_margin(z, topology) <= 0:
                raise LengthsAnglesError(f"initial path point {i + 1} violates the triangle inequality")
        out = _solve_sqp(zs, topology, model, max_iterations, tol, constraint_tol, regularization, progress)
    else:
        Xc = np.array([context.to_canonical(x) for x in Xs])
        out = _solve_vertices(zs, Xc, topology, model, context, max_iterations, tol, progress)
        Xs = np.array([context.from_canonical(x) for x in Xc])

    vertices = None
    if method == "vertices" and K >= 2:
        ends = [context.align(X) if X is not None else None for X in (X0, XK)]
        if ends[0] is not None and ends[1] is not None:
            vertices = np.concatenate([ends[0][None], Xs, ends[1][None]])
    elif method == "sqp" and reconstruct_vertices:
        need_reference("reconstruct_vertices")
        proj = interpolate(zs, topology, np.arange(K + 1, dtype=float), reference_vertices=reference_vertices,
                           **projection_kw)
        vertices = np.array(proj.vertices)

    profile = path_energy_profile(zs, energy)
    margin = min(_min_margin(z, topology) for z in zs)
    violation = _euler_max(zs[1:-1], topology)
    success = out["status"] == 0 and margin > 0
    message = out["message"]
    if margin <= 0:
        message += "; but a triangle inequality is violated on the path"
    return GeodesicResult(
        z=zs, vertices=vertices, path_energy=K * float(profile.sum()), step_energies=profile,
        initial_path_energy=initial_energy, constraint_violation=violation, min_triangle_margin=margin,
        multipliers=out["multipliers"], success=bool(success), status=out["status"], message=message,
        iterations=out["iterations"], nit=out["iterations"], history=out["history"],
        seconds=time.perf_counter() - t0, timings={"total": time.perf_counter() - t0}, method=method, n_steps=K)
