"""Energy-based reconstruction by Gauss-Newton (thesis 3.4.1, eq. 3.26, Def. 3.15).

Given target lengths and angles ``z* = (l*, theta*)`` (shape ``(2E,)``, see
:mod:`lacore.lengths_angles`), find vertex positions ``X`` minimizing::

    W[z*, Z(X)]                                                     (3.26)

For the quadratic energy ``W_q`` (3.19) this is the nonlinear least-squares
problem ``sum_j w_j (Z_j(X) - z*_j)^2`` with the residual weights ``w`` of
:class:`lacore.energies.QuadraticEnergy` (``w_s`` on lengths, ``eta w_b`` on
angles, (3.20) or (3.21) from a reference mesh).  With ``J = dZ/dX``
(``(2E, 3V)``) every iteration solves::

    (2 J^T W J) d = -g,     g = 2 J^T W (Z(X) - z*),     W = diag(w)

For another energy in ``z`` (the thin shells energy ``W_TS`` (3.25)) the
Gauss-Newton matrix is ``J^T (d^2W/dz^2) J`` with the element blocks of
``d^2W/dz^2`` projected to be positive semi-definite, from
:meth:`lacore.energies.EnergyInVertices.gauss_newton_hessian`.

Rigid motions
-------------
``Z`` is invariant under rigid motions, so ``J^T W J`` has a 6-dimensional
kernel per connected component.  The motion is fixed by the 3-2-1 rule on one
triangle per component (``fixed_face``, vertices ``a, b, c``): in the
triangle's frame (origin ``X_a``, x axis along ``X_b - X_a``, z axis along its
normal) the coordinates ``a.xyz``, ``b.yz`` and ``c.z`` are held at 0.  These
six constraints only remove the rigid motions, so the minimizer is exactly the
one of (3.26); the triangle itself may change shape.  With
``fix_triangle_shape=True`` all nine coordinates of the triangle are held (the
practice of the thesis' experiments, section 3.4.3): its shape then stays that
of the starting mesh, which biases the result when the target changes that
triangle.

The output is expressed in the frame the *reference* mesh gives the fixed
triangle: ``X_a`` is exactly the reference position, ``X_b`` lies on the
reference ray ``a -> b`` and ``X_c`` in the reference plane of the triangle, on
the same side (an undeformed triangle sits exactly where the reference has it,
up to round-off).  The starting mesh may be placed anywhere.

The default fixed face of a component is its central, well-shaped face on the
reference mesh (:func:`lacore.reconstruction.spanning_trees.default_root_faces`),
the same face that roots the frame-based reconstructions; choosing it on the
reference (not on ``z*``) keeps all frames of an animation in one placement.

Implementation
--------------
* The sparsity pattern of ``J^T W J`` (3x3 blocks for every pair of vertices of
  an edge's two triangles) and, for every entry of every local outer product
  ``g_e g_e^T`` (6x6 for a length row, 12x12 for an angle row), its slot in the
  lower-triangular CSC value array are computed once per topology
  (:func:`gauss_newton_pattern`).  An iteration forms the outer products
  component-major (contiguous over all edges) and sums them with one
  :func:`numpy.bincount`, directly in the factorization's value order: Jacobian,
  gradient and matrix take 6 ms on the 2k-vertex finger and 16-21 ms on a
  5.3k-vertex mesh, 2-3x less than ``J.T @ W @ J`` in SciPy plus extracting
  the lower triangle (``benchmarks/bench_gauss_newton.py``).
* The fixed coordinates keep their rows and columns in the pattern (set to the
  identity), so the pattern and its symbolic Cholesky factorization
  (:class:`lacore.sparse_cholesky.SparseCholesky`, CHOLMOD when available) do
  not depend on the fixed face and are reused across iterations and calls
  through a :class:`ReconstructionContext`.  The fill-reducing ordering is the
  better (fewer nonzeros) of CHOLMOD's AMD and a geometric nested dissection of
  the reference mesh (:func:`lacore.sparse_cholesky.nested_dissection`), which
  saves about a quarter of the flops on closed 5k-vertex meshes.
* Far from the solution every step is an exact Gauss-Newton step with a fresh
  numeric factorization: solving with an older factorization as a CG
  preconditioner needs 10-35 iterations there (the matrix changes a lot with a
  displacement of a fraction of an edge length), no faster than refactorizing.
  Near the solution (``reuse_near_convergence``, default on: the last step was
  a full step and the vertices moved by at most 5 % of the mean target edge
  length -- sum of the steps' max-norms -- since the last factorization)
  the factorization made earlier in the same call preconditions CG on the
  current Gauss-Newton matrix (matrix-free products ``J^T W J v``), solved to
  a relative residual ``min(1e-2, W_k / W_{k-1})`` (an Eisenstat-Walker-type
  forcing term: superlinear convergence at zero residual, enough for the
  linear phase of a non-zero residual) but no tighter than reaching the noise
  floor needs; 1-6 CG iterations (one triangular solve each, ~1/12 of a
  factorization on the finger) replace the last one or two factorizations,
  and a step whose CG does not reach its tolerance in 8 iterations
  refactorizes.  The converged point is the exact minimizer: only the linear
  solves are inexact, to tolerances that vanish with the residual.
  ``reuse_factorization=True`` reuses more aggressively (also across calls,
  e.g. animation frames) with a fixed tolerance ``pcg_rtol``.
* Geodesic acceleration (``geodesic_acceleration``, default on, ``W_q``
  only; Transtrum & Sethna 2012): with the fresh factorization, one more solve
  ``(J^T W J) a = -J^T W r_vv`` corrects the step for the curvature of the
  residual along ``d`` (``r_vv``: second directional derivative of
  ``Z(X) - z*``, by a finite difference with one evaluation of ``Z``), and
  the line search follows the parabola ``X + t d + t^2 a / 2`` (same slope at
  0) when ``2 |a| <= 1.5 |d|`` and ``max|d|`` exceeds 1e-3 mean edge lengths,
  else -- or when no step along it is accepted -- the line ``X + t d``.  The
  Gauss-Newton step of a bending finger is mostly a rotation, which the
  straight line overshoots (accepted ``t ~ 0.3``); along the parabola
  finger0 -> finger1 takes 5 instead of 8 iterations and the average 5
  instead of 6 (4 and 3 factorizations with the reuse above, instead of 8
  and 6), the 5.3k-vertex pose 4 instead of 6, for ~2.5 ms per accelerated
  iteration on the finger.  With the acceleration on,
  no trial step (of either path) may fold an edge -- its dihedral angle more
  than ``pi / 2`` off the target -- that is not folded at the iteration's
  start (unless only such a step decreases the energy): on a strongly
  extrapolated finger target (1.5) the parabola otherwise led into a folded
  local minimum of 7x the energy.
* Line search: Armijo backtracking (``c1 = 1e-4``) starting at the full step 1
  (never larger), shrinking by safeguarded quadratic interpolation (factor in
  ``[0.1, 0.5]``).  When a step ``t < 1`` is accepted, up to three more trials
  between it and the last rejected step look for a lower energy (an energy
  evaluation costs ~1/20 of an iteration; this saves ~25 % of the iterations on
  large deformations).
* Stopping (first rule that holds, see :data:`~lacore.reconstruction.result.STATUS_MESSAGES`):
  energy at the floating-point noise level of ``W`` around ``z*`` (status 1);
  relative energy decrease ``W_k - W_{k+1} <= ftol W_k``, predicted
  Gauss-Newton decrease ``-g.d / 2 <= ftol W_k``, or -- in the linear
  convergence phase of a non-zero residual, two full steps in a row with
  decrease ratio ``r = dW_k / dW_{k-1} < 1/2`` -- estimated remaining decrease
  ``10 dW_k r / (1 - r) <= ftol W_{k+1}`` (2), which saves the final
  factorization that would only confirm convergence; scale-free gradient
  ``|g|_inf * size <= gtol * W`` (3); step ``|t d|_inf <= xtol * size`` (4);
  ``size`` = bounding-box diagonal of the reference mesh.  The iteration cap
  gives status 0, a line search without decrease status -1.

Angle residuals are not wrapped: ``theta`` lies in ``(-pi, pi]`` and a target
angle near ``+-pi`` whose reconstruction crosses the branch cut is penalized by
``~2 pi``, as in the thesis.
"""

import time
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp

from ..errors import LengthsAnglesError, MeshError, format_indices
from ..lengths_angles import _jacobian_pattern, check_z, lengths_and_angles, lengths_and_angles_jacobian
from ..sparse_cholesky import NotPositiveDefiniteError, SparseCholesky, default_backend, nested_dissection
from ..topology import check_vertices
from .result import STATUS_MESSAGES, ReconstructionResult

__all__ = [
    "ReconstructionContext",
    "get_context",
    "gauss_newton_reconstruction",
    "run_gauss_newton",
    "gauss_newton_pattern",
    "preconditioned_cg",
    "triangle_frame",
    "GN_OPTIONS",
]

#: Default Gauss-Newton options (keyword arguments of :func:`run_gauss_newton`).
GN_OPTIONS = {"max_iterations": 100, "ftol": 1e-9, "gtol": 1e-8, "xtol": 1e-12, "atol": None,
              "reuse_factorization": False, "pcg_rtol": 0.1, "pcg_maxiter": 6, "reuse_near_convergence": True,
              "geodesic_acceleration": True}

#: PCG has stalled (refactorize) when ``pcg_maxiter`` iterations reduced the relative residual less than this.
_PCG_STALL = 0.5

#: Near convergence (``reuse_near_convergence``): the last step was a full step and the vertices moved by at most
#: this fraction of the mean target edge length (sum of the steps' max-norms) since the held factorization ...
_NEAR_DRIFT = 0.05
#: ... then PCG with the held factor solves to the relative residual
#: ``min(_NEAR_RTOL_MAX, max(W_k / W_{k-1}, 0.1 sqrt(atol / W_k), _NEAR_RTOL_MIN))`` in at most
#: ``_NEAR_MAXITER`` iterations, else the step refactorizes.
_NEAR_RTOL_MAX = 1e-2
_NEAR_RTOL_MIN = 1e-12
_NEAR_MAXITER = 8

#: Geodesic acceleration (``geodesic_acceleration``): finite-difference step (fraction of the step ``d``), ...
_ACCEL_FD_STEP = 0.1
#: ... only for steps ``max|d|`` above this fraction of the mean target edge length (below, Gauss-Newton converges
#: fast and the finite difference loses digits) ...
_ACCEL_MIN_STEP = 1e-3
#: ... and only when ``2 |a| <= _ACCEL_MAX_RATIO |d|``.
_ACCEL_MAX_RATIO = 1.5

_I6, _J6 = np.triu_indices(6)
_I12, _J12 = np.triu_indices(12)
_EPS = np.finfo(float).eps


def _dot(a, b):
    """``a . b`` of two 1-D float arrays without BLAS.

    NumPy's OpenBLAS runs ``ddot`` multithreaded above 10000 entries (an energy
    has ``2E``); its worker threads then spin-wait, which doubled the CPU time
    of a reconstruction on an idle 2-core machine at no gain in wall time.
    ``einsum`` uses NumPy's own (SIMD, single-threaded) loops.
    """
    return float(np.einsum("i,i->", a, b))


# --------------------------------------------------------------------------- pattern
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
        then ``(78, E_int)``, pairs in ``np.triu_indices`` order; ``nnz``, ``n``.
    """
    def compute():
        n = 3 * topology.n_vertices
        E, Ei = topology.n_edges, len(topology.interior_edges)
        jp = _jacobian_pattern(topology)
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
                "local_order": local_order, "nnz": len(ukeys), "n": n}
    return topology._cached("lacore.reconstruction.gauss_newton_pattern", compute)


def _upper_outer(g, gw, out):
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


def _dof_ordering(topology, pattern, vertices):
    """Nested-dissection ordering of the coordinates: vertex order from the mesh geometry, 3 coordinates each."""
    V = topology.n_vertices
    rows, cols = pattern["indices"] // 3, pattern["cols"] // 3
    G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(V, V))
    order = nested_dissection(G + G.T, vertices)
    return (3 * order[:, None] + np.arange(3)).ravel()


# --------------------------------------------------------------------------- gauge
def triangle_frame(vertices, face):
    """3-2-1 frame of a triangle: origin ``X_a`` and rotation ``Q`` (rows: x, y, z axes).

    Parameters
    ----------
    vertices : (V, 3) ndarray
    face : (3,) int
        Vertex indices ``a, b, c`` (counter-clockwise).

    Returns
    -------
    origin : (3,) ndarray
    Q : (3, 3) ndarray
        Orthonormal rows ``e1 = (X_b - X_a) / |X_b - X_a|``, ``e2 = n x e1`` and
        the unit normal ``n``.  Canonical coordinates are ``(X - origin) @ Q.T``.

    Raises
    ------
    MeshError
        If the triangle is degenerate.
    """
    a, b, c = vertices[face[0]], vertices[face[1]], vertices[face[2]]
    e1 = b - a
    n = np.cross(e1, c - a)
    ln, l1 = np.linalg.norm(n), np.linalg.norm(e1)
    if not (ln > 0 and l1 > 0 and np.isfinite(ln)):
        raise MeshError(f"the fixed face {tuple(int(v) for v in face)} is degenerate (zero area)")
    e1 = e1 / l1
    n = n / ln
    return a.copy(), np.stack([e1, np.cross(n, e1), n])


def _fixed_faces(topology, reference_vertices, fixed_face):
    """One fixed face per connected component: ``fixed_face`` (int or sequence) completed by the defaults."""
    from .spanning_trees import default_root_faces

    n_comp, labels = topology.face_components()
    faces = np.asarray(default_root_faces(topology, vertices=reference_vertices), np.int64)
    if fixed_face is None:
        return faces
    given = np.atleast_1d(np.asarray(fixed_face))
    if given.ndim != 1 or not np.issubdtype(given.dtype, np.integer):
        raise MeshError(f"fixed_face must be a face index (or one per component), got {fixed_face!r}")
    bad = given[(given < 0) | (given >= topology.n_faces)]
    if bad.size:
        raise MeshError(f"fixed_face {format_indices(bad)} out of range: the mesh has {topology.n_faces} faces")
    comp = labels[given]
    if len(np.unique(comp)) != len(comp):
        raise MeshError(f"fixed faces {format_indices(given)} include two faces of the same component")
    faces[comp] = given
    return faces


def _gauge_dofs(faces, fix_triangle_shape):
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    dofs = [3 * a, 3 * a + 1, 3 * a + 2, 3 * b + 1, 3 * b + 2, 3 * c + 2]
    if fix_triangle_shape:
        dofs += [3 * b, 3 * c, 3 * c + 1]
    return np.unique(np.concatenate(dofs))


# --------------------------------------------------------------------------- objectives
def _reference_weights(reference_vertices, topology, weights, bending_weight):
    """Residual weights ``(2E,)`` of ``W_q`` from :class:`lacore.energies.QuadraticEnergy`."""
    from ..energies import QuadraticEnergy

    energy = QuadraticEnergy(topology, reference_vertices=reference_vertices, weights=weights,
                             bending_weight=bending_weight)
    return np.asarray(energy.residual_weights, float)


class _QuadraticObjective:
    """``W_q[z*, Z(X)]``: value, gradient and Gauss-Newton matrix values in the pattern's order."""

    name = "quadratic"

    def __init__(self, z_target, residual_weights, topology, pattern, buffer=None):
        self.z_target = z_target
        self.w = residual_weights
        self.topology = topology
        self.pattern = pattern
        E = topology.n_edges
        self._w2_len = 2.0 * residual_weights[:E]
        self._w2_ang = 2.0 * residual_weights[E + topology.interior_edges]
        self._n_len = 6 * E
        self._vals = np.empty(len(pattern["slots"])) if buffer is None else buffer

    def value_z(self, z):
        r = z - self.z_target
        return _dot(self.w * r, r)

    def energy(self, X):
        return self.value_z(lengths_and_angles(X, self.topology, check=False))

    def linearize(self, X):
        """Energy, gradient ``(3V,)`` and a function returning the Gauss-Newton matrix values at ``X``."""
        J, z = lengths_and_angles_jacobian(X, self.topology, return_z=True)
        r = z - self.z_target
        wr = self.w * r
        energy = _dot(wr, r)
        grad = 2.0 * (J.T @ wr)
        return energy, grad, _QuadraticGNMatrix(self, J, z)

    def acceleration_gradient(self, X, d, matrix, h):
        """``2 J^T W r_vv``: right-hand side of the geodesic acceleration for the direction ``d`` (``(3V,)``).

        ``r_vv`` is the second directional derivative of the residual
        ``Z(X) - z*`` along ``d``, by the finite difference
        ``(2 / h) ((Z(X + h d) - Z(X)) / h - J d)`` (one evaluation of ``Z``).
        """
        zh = lengths_and_angles(X + h * d.reshape(-1, 3), self.topology, check=False)
        rvv = (2.0 / h) * ((zh - matrix.z) / h - matrix.J @ d)
        return 2.0 * (matrix.J.T @ (self.w * rvv))

    def noise_floor(self):
        """``W_q`` of a perturbation of 16 ulp of every entry of ``z*`` (angles: of pi)."""
        E = self.topology.n_edges
        scale = np.concatenate([np.abs(self.z_target[:E]), np.full(E, np.pi)])
        return float(np.sum(self.w * (16 * _EPS * scale) ** 2))


class _QuadraticGNMatrix:
    """The Gauss-Newton matrix ``2 J^T W J`` of ``W_q`` at one point.

    Calling it returns the values in the pattern's order (for a factorization);
    :meth:`dot` multiplies without assembling (two sparse products with ``J``).
    """

    def __init__(self, objective, J, z):
        self.objective = objective
        self.J = J
        self.z = z
        self._w2 = 2.0 * objective.w

    def __call__(self):
        obj, J = self.objective, self.J
        local = J.data[obj.pattern["local_order"]]
        gl = local[: obj._n_len].reshape(6, -1)
        ga = local[obj._n_len:].reshape(12, -1)
        vals = obj._vals  # reused buffer: no page faults for a fresh multi-MB array per iteration
        m = 21 * gl.shape[1]
        _upper_outer(gl, gl * obj._w2_len, vals[:m].reshape(21, -1))
        _upper_outer(ga, ga * obj._w2_ang, vals[m:].reshape(78, -1))
        return np.bincount(obj.pattern["slots"], weights=vals, minlength=obj.pattern["nnz"])

    def dot(self, v):
        """``2 J^T W J v`` for ``v`` of shape ``(3V,)``."""
        return self.J.T @ (self._w2 * (self.J @ v))


class _AssembledGNMatrix:
    """A Gauss-Newton matrix given by a function returning its lower-triangle values (pattern order).

    :meth:`dot` assembles once and multiplies with the symmetric matrix.
    """

    def __init__(self, values, pattern):
        self._values = values
        self._pattern = pattern
        self._lower = None

    def __call__(self):
        return self._values()

    def dot(self, v):
        """Product of the symmetric matrix with ``v`` of shape ``(n,)``."""
        if self._lower is None:
            p = self._pattern
            self._lower = sp.csc_matrix((self._values(), p["indices"], p["indptr"]), shape=(p["n"], p["n"]))
        L = self._lower
        return L @ v + L.T @ v - L.diagonal() * v


class _ShellsObjective:
    """``W_TS[z*, Z(X)]`` through :class:`lacore.energies.EnergyInVertices`."""

    name = "shells"

    def __init__(self, z_target, topology, bending_weight, solver, pattern):
        from ..energies import EnergyInVertices, ThinShellsEnergy

        self.shells = ThinShellsEnergy(topology, bending_weight=bending_weight)
        self.model = EnergyInVertices(self.shells, z_target, topology)
        self.z_target = z_target
        self.topology = topology
        self.solver = solver
        self.pattern = pattern

    def value_z(self, z):
        return float(self.shells.value(self.z_target, z))

    def energy(self, X):
        return self.value_z(lengths_and_angles(X, self.topology, check=False))

    def linearize(self, X):
        value, grad = self.model.value_and_gradient(X)

        def values():
            return self.solver.values_from_matrix(self.model.gauss_newton_hessian(X))
        return float(value), np.asarray(grad, float).ravel(), _AssembledGNMatrix(values, self.pattern)

    def noise_floor(self):
        """Round-off level of ``W_TS`` near ``z*``: ``16 eps (mu + lam) * total area``.

        The membrane density cancels terms of size ``mu``, ``lam`` per unit area
        at ``G = I``, so its value carries an absolute error of that order.
        """
        from ..trigonometry import triangle_areas

        area = float(np.sum(triangle_areas(self.z_target[: self.topology.n_edges][self.topology.face_edges])))
        return 16 * _EPS * (self.shells.mu + self.shells.lam) * area


# --------------------------------------------------------------------------- context
class ReconstructionContext:
    """Everything about a reconstruction set-up that does not depend on the target.

    Holds the residual weights (from the reference mesh), the fixed faces and
    their reference frames, the Gauss-Newton sparsity pattern and the sparse
    Cholesky object with its symbolic (and last numeric) factorization.
    (Spanning trees are cached on the topology (BFS) or passed as ``tree=`` to
    :func:`lacore.reconstruction.reconstruct`, e.g. a preassembled tree.)  Pass one context to
    many :func:`lacore.reconstruction.reconstruct` calls (e.g. the frames of an
    interpolation, each warm-started from the previous one) to share all of it.
    :func:`get_context` keeps the last few contexts per topology, so repeated
    calls with identical settings share them without passing one explicitly.

    A context holds one numeric factorization and is not thread-safe: use one
    context per thread.

    Parameters
    ----------
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh: source of the weights (3.20)/(3.21), the default
        starting point and the output frame.
    energy : {"quadratic", "shells"}
        ``W_q`` (3.19) or ``W_TS`` (3.25).
    weights : {"frohlich_botsch", "heeren", "uniform"}
        Weights of ``W_q``: (3.20), (3.21) or all 1.
    bending_weight : float
        ``eta`` in (3.19)/(3.25).
    fixed_face : int or sequence of int, optional
        Face fixing the rigid motion (one per connected component; components
        not given get their default, see the module docstring).
    fix_triangle_shape : bool
        Hold all nine coordinates of the fixed faces (see module docstring).
    solver : {"cholmod", "scipy"}, optional
        Sparse Cholesky backend, default :func:`lacore.sparse_cholesky.default_backend`.

    Raises
    ------
    MeshError
        For reference vertices that do not fit the topology, a bad or degenerate
        fixed face.
    """

    def __init__(self, topology, reference_vertices, energy="quadratic", weights="frohlich_botsch",
                 bending_weight=1e-3, fixed_face=None, fix_triangle_shape=False, solver=None):
        if energy not in ("quadratic", "shells"):
            raise ValueError(f"unknown energy {energy!r}; use 'quadratic' or 'shells'")
        if not (np.isfinite(bending_weight) and bending_weight >= 0):
            raise ValueError(f"bending_weight must be a finite number >= 0, got {bending_weight!r}")
        if weights not in ("frohlich_botsch", "heeren", "uniform"):
            raise ValueError(f"unknown weights {weights!r}; use 'frohlich_botsch', 'heeren' or 'uniform'")
        backend = default_backend() if solver is None else solver
        if backend not in ("cholmod", "scipy"):
            raise ValueError(f"unknown solver {solver!r}; use 'cholmod' or 'scipy'")
        self.topology = topology
        X = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices").copy()
        X.setflags(write=False)
        self.reference_vertices = X
        self.energy_name = energy
        self.weights_kind = weights
        self.bending_weight = float(bending_weight)
        self.fix_triangle_shape = bool(fix_triangle_shape)
        self.backend = backend
        self.fixed_faces = _fixed_faces(topology, X, fixed_face)
        self.fixed_face = int(self.fixed_faces[0])
        self._face_vertices = topology.faces[self.fixed_faces]  # (C, 3)
        frames = [triangle_frame(X, f) for f in self._face_vertices]
        self._origins = np.array([o for o, _ in frames])
        self._Qs = np.array([Q for _, Q in frames])
        labels = topology.face_components()[1]
        self._vertex_component = np.zeros(topology.n_vertices, np.int64)
        self._vertex_component[topology.faces.ravel()] = np.repeat(labels, 3)
        self.fixed_dofs = _gauge_dofs(self._face_vertices, self.fix_triangle_shape)
        self.size = float(np.linalg.norm(X.max(0) - X.min(0))) or 1.0
        self._residual_weights = None
        self._solver = None
        self._buffer = None
        self._fixed_entries = None

    @property
    def pattern(self):
        """:func:`gauss_newton_pattern` of the topology."""
        return gauss_newton_pattern(self.topology)

    @property
    def residual_weights(self):
        """``(2E,)`` weights of ``W_q`` (lengths: ``w_s``, angles: ``eta w_b``)."""
        if self._residual_weights is None:
            w = _reference_weights(self.reference_vertices, self.topology, self.weights_kind, self.bending_weight)
            w.setflags(write=False)
            self._residual_weights = w
        return self._residual_weights

    @property
    def solver(self):
        """The :class:`~lacore.sparse_cholesky.SparseCholesky` (symbolic analysis on first use)."""
        if self._solver is None:
            pat = self.pattern
            ordering = None
            if self.backend == "cholmod":
                ordering = _dof_ordering(self.topology, pat, self.reference_vertices)
            s = SparseCholesky(pat["matrix"], backend=self.backend, ordering=ordering)
            if not (np.array_equal(s.indptr, pat["indptr"]) and np.array_equal(s.indices, pat["indices"])):
                raise RuntimeError("sparse Cholesky pattern mismatch")  # pragma: no cover
            self._solver = s
        return self._solver

    @property
    def fixed_entries(self):
        """Value positions touching fixed coordinates (zeroed) and their diagonal positions (set to 1)."""
        if self._fixed_entries is None:
            pat = self.pattern
            is_fixed = np.zeros(pat["n"], bool)
            is_fixed[self.fixed_dofs] = True
            touch = np.flatnonzero(is_fixed[pat["indices"]] | is_fixed[pat["cols"]])
            diag = touch[pat["indices"][touch] == pat["cols"][touch]]
            self._fixed_entries = (touch, diag)
        return self._fixed_entries

    # coordinates
    def to_canonical(self, vertices):
        """Rigidly move every component so that its fixed face sits in the 3-2-1 position.

        Returns ``(V, 3)`` coordinates whose fixed coordinates are exactly 0.
        """
        X = np.asarray(vertices, float)
        frames = [triangle_frame(X, f) for f in self._face_vertices]
        origins = np.array([o for o, _ in frames])
        Qs = np.array([Q for _, Q in frames])
        comp = self._vertex_component
        Xc = np.einsum("vij,vj->vi", Qs[comp], X - origins[comp])
        a, b, c = self._face_vertices.T
        Xc[a] = 0.0
        Xc[b, 1:] = 0.0
        Xc[c, 2] = 0.0
        return Xc

    def from_canonical(self, Xc):
        """Canonical coordinates -> the reference mesh's frame (see module docstring)."""
        comp = self._vertex_component
        return np.einsum("vji,vj->vi", self._Qs[comp], Xc) + self._origins[comp]

    def align(self, vertices):
        """Rigidly move ``vertices`` (per component) into the output frame of this context."""
        return self.from_canonical(self.to_canonical(vertices))

    def objective(self, z_target):
        """The energy ``X -> W[z*, Z(X)]`` for a target (``z*`` already validated)."""
        if self.energy_name == "quadratic":
            if self._buffer is None:  # outer-product values, reused by all targets of this context
                self._buffer = np.empty(len(self.pattern["slots"]))
            return _QuadraticObjective(z_target, self.residual_weights, self.topology, self.pattern, self._buffer)
        return _ShellsObjective(z_target, self.topology, self.bending_weight, self.solver, self.pattern)

    def energy(self, z_target, vertices):
        """``W[z*, Z(vertices)]`` under this context's energy."""
        z = lengths_and_angles(vertices, self.topology)
        return self.objective(np.asarray(z_target, float)).value_z(z)


_CONTEXTS_PER_TOPOLOGY = 4


def get_context(topology, reference_vertices, **settings):
    """A cached :class:`ReconstructionContext` for these reference vertices and settings.

    The last few contexts are kept on the topology, keyed by the reference
    coordinates' bytes and the settings (keyword arguments of
    :class:`ReconstructionContext`), so repeated reconstructions with the same
    set-up reuse weights and the symbolic factorization.
    """
    X = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices")
    ff = settings.get("fixed_face")
    if ff is not None:
        settings["fixed_face"] = tuple(np.atleast_1d(np.asarray(ff)).tolist())
    cache = topology._cached("lacore.reconstruction.contexts", OrderedDict)
    key = (X.tobytes(), tuple(sorted(settings.items())))
    ctx = cache.get(key)
    if ctx is None:
        ctx = ReconstructionContext(topology, X, **settings)
        cache[key] = ctx
        while len(cache) > _CONTEXTS_PER_TOPOLOGY:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    return ctx


# --------------------------------------------------------------------------- solver
def _line_search(objective, X, d, energy, slope, c1, max_backtracks, refine=8, accel=None, theta=None):
    """Armijo backtracking from the full step ``t = 1``; returns ``(t, X_new, E_new, evaluations)``.

    The trial points are ``X + t d``, or ``X + t d + t^2 accel / 2`` along the
    parabola of a geodesic acceleration ``accel`` (same slope ``g.d`` at 0).

    Trial steps shrink by safeguarded quadratic interpolation.  When a step
    ``t < 1`` is accepted after the larger ``t_prev`` was rejected, up to
    ``refine`` further trials in ``(t, t_prev)`` (minimizers of the quadratic
    through ``E(0), E'(0), E(t)``) look for a lower energy: an evaluation of
    ``Z`` costs far less than a Gauss-Newton iteration.

    With ``theta = (target, unfolded)`` (the target dihedral angles and a mask
    of the edges whose angle at ``X`` is within ``pi / 2`` of it), trials
    folding one of these edges -- its angle more than ``pi / 2`` off the target --
    are rejected (the step is halved): such a step turns the surface over or
    crosses the branch cut at ``+-pi``, into another, usually worse, local
    minimum.
    """
    E = objective.topology.n_edges

    def trial(tt):
        Xt = X + tt * d if accel is None else X + tt * d + (0.5 * tt * tt) * accel
        if theta is None:
            return Xt, objective.energy(Xt), False
        z = lengths_and_angles(Xt, objective.topology, check=False)
        if np.any(np.abs(z[E:][theta[1]] - theta[0][theta[1]]) > 0.5 * np.pi):
            return Xt, np.nan, True
        return Xt, objective.value_z(z), False

    t, t_prev = 1.0, None
    for k in range(max_backtracks):
        Xt, Et, turned = trial(t)
        if np.isfinite(Et) and Et <= energy + c1 * t * slope:
            n = k + 1
            for _ in range(refine if t_prev is not None else 0):
                denom = 2.0 * (Et - energy - slope * t)
                t_try = -slope * t * t / denom if denom > 0 else 2.0 * t
                t_try = min(t_try, 0.5 * (t + t_prev), 2.0 * t)
                if not t_try > 1.05 * t:
                    break
                X_try, E_try, _ = trial(t_try)
                n += 1
                if not (np.isfinite(E_try) and E_try < Et):
                    break
                t, Xt, Et = t_try, X_try, E_try
            return t, Xt, Et, n
        t_prev = t
        if turned:
            t *= 0.5
        elif np.isfinite(Et):
            # minimizer of the quadratic through E(0), E'(0) and E(t), kept in [0.1 t, 0.5 t]
            denom = 2.0 * (Et - energy - slope * t)
            t_new = -slope * t * t / denom if denom > 0 else 0.5 * t
            t = min(0.5 * t, max(0.1 * t, t_new))
        else:
            t *= 0.1
    return 0.0, X, energy, max_backtracks


def preconditioned_cg(matvec, b, precondition, fixed, rtol, maxiter):
    """Preconditioned conjugate gradients for ``A x = b`` on the free coordinates.

    Parameters
    ----------
    matvec : callable
        ``v -> A v`` for the symmetric positive (semi-)definite ``A``.
    b : (n,) ndarray
        Right-hand side; its ``fixed`` entries are ignored (treated as 0).
    precondition : callable
        ``r -> M^{-1} r`` for a symmetric positive definite ``M`` (e.g. a
        Cholesky factorization of ``A`` at another point).
    fixed : (k,) int array
        Coordinates held at 0 (rows and columns of ``A`` removed).
    rtol : float
        Stop when ``sqrt(r^T M^{-1} r) <= rtol sqrt(b^T M^{-1} b)`` (relative
        residual in the preconditioner's dual norm).
    maxiter : int
        At most this many iterations (each: one ``matvec``, one ``precondition``).

    Returns
    -------
    x : (n,) ndarray
        The last iterate (``x[fixed] = 0``).
    iterations : int
    relative_residual : float
        ``sqrt(r^T M^{-1} r / b^T M^{-1} b)`` of the returned iterate; ``inf``
        when a non-positive curvature ``p^T A p <= 0`` stopped the iteration.
    """
    b = np.array(b, dtype=float)
    b[fixed] = 0.0
    x = np.zeros_like(b)
    r = b
    zr = precondition(r)
    zr[fixed] = 0.0
    rz = _dot(r, zr)
    if not rz > 0:
        return x, 0, 0.0 if rz == 0.0 else np.inf
    rz0 = rz
    target = rtol * rtol * rz
    p = zr
    for k in range(1, int(maxiter) + 1):
        Ap = matvec(p)
        Ap[fixed] = 0.0
        curv = _dot(p, Ap)
        if not (curv > 0 and np.isfinite(curv)):
            return x, k, np.inf
        alpha = rz / curv
        x = x + alpha * p
        r = r - alpha * Ap
        zr = precondition(r)
        zr[fixed] = 0.0
        rz_new = _dot(r, zr)
        if rz_new <= target:
            return x, k, float(np.sqrt(rz_new / rz0))
        p = zr + (rz_new / rz) * p
        rz = rz_new
    return x, int(maxiter), float(np.sqrt(max(rz, 0.0) / rz0))


def run_gauss_newton(objective, Xc, context, *, max_iterations=100, ftol=1e-9, gtol=1e-8, xtol=1e-12,
                     atol=None, reuse_factorization=False, pcg_rtol=0.1, pcg_maxiter=6,
                     reuse_near_convergence=True, geodesic_acceleration=True, c1=1e-4, max_backtracks=40):
    """Gauss-Newton iterations in canonical coordinates (see the module docstring for the rules).

    Parameters
    ----------
    objective : object
        With ``energy(X)``, ``linearize(X) -> (energy, gradient (3V,), matrix)``
        (``matrix()`` returns the Gauss-Newton matrix values in the pattern's
        order; it is only called when a step is computed) and ``noise_floor()``.
    Xc : (V, 3) ndarray
        Start, in canonical coordinates of ``context`` (fixed coordinates 0).
    context : ReconstructionContext
    max_iterations : int
    ftol, gtol, xtol : float
        Stopping tolerances (module docstring).
    atol : float, optional
        Absolute energy tolerance; default ``objective.noise_floor()``.
    reuse_factorization : bool
        Inexact steps: solve the Gauss-Newton system by :func:`preconditioned_cg`
        with the factorization already held by ``context.solver`` (from an
        earlier iteration or an earlier call with this context, i.e. another
        pose) as the preconditioner, and refactorize at the current point only
        when PCG stalls -- ``pcg_maxiter`` iterations reduce the relative
        residual by less than a factor 2 -- or gives no descent direction (the new factor is then kept for the
        following steps and calls).  Default ``False``: a fresh factorization
        and an exact step every iteration.
    pcg_rtol : float
        Relative residual at which PCG stops (``0 < pcg_rtol < 1``).
    pcg_maxiter : int
        PCG iterations before refactorizing (``>= 1``).
    reuse_near_convergence : bool
        Without ``reuse_factorization``: once the iteration is in its local
        (fast or linear) convergence phase -- the last step was a full step
        and the vertices moved by at most 5 % of the mean target edge length
        (sum of the steps' max-norms) since the last factorization, so the
        Gauss-Newton matrix changed little -- solve by :func:`preconditioned_cg` with the factorization
        made earlier in *this* call, to the relative residual
        ``min(1e-2, max(W_k / W_{k-1}, 0.1 sqrt(atol / W_k)))`` (a forcing
        term that keeps superlinear convergence at zero residual, but asks no
        more than reaching the noise floor ``atol`` needs) in at most 8 iterations,
        refactorizing at the current point when that fails.  A PCG iteration
        costs ~1/8 of a factorization on the finger (~1/12 on a 5k-vertex
        closed mesh), and near the solution 1-6 suffice.  Default ``True``.
    geodesic_acceleration : bool
        Second-order (geodesic acceleration) correction of exact steps and the
        fold safeguard of the line search (module docstring); only for
        objectives with ``acceleration_gradient`` (``W_q``).  Default ``True``.
    c1 : float
        Armijo constant.
    max_backtracks : int
        Line-search trials before giving up.

    Returns
    -------
    dict
        ``X, status, iterations, energy, initial_energy, history, gradient_norm,
        steps, shifts, evaluations, factorizations, pcg_iterations, timings``
        (``pcg_iterations``: per step, the PCG iterations used; 0 for an exact step).
    """
    if not 0 < pcg_rtol < 1:
        raise ValueError(f"pcg_rtol must lie in (0, 1), got {pcg_rtol!r}")
    if int(pcg_maxiter) != pcg_maxiter or pcg_maxiter < 1:
        raise ValueError(f"pcg_maxiter must be a positive integer, got {pcg_maxiter!r}")
    solver = context.solver
    touch, diag = context.fixed_entries
    fixed = context.fixed_dofs
    size = context.size
    atol = objective.noise_floor() if atol is None else float(atol)
    timings = {"assembly": 0.0, "factorization": 0.0, "solve": 0.0, "line_search": 0.0, "acceleration": 0.0}
    X = np.array(Xc, dtype=float)
    history, steps, shifts, pcg_its = [], [], [], []
    factorizations = evaluations = it = 0
    status = 0
    prev_decrease = np.inf
    own_factor = False     # the held factorization was made in this call ...
    drift = np.inf         # ... at a point this far (sum of max-norm steps) from X
    edge = float(np.mean(objective.z_target[: objective.topology.n_edges]))
    max_drift = _NEAR_DRIFT * edge
    accelerate = geodesic_acceleration and hasattr(objective, "acceleration_gradient")
    prev_energy = np.inf
    while True:
        t0 = time.perf_counter()
        energy, grad, matrix = objective.linearize(X)
        evaluations += 1
        grad[fixed] = 0.0
        gnorm = float(np.max(np.abs(grad)))
        timings["assembly"] += time.perf_counter() - t0
        if not history:
            if not np.isfinite(energy):
                raise LengthsAnglesError("the energy is not finite at the starting point: the start or the target "
                                         "has triangles violating the triangle inequality")
            history.append(energy)
        if energy <= atol:
            status = 1
            break
        if gnorm * size <= gtol * energy:
            status = 3
            break
        if it >= max_iterations:
            status = 0
            break
        # Gauss-Newton direction: PCG with the held factorization, or an exact step with a fresh one
        d = None
        fresh = False
        if reuse_factorization and solver.has_factor:
            t0 = time.perf_counter()
            d, n_cg, rel = preconditioned_cg(matrix.dot, -grad, solver.solve, fixed, pcg_rtol, pcg_maxiter)
            timings["solve"] += time.perf_counter() - t0
            slope = _dot(grad, d)
            if rel <= _PCG_STALL and slope < 0:
                pcg_its.append(n_cg)
            else:
                d = None  # PCG stalled: refactorize at the current point
        elif reuse_near_convergence and own_factor and steps[-1] == 1.0 and drift <= max_drift:
            t0 = time.perf_counter()
            # forcing term W_k / W_{k-1}: superlinear convergence; no more accuracy than the noise floor needs
            # (a residual rtol |g| leaves about rtol^2 W_k of the linearized energy)
            rtol = min(_NEAR_RTOL_MAX, max(_NEAR_RTOL_MIN, energy / prev_energy, 0.1 * np.sqrt(atol / energy)))
            d, n_cg, rel = preconditioned_cg(matrix.dot, -grad, solver.solve, fixed, rtol, _NEAR_MAXITER)
            timings["solve"] += time.perf_counter() - t0
            slope = _dot(grad, d)
            if rel <= rtol and slope < 0:
                pcg_its.append(n_cg)
            else:
                d = None  # not close enough to the factorized point: refactorize
        if d is None:
            t0 = time.perf_counter()
            H = matrix()
            H[touch] = 0.0
            H[diag] = 1.0
            t1 = time.perf_counter()
            timings["assembly"] += t1 - t0
            t0 = t1
            try:
                solver.factorize(H)
            except NotPositiveDefiniteError:
                timings["factorization"] += time.perf_counter() - t0
                status = -2
                break
            factorizations += 1
            own_factor, drift = True, 0.0
            shifts.append(solver.shift)
            pcg_its.append(0)
            t1 = time.perf_counter()
            timings["factorization"] += t1 - t0
            d = solver.solve(-grad)
            timings["solve"] += time.perf_counter() - t1
            d[fixed] = 0.0
            slope = _dot(grad, d)
            fresh = True
        if not slope < 0:
            status = -1
            break
        if -0.5 * slope <= ftol * energy:  # predicted Gauss-Newton decrease negligible
            status = 2
            break
        # geodesic acceleration: second-order correction of the path with the same factorization
        accel = None
        if accelerate and fresh and float(np.max(np.abs(d))) > _ACCEL_MIN_STEP * edge:
            t0 = time.perf_counter()
            b = objective.acceleration_gradient(X, d, matrix, _ACCEL_FD_STEP)
            evaluations += 1
            b[fixed] = 0.0
            if np.all(np.isfinite(b)):
                a = solver.solve(-b)
                a[fixed] = 0.0
                if 2.0 * np.sqrt(_dot(a, a)) <= _ACCEL_MAX_RATIO * np.sqrt(_dot(d, d)):
                    accel = a.reshape(-1, 3)
            timings["acceleration"] += time.perf_counter() - t0
        # line search (along the accelerated parabola, else -- or if that fails -- along d)
        t0 = time.perf_counter()
        theta = None
        if accelerate:  # no step may fold an edge (angle more than pi/2 off target) that is not folded yet
            E = objective.topology.n_edges
            target = objective.z_target[E:]
            theta = (target, np.abs(matrix.z[E:] - target) <= 0.5 * np.pi)
        t = 0.0
        if accel is not None:
            t, X_new, E_new, n_eval = _line_search(objective, X, d.reshape(-1, 3), energy, slope, c1,
                                                   max_backtracks, accel=accel, theta=theta)
            evaluations += n_eval
        if t == 0.0:
            t, X_new, E_new, n_eval = _line_search(objective, X, d.reshape(-1, 3), energy, slope, c1,
                                                   max_backtracks, theta=theta)
            evaluations += n_eval
        if t == 0.0 and theta is not None:  # only folding steps decrease the energy: allow them
            t, X_new, E_new, n_eval = _line_search(objective, X, d.reshape(-1, 3), energy, slope, c1,
                                                   max_backtracks)
            evaluations += n_eval
        timings["line_search"] += time.perf_counter() - t0
        if t == 0.0:
            status = 1 if energy <= 1e6 * atol else -1
            break
        it += 1
        steps.append(t)
        history.append(E_new)
        decrease = energy - E_new
        prev_energy = energy
        step_norm = float(np.max(np.abs(X_new - X)))
        drift += step_norm
        X = X_new
        if E_new <= atol:
            continue  # status 1 after evaluating the final gradient
        # linear convergence with full steps: the remaining decrease is about dec r / (1 - r), r = dec / dec_prev
        # (estimated with a safety factor 10)
        rate = decrease / prev_decrease if len(steps) > 1 and t == 1.0 and steps[-2] == 1.0 else 1.0
        prev_decrease = decrease
        if decrease <= ftol * energy or (rate < 0.5 and 10.0 * decrease * rate / (1.0 - rate) <= ftol * E_new):
            status = 2
        elif step_norm <= xtol * size:
            status = 4
        else:
            continue
        # converged after a step: report energy and gradient at the final point (the matrix is not needed)
        t0 = time.perf_counter()
        energy, grad, _ = objective.linearize(X)
        evaluations += 1
        grad[fixed] = 0.0
        gnorm = float(np.max(np.abs(grad)))
        timings["assembly"] += time.perf_counter() - t0
        break
    return {"X": X, "status": status, "iterations": it, "energy": float(energy), "initial_energy": history[0],
            "history": history, "gradient_norm": gnorm, "steps": steps, "shifts": shifts,
            "evaluations": evaluations, "factorizations": factorizations, "pcg_iterations": pcg_its,
            "timings": timings}


def gauss_newton_reconstruction(z_target, topology, reference_vertices=None, *, initial_vertices=None,
                                context=None, method_name="gn", **options):
    """Energy-based reconstruction ``R_W[z*]`` (Def. 3.15) by Gauss-Newton.

    Parameters
    ----------
    z_target : (2E,) array_like
        Target lengths and angles ``z*``.
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh (weights, default start, output frame).  May be omitted
        when ``context`` is given.
    initial_vertices : (V, 3) array_like, optional
        Starting point (e.g. the previous frame of an animation, or a
        frame-based reconstruction); default the reference mesh.  Its rigid
        placement does not matter.
    context : ReconstructionContext, optional
        Shared set-up; default :func:`get_context` with the context settings in ``options``.
    method_name : str
        Reported as :attr:`ReconstructionResult.method`.
    **options
        Gauss-Newton options (:data:`GN_OPTIONS`, see :func:`run_gauss_newton`) and,
        without ``context``, the settings of :class:`ReconstructionContext`
        (``energy, weights, bending_weight, fixed_face, fix_triangle_shape, solver``).

    Returns
    -------
    ReconstructionResult
    """
    t_start = time.perf_counter()
    gn_options = {k: options.pop(k) for k in list(options) if k in GN_OPTIONS}
    if context is None:
        if reference_vertices is None:
            raise ValueError("give reference_vertices or a context")
        context = get_context(topology, reference_vertices, **options)
    elif options:
        raise ValueError(f"settings {sorted(options)} are fixed by the given context")
    z_target = check_z(z_target, topology, name="target z")
    X0 = context.reference_vertices if initial_vertices is None else check_vertices(
        initial_vertices, topology.n_vertices, name="initial vertices")
    objective = context.objective(z_target)
    Xc = context.to_canonical(X0)
    t_init = time.perf_counter() - t_start
    out = run_gauss_newton(objective, Xc, context, **gn_options)
    vertices = context.from_canonical(out["X"])
    timings = dict(out["timings"])
    timings["initialization"] = t_init
    timings["total"] = time.perf_counter() - t_start
    status = out["status"]
    result = ReconstructionResult(
        vertices=vertices, success=status > 0, status=status, message=STATUS_MESSAGES[status], method=method_name,
        iterations=out["iterations"], energy=out["energy"], energy_name=objective.name,
        initial_energy=out["initial_energy"], energy_history=out["history"], gradient_norm=out["gradient_norm"],
        step_sizes=out["steps"], regularization=out["shifts"], function_evaluations=out["evaluations"],
        factorizations=out["factorizations"], pcg_iterations=out["pcg_iterations"], timings=timings,
        fixed_face=context.fixed_face, backend=context.backend)
    return result
