"""Armature-free marker fitting: mesh poses from motion-capture markers and a shape model (thesis 4.3.1).

For every frame ``t`` of a take, :func:`fit_markers` solves (4.23) with the
data term generalized to surface points with normal offsets
(:mod:`lacore.markers.binding`) and an optional temporal term::

    minimize  J_t[X, alpha] = sum_{m visible} |p_m(X) - x_m^t|^2                    data (4.20)
                            + gamma W_q[Z[X], zbar + U^T alpha]                      prior (4.21)-(4.23)
                            + tau |alpha - alpha^{t-1}|^2                            temporal
                            (+ kappa |X - X^{t-1}|^2 only in frames with < 3 usable markers)

over vertex positions ``X`` (V, 3) and model coefficients ``alpha`` (J,)
(``z = zbar + sum_j alpha_j u_j``, the ``u_j`` ``g``-orthonormal: ``U M U^T = Id``,
``M = diag(w)`` the residual weights of ``W_q`` from the model's reference mesh).

Solver (the thesis' remark on implementation)
---------------------------------------------
1. **Start.** Frame 0: the model's reference mesh (not the immersion of the
   mean ``zbar``, which can contain slivers: on the 2.5k-vertex coarse human a
   face of the mean pose has 1e-9 of its rest area) moved by a Kabsch fit
   (:func:`lacore.geometry.rigid.rigid_fit`) of its marker points onto the visible
   markers; later frames: the previous frame's pose, moved by the Kabsch fit of
   its marker points onto the new markers (the walk), and its coefficients.
2. **Alternating iterations** (``alternating_iterations``, default 3 in frame 0, 1 in warm-started frames): the
   ``z``-step minimizes over ``alpha`` exactly, the ``g``-orthogonal projection
   (4.22) of ``Z[X]`` onto ``zbar + span U`` (with the temporal term:
   ``(gamma U M U^T + tau Id) alpha = gamma U M (Z[X] - zbar) + tau alpha^{t-1}``);
   the ``X``-step is one Gauss-Newton step in ``X`` for fixed ``z`` (the prior
   then is the energy of the reconstruction, :mod:`lacore.reconstruction.gauss_newton`).
3. **Joint Gauss-Newton** in ``(X, alpha)`` (at most ``joint_iterations``).
   The Gauss-Newton matrix is bordered::

       [ A    B ] [dX]     [g_X]      A = 2 (gamma J^T M J + sum_m G_m^T G_m) (+ 2 kappa Id)   sparse (3V, 3V)
       [ B^T  C ] [da] = - [g_a]      B = -2 gamma J^T M U^T                              dense (3V, J)
                                      C = 2 (gamma U M U^T + tau Id)                      (J, J)

   with ``J = dZ/dX`` and ``G_m`` the ``(3, 9)`` Jacobian of marker ``m``'s
   surface point (normal derivative included).  ``A`` is factorized once per
   iteration by :class:`lacore.linalg.sparse_cholesky.SparseCholesky` (symbolic
   analysis once per topology, reused by every iteration and frame); the Schur
   complement ``S = C - B^T A^-1 B`` (J x J) gives ``da = S^-1 (B^T A^-1 g_X - g_a)``
   and ``dX = -A^-1 (g_X + B da)``: ``J + 1`` solves with one factor, never a
   dense ``3V x 3V`` matrix.

``W_q`` is invariant under rigid motions, so ``A`` is singular without data;
``>= 3`` visible, non-collinear markers make it definite.  Frames with fewer
(or collinear ones) add the anchor term ``kappa |X - X^{t-1}|^2`` (``kappa =
anchor_weight``, relative to ``gamma`` times the mean diagonal of the prior's
Gauss-Newton matrix) and report status 2; the pose then comes from the prior,
the temporal term and the markers still seen.

Degenerate triangles (the thesis' exploding gradients)
------------------------------------------------------
The gradient of a dihedral angle grows like ``1 / height`` of its triangles; the
thesis saw fits get stuck when a Gauss-Newton step squashed a triangle.  The
default safeguard is a **compression penalty** in the energy (in the spirit of
the thin-shells membrane term, which penalizes compression, but one-sided and
zero on every face with at least ``compression_ratio`` = 25 % of its area in
the model's reference mesh)::

    + compression_weight lbar^2 sum_f max(0, compression_ratio - a_f(X) / abar_f)^2

with its exact Gauss-Newton block per face (``lbar`` the mean edge length, so
the term has the data term's unit).  It leaves normal poses untouched and
keeps the closed-form ``z``-step (4.22) that using ``W_TS`` as the prior would
lose.  Two alternatives were tried on the human and rejected: a line search
rejecting steps that flip a face (blocks the large first-frame steps: 212 mm
instead of 14 mm error in frame 0) and one rejecting steps that shrink a face
below 5 % of its area (faces pressed against the bound block every later step:
the fit stalls and trails the markers by up to 200 mm).
``tests/test_marker_fitting.py`` shows a fit that collapses triangles to 7e-10
of their area without the penalty and keeps them at 25 % with it, at the same
energy to 0.1 %.

Multiresolution
---------------
Fit the model of a coarse mesh (for the human, the 2.5k-vertex coarse body)
and give ``prolongation`` (a :class:`lacore.multiresolution.Prolongation` or
a callable ``(coarse_vertices, coefficients) -> fine vertices``, e.g.
:class:`lacore.markers.prolongation.NearestKeysProlongation`): every fitted
frame is prolonged to the full mesh (``fine_vertices``, timed in
``timings["prolongation"]``, thesis 2.3: ~20 ms).  Without it
``fine_vertices`` is None and ``timings["prolongation"]`` is 0.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, format_indices
from ..geometry.lengths_angles import face_normals, lengths_and_angles
from .prolongation import as_fit_prolongation
from .binding import MarkerBinding, MarkerBindingError, surface_point_jacobians, surface_points
from ..progress import report
from ..reconstruction.assembly import dof_ordering, gauss_newton_pattern
from ..reconstruction.objectives import QuadraticObjective
from ..result import SolverResult
from ..geometry.rigid import apply_rigid, rigid_fit
from ..linalg.sparse_cholesky import NotPositiveDefiniteError, SparseCholesky

__all__ = ["fit_markers", "MarkerFitResult", "MarkerDataError", "FRAME_STATUS", "check_markers",
           "MAX_MARKER_COORDINATE"]

#: Meaning of :attr:`MarkerFitResult.frame_status`.
FRAME_STATUS = {
    -2: "the linear system could not be solved",
    -1: "the line search found no decrease before the first joint step",
    0: "converged",
    1: "iteration limit reached",
    2: "fewer than 3 usable (visible, non-collinear) markers: pose from the prior and the temporal term",
}

_I9, _J9 = np.triu_indices(9)


class MarkerDataError(InputError):
    """Marker positions of a wrong shape or type, infinite, too large, or with nothing to fit."""


#: Largest marker coordinate magnitude: squared distances of larger ones overflow double precision.
MAX_MARKER_COORDINATE = 1e150


def check_markers(markers, binding):
    """Marker positions as float ``(T, M, 3)`` (a single frame ``(M, 3)`` becomes ``T = 1``).

    NaN marks an occluded marker (a row with any NaN counts as occluded).
    :class:`MarkerDataError` (one line: the problem and what to do) for values
    that are not real numbers, no frames, no markers, infinite values,
    coordinates beyond :data:`MAX_MARKER_COORDINATE` in magnitude, or no
    visible marker in any frame (nothing to fit); :class:`MarkerBindingError`
    for a marker count other than the binding's.
    """
    a = np.asarray(markers)
    if a.dtype.kind not in "fiu":
        raise MarkerDataError(f"marker positions must be real numbers, got {a.dtype} values")
    x = a.astype(float)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[2] != 3:
        raise MarkerDataError(f"marker positions must have shape (T, M, 3), got {np.shape(markers)}")
    if x.shape[0] == 0:
        raise MarkerDataError("the marker data has no frames (positions of shape (0, M, 3)): nothing to fit")
    if x.shape[1] == 0:
        raise MarkerDataError("the marker data has no markers (positions of shape (T, 0, 3)): nothing to fit")
    if x.shape[1] != binding.n_markers:
        raise MarkerBindingError(f"the marker data has {x.shape[1]} markers, the binding {binding.n_markers}")
    bad = np.isinf(x).any(2)
    if bad.any():
        t, m = np.nonzero(bad)
        where = format_indices(zip(t, m, strict=True))
        raise MarkerDataError(f"marker positions are infinite at (frame, marker) {where}")
    finite = np.isfinite(x)
    if not finite.any():
        raise MarkerDataError("no marker is visible in any frame (all positions are NaN): nothing to fit")
    peak = float(np.max(np.abs(x[finite])))
    if peak > MAX_MARKER_COORDINATE:
        raise MarkerDataError(f"marker positions reach {peak:.3g}, beyond {MAX_MARKER_COORDINATE:g} (their squares "
                              "overflow): give them in the length unit of the model")
    x = x.copy()
    x[np.isnan(x).any(2)] = np.nan
    return x


@dataclass(kw_only=True, repr=False)
class MarkerFitResult(SolverResult):
    """Outcome of :func:`fit_markers` (a :class:`lacore.result.SolverResult`).

    Attributes
    ----------
    vertices : (T, V, 3) ndarray
        Fitted poses, in the markers' frame.
    coefficients : (T, J) ndarray
        ``alpha`` per frame (``z = zbar + alpha @ modes``).
    z : (T, 2E) ndarray
        ``Z[vertices]`` per frame (admissible lengths and angles of the fitted pose).
    marker_residuals : (T, M) ndarray
        ``|p_m(X) - x_m|`` per frame and marker (NaN where occluded).
    frame_rms : (T,) ndarray
        RMS of the visible markers' residuals (NaN without visible markers).
    marker_rms : float
        RMS over all visible samples.
    frame_energy : (T,) ndarray
        ``J_t`` at the solution; ``frame_data`` and ``frame_prior`` its data and ``gamma W_q`` parts.
    frame_status : (T,) int ndarray
        See :data:`FRAME_STATUS`; ``frame_messages`` the same in words.
    frame_iterations : (T, 2) int ndarray
        Alternating and joint iterations per frame.
    frame_seconds : (T,) ndarray
    visible : (T,) int ndarray
        Visible markers per frame.
    success : bool
        No frame failed (all statuses >= 0).
    status : int
        Worst frame status by severity (-2, -1, 1, 2, 0 in that order).
    message : str
    iterations : int
        Total Gauss-Newton iterations (alternating X-steps and joint steps).
    timings : dict
        Seconds in ``initialization`` (set-up, starts), ``alternating``,
        ``joint``, ``prolongation`` (0 without ``prolongation``), ``total``.
    fine_vertices : (T, V_fine, 3) ndarray or None
        The fitted poses prolonged to the fine mesh (``prolongation`` given).
    prior_weight, temporal_weight : float
    regularized_frames : list of int
        Frames that needed the anchor term or a diagonal shift of the factorization.
    """

    vertices: np.ndarray
    coefficients: np.ndarray
    z: np.ndarray
    marker_residuals: np.ndarray
    frame_rms: np.ndarray
    marker_rms: float
    frame_energy: np.ndarray
    frame_data: np.ndarray
    frame_prior: np.ndarray
    frame_status: np.ndarray
    frame_messages: list
    frame_iterations: np.ndarray
    frame_seconds: np.ndarray
    visible: np.ndarray
    prior_weight: float = 1.0
    temporal_weight: float = 0.0
    regularized_frames: list = field(default_factory=list)
    fine_vertices: np.ndarray = None

    @property
    def n_frames(self):
        return int(self.vertices.shape[0])

    def summary(self):
        """A JSON-serializable dict of the scalar fields and per-frame statistics (no vertex arrays)."""
        def f(x):
            x = float(x)
            return x if np.isfinite(x) else None
        T = self.n_frames
        total = float(self.timings.get("total", 0.0))
        return {
            "success": bool(self.success), "status": int(self.status), "message": self.message,
            "frames": T, "iterations": int(self.iterations),
            "timings": {k: float(v) for k, v in self.timings.items()},
            "seconds": total, "seconds_per_frame": total / T if T else None,
            "marker_rms": f(self.marker_rms),
            "max_frame_rms": f(np.nanmax(self.frame_rms)) if np.isfinite(self.frame_rms).any() else None,
            "frame_status_counts": {str(int(s)): int(np.sum(self.frame_status == s))
                                    for s in np.unique(self.frame_status)},
            "mean_iterations": [float(v) for v in self.frame_iterations.mean(0)] if T else [0.0, 0.0],
            "prior_weight": float(self.prior_weight), "temporal_weight": float(self.temporal_weight),
            "regularized_frames": [int(t) for t in self.regularized_frames],
        }


_SEVERITY = {-2: 5, -1: 4, 2: 3, 1: 2, 0: 0}


class _Problem:
    """Constant pieces of one fit: model arrays, pattern, factorization, binding slots."""

    def __init__(self, model, binding, gamma, tau, compression_ratio, compression_weight, anchor_weight, solver,
                 n_modes=None):
        topo = model.topology
        self.topology = topo
        self.faces = topo.faces
        self.V = topo.n_vertices
        self.E = topo.n_edges
        self.binding = binding
        self.gamma = float(gamma)
        self.tau = float(tau)
        self.w = np.asarray(model.metric_weights, float)
        self.zbar = np.asarray(model.mean_z, float)
        self.U = np.asarray(model.modes, float)[:n_modes]             # (J, 2E)
        self.J = self.U.shape[0]
        self.WU = (self.w * self.U).T.copy()                          # (2E, J) = M U^T
        self.UMU = self.U @ self.WU                                   # (J, J), = Id for a g-orthonormal model
        self.pattern = pat = gauss_newton_pattern(topo)
        cache = topo.cache.get((__name__, "cholesky"), dict)
        key = solver or "default"
        chol = cache.get(key)
        if chol is None:
            ordered = (solver or "cholmod") == "cholmod"  # CHOLMOD takes an ordering; SuperLU finds its own
            ordering = dof_ordering(topo, pat, model.reference_vertices)[0] if ordered else None
            try:
                chol = SparseCholesky(pat["matrix"], backend=solver, ordering=ordering)
            except ValueError:
                chol = SparseCholesky(pat["matrix"], backend=solver)
            cache[key] = chol
        self.chol = chol
        self.diag = np.flatnonzero(pat["indices"] == pat["cols"])
        # data-term slots: upper pairs of every marker's 9x9 block in the pattern's value order
        _, dofs = surface_point_jacobians(model.reference_vertices, self.faces, binding)
        self.dofs = dofs
        self.data_slots = self._slots(dofs)
        self.buffer = np.empty(len(pat["slots"]))
        # compression penalty: per face, the 9 coordinates of its corners
        self.face_dofs = (3 * self.faces[:, :, None] + np.arange(3)).reshape(-1, 9)
        self.face_slots = None
        self.rest_area = 0.5 * np.linalg.norm(face_normals(model.reference_vertices, self.faces, unit=False), axis=1)
        self.rho = 0.0 if compression_ratio is None else float(compression_ratio)
        edge = np.linalg.norm(np.diff(model.reference_vertices[model.edges], axis=1)[:, 0], axis=1)
        self.w_c = float(compression_weight) * float(np.mean(edge)) ** 2 if self.rho > 0 else 0.0
        self.anchor_weight = float(anchor_weight)
        self.prior_scale = None

    def _slots(self, dofs):
        """Positions of the upper pairs of ``(k, 9)`` coordinate blocks in the pattern's value order."""
        pat = self.pattern
        n = pat["n"]
        r = np.maximum(dofs[:, _I9], dofs[:, _J9])
        c = np.minimum(dofs[:, _I9], dofs[:, _J9])
        keys = pat["cols"] * n + pat["indices"]
        k = c * n + r
        pos = np.searchsorted(keys, k)
        if np.any(keys[np.minimum(pos, len(keys) - 1)] != k):  # pragma: no cover - faces are in the pattern
            raise RuntimeError("face blocks outside the Gauss-Newton pattern")
        return pos

    # ---------------------------------------------------------------- pieces
    def compression(self, X):
        """Compression residuals ``rho - a_f / abar_f`` (positive part), their faces and value ``w_c sum r^2``."""
        if not self.w_c:
            return np.zeros(0), np.zeros(0, np.int64), 0.0
        a = 0.5 * np.linalg.norm(face_normals(X, self.faces, unit=False), axis=1)
        r = self.rho - a / self.rest_area
        act = np.flatnonzero(r > 0)
        r = r[act]
        return r, act, self.w_c * float(r @ r)

    def compression_jacobian(self, X, act):
        """``d (a_f / abar_f) / dX`` of the faces ``act``: ``(k, 9)`` on their corner coordinates.

        ``da/dX_0 = n x (e_2 - e_1) / 2``, ``da/dX_1 = -n x e_2 / 2``, ``da/dX_2 = n x e_1 / 2``.
        """
        P = X[self.faces[act]]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        c = np.cross(e1, e2)
        n = c / np.linalg.norm(c, axis=1)[:, None]
        g = 0.5 * np.concatenate([np.cross(n, e2 - e1), -np.cross(n, e2), np.cross(n, e1)], axis=1)
        return g / self.rest_area[act, None]

    def data(self, X, x, vis):
        """Data residuals ``(m, 3)`` of the visible markers and their value."""
        P = surface_points(X, self.faces, self._sub(vis))
        r = P - x[vis]
        return r, float(np.einsum("ij,ij->", r, r))

    def _sub(self, vis):
        b = self.binding
        return MarkerBinding(b.faces[vis], b.barycentric[vis], b.offsets[vis])

    def energy(self, X, a, fr):
        """``(total, data, prior)`` at ``(X, a)`` for frame ``fr``; the total adds compression, temporal, anchor."""
        z = lengths_and_angles(X, self.topology, check=False)
        _, d = self.data(X, fr.x, fr.vis) if fr.n_vis else (None, 0.0)
        rz = z - self.zbar - a @ self.U if self.J else z - self.zbar
        p = self.gamma * float(np.einsum("i,i,i->", self.w, rz, rz))
        tot = d + p + self.compression(X)[2]
        if self.J and self.tau:
            da = a - fr.a_prev
            tot += self.tau * float(da @ da)
        if fr.kappa:
            dx = X - fr.X_anchor
            tot += fr.kappa * float(np.einsum("ij,ij->", dx, dx))
        return tot, d, p

    def linearize(self, X, a, fr):
        """Gradient in X ``(3V,)``, GN matrix values of ``A`` (pattern order), prior objective and its GN matrix."""
        target = self.zbar + a @ self.U if self.J else self.zbar
        obj = QuadraticObjective(target, self.gamma * self.w, self.topology, self.pattern, buffer=self.buffer)
        _, grad, gn = obj.linearize(X)
        vals = gn()
        if self.prior_scale is None:
            self.prior_scale = float(np.mean(vals[self.diag])) / self.gamma if self.gamma else 1.0
        if fr.n_vis:
            r, _ = self.data(X, fr.x, fr.vis)
            G, _ = surface_point_jacobians(X, self.faces, self._sub(fr.vis))
            dofs = self.dofs[fr.vis]
            grad = grad + np.bincount(dofs.ravel(), weights=(2.0 * np.einsum("mij,mi->mj", G, r)).ravel(),
                                      minlength=3 * self.V)
            H = 2.0 * np.einsum("mki,mkj->mij", G, G)[:, _I9, _J9]
            vals = vals + np.bincount(self.data_slots[fr.vis].ravel(), weights=H.ravel(), minlength=len(vals))
        rc, act, _ = self.compression(X)
        if act.size:
            g = self.compression_jacobian(X, act)                       # d ratio / dX, residual rho - ratio
            dofs = self.face_dofs[act]
            grad = grad + np.bincount(dofs.ravel(), weights=(-2.0 * self.w_c * rc[:, None] * g).ravel(),
                                      minlength=3 * self.V)
            H = 2.0 * self.w_c * (g[:, _I9] * g[:, _J9])
            if self.face_slots is None:
                self.face_slots = self._slots(self.face_dofs)
            vals = vals + np.bincount(self.face_slots[act].ravel(), weights=H.ravel(), minlength=len(vals))
        if fr.kappa:
            grad = grad + 2.0 * fr.kappa * (X - fr.X_anchor).ravel()
            vals = vals.copy()
            vals[self.diag] += 2.0 * fr.kappa
        return grad, vals, gn

    def z_step(self, X, fr):
        """Exact minimizer over ``alpha`` for fixed ``X`` (4.22) (+ temporal term)."""
        if not self.J:
            return np.zeros(0)
        z = lengths_and_angles(X, self.topology, check=False)
        lhs = self.gamma * self.UMU + self.tau * np.eye(self.J)
        rhs = self.gamma * (self.WU.T @ (z - self.zbar)) + self.tau * fr.a_prev
        return np.linalg.solve(lhs, rhs)


@dataclass
class _Frame:
    x: np.ndarray
    vis: np.ndarray
    n_vis: int
    a_prev: np.ndarray
    X_anchor: np.ndarray
    kappa: float


def _usable(x_vis):
    """At least 3 visible markers that are not collinear (second singular value > 1e-3 of the first)."""
    if len(x_vis) < 3:
        return False
    s = np.linalg.svd(x_vis - x_vis.mean(0), compute_uv=False)
    return bool(s[0] > 0 and s[1] > 1e-3 * s[0])


def _line_search(prob, X, a, dX, da, E0, slope, fr, max_backtracks=30):
    """Armijo backtracking; returns ``(t, X, a, E, parts)``."""
    t = 1.0
    for _ in range(max_backtracks):
        Xt = X + t * dX.reshape(-1, 3)
        at = a + t * da if da is not None else a
        Et, d, p = prob.energy(Xt, at, fr)
        if np.isfinite(Et) and Et <= E0 + 1e-4 * t * slope:
            return t, Xt, at, Et, (d, p)
        t *= 0.5
    return 0.0, X, a, E0, None


def _factorize(prob, grad, vals):
    """Factorize the Gauss-Newton matrix; NotPositiveDefiniteError (frame status -2) also when it or the gradient
    is not finite (e.g. markers so far from the mesh's scale that its lengths lose all precision)."""
    if not (np.all(np.isfinite(vals)) and np.all(np.isfinite(grad))):
        raise NotPositiveDefiniteError("the Gauss-Newton matrix or gradient is not finite")
    prob.chol.factorize(vals)


def _joint_step(prob, X, a, fr):
    """Gauss-Newton step of the joint problem in ``(X, alpha)`` by the bordered system (Schur complement).

    Returns ``(dX (3V,), da (J,) or None, slope)`` with ``slope = g . d`` the
    directional derivative of the energy along the step.
    """
    grad, vals, gn = prob.linearize(X, a, fr)
    _factorize(prob, grad, vals)
    if not prob.J:
        dX = -prob.chol.solve(grad)
        return dX, None, float(grad @ dX)
    J = prob.J
    rz = gn.z - (prob.zbar + a @ prob.U)
    ga = -2.0 * prob.gamma * (prob.WU.T @ rz) + 2.0 * prob.tau * (a - fr.a_prev)
    B = -2.0 * prob.gamma * np.asarray(gn.J.T @ prob.WU)                   # (3V, J), dense border
    C = 2.0 * (prob.gamma * prob.UMU + prob.tau * np.eye(J))
    Y = prob.chol.solve(np.column_stack([grad, B]))                         # A^-1 [g_X, B]: J + 1 solves
    S = C - B.T @ Y[:, 1:]                                                  # Schur complement (J, J)
    da = np.linalg.solve(S, B.T @ Y[:, 0] - ga)
    dX = -(Y[:, 0] + Y[:, 1:] @ da)
    return dX, da, float(grad @ dX + ga @ da)


def fit_markers(model, markers, binding, *, prior_weight=1.0, temporal_weight=0.0, alternating_iterations=3,
                warm_alternating_iterations=1,
                joint_iterations=5, n_modes=None, ftol=1e-3, xtol=1e-9, compression_ratio=0.25,
                compression_weight=100.0, anchor_weight=1e-3,
                initial_vertices=None, initial_coefficients=None, solver=None, prolongation=None, progress=None):
    """Fit a shape model to marker positions over a take (thesis (4.20)-(4.23)).

    Parameters
    ----------
    model : lacore.models.shape_model.ShapeModel
        The prior: mean ``zbar``, ``g``-orthonormal modes ``U`` (``J`` may be 0:
        the mean-only prior), weights of ``W_q``, reference mesh (start, areas ``abar_f``).
    markers : (T, M, 3) or (M, 3) array_like
        Marker positions per frame; NaN where a marker is occluded.
    binding : MarkerBinding
        Surface point and normal offset of every marker on the model's mesh.
    prior_weight : float
        ``gamma`` > 0 of (4.23).  The data term is in squared length units of the
        markers, ``W_q`` is scale-free (lengths weighted by ``1 / lbar^2``).
    temporal_weight : float
        ``tau >= 0``: penalty ``tau |alpha^t - alpha^{t-1}|^2`` on the change of
        the model coefficients (``g``-norm of the change of ``z`` in the model's
        subspace) from the previous frame; rigid-motion free, so the walk is not
        damped.  0 (default): warm start only, as in the thesis.
    alternating_iterations, warm_alternating_iterations : int
        ``z``-step + ``X``-step rounds before the joint iteration in the first
        frame and in warm-started (later) frames.
        ``z``-step + ``X``-step rounds before the joint iteration.
    joint_iterations : int
        Maximal joint Gauss-Newton iterations per frame.
    n_modes : int, optional
        Use only the first ``n_modes`` modes of the model (0: the mean-only prior
        ``W_q[Z[X], zbar]``); default all.
    ftol, xtol : float
        Stop the joint iteration when the relative energy decrease is below
        ``ftol`` or the largest vertex move below ``xtol`` times the mesh size.
    compression_ratio, compression_weight : float
        Safeguard against degenerate triangles (see module notes): the penalty
        ``compression_weight lbar^2 sum_f max(0, compression_ratio - a_f / abar_f)^2``
        on faces compressed below ``compression_ratio`` of their area ``abar_f``
        in the reference mesh (``lbar`` its mean edge length, so the term has the
        data term's unit); ``compression_ratio=None`` disables it.
    anchor_weight : float
        ``kappa`` of the anchor term in frames with < 3 usable markers, relative
        to ``gamma`` times the mean diagonal entry of the prior's Gauss-Newton matrix.
    initial_vertices : (V, 3) array_like, optional
        Start of frame 0 instead of the Kabsch-placed reference mesh.
    initial_coefficients : (J,) array_like, optional
        ``alpha`` of the previous frame for frame 0 (temporal term), default 0.
    solver : {"cholmod", "scipy"}, optional
    prolongation : lacore.multiresolution.Prolongation or callable, optional
        Prolong every fitted pose to the fine mesh the model's mesh was
        coarsened from (module notes): a ``Prolongation`` (first key shape)
        or ``f(coarse_vertices (V, 3), coefficients (J,)) -> (V_fine, 3)``.
    progress : callable, optional
        ``progress(done, total, message)`` per frame (:mod:`lacore.progress`).

    Returns
    -------
    MarkerFitResult

    Raises
    ------
    MarkerBindingError
        Binding out of range, marker bound to nothing, marker count mismatch.
    MarkerDataError
        Marker array of a wrong shape or with infinite values.
    InputError
        Bad weights.
    """
    t_start = time.perf_counter()
    if not isinstance(binding, MarkerBinding):
        raise MarkerBindingError(f"binding must be a MarkerBinding, got {type(binding).__name__}")
    binding.check(model.faces)
    x_all = check_markers(markers, binding)
    for name, v, lo in (("prior_weight", prior_weight, 0.0), ("temporal_weight", temporal_weight, 0.0)):
        if not (np.isfinite(v) and v >= lo):
            raise InputError(f"{name} must be a finite number >= 0, got {v!r}")
    if not prior_weight > 0:
        raise InputError(f"prior_weight must be > 0, got {prior_weight!r}")
    T, M = x_all.shape[:2]
    if n_modes is not None and not (int(n_modes) == n_modes and 0 <= n_modes <= model.n_modes):
        raise InputError(f"n_modes must be an integer from 0 to {model.n_modes}, got {n_modes!r}")
    prolong = None if prolongation is None else as_fit_prolongation(prolongation)
    prob = _Problem(model, binding, prior_weight, temporal_weight, compression_ratio, compression_weight,
                    anchor_weight, solver, None if n_modes is None else int(n_modes))
    V, J = prob.V, prob.J
    size = float(np.linalg.norm(np.ptp(model.reference_vertices, axis=0)))

    out_X = np.empty((T, V, 3))
    out_a = np.zeros((T, J))
    out_z = np.empty((T, 2 * prob.E))
    status = np.zeros(T, np.int64)
    iters = np.zeros((T, 2), np.int64)
    energy = np.zeros((T, 3))
    seconds = np.zeros(T)
    timings = {"initialization": time.perf_counter() - t_start, "alternating": 0.0, "joint": 0.0,
               "prolongation": 0.0}
    regularized = []
    out_fine = None

    X = np.asarray(model.reference_vertices, float).copy() if initial_vertices is None else \
        np.asarray(initial_vertices, float).copy()
    if X.shape != (V, 3):
        raise InputError(f"initial_vertices must have shape ({V}, 3), got {X.shape}")
    a = np.zeros(J) if initial_coefficients is None else np.asarray(initial_coefficients, float).reshape(J)
    have_previous = initial_vertices is not None
    for t in range(T):
        report(progress, t, T, f"frame {t + 1}/{T}")
        t0 = time.perf_counter()
        x = x_all[t]
        vis = np.flatnonzero(np.isfinite(x[:, 0]))
        usable = _usable(x[vis])
        # start: Kabsch fit of the current pose's marker points onto the visible markers
        if usable:
            R, tr = rigid_fit(surface_points(X, prob.faces, binding)[vis], x[vis])
            X = apply_rigid(X, R, tr)
        elif t == 0 and not have_previous and len(vis):
            X = X + (x[vis].mean(0) - surface_points(X, prob.faces, binding)[vis].mean(0))
        if prob.prior_scale is None:
            prob.linearize(X, a, _Frame(x, vis[:0], 0, a, X, 0.0))
        kappa = 0.0 if usable else prob.anchor_weight * prob.gamma * prob.prior_scale
        fr = _Frame(x, vis, len(vis), a.copy(), X.copy(), kappa)
        if kappa:
            regularized.append(t)
        st = 0
        # ------------------------------------------------ alternating
        ta = time.perf_counter()
        n_alt = 0
        E_cur = prob.energy(X, a, fr)[0]
        n_rounds = alternating_iterations if (t == 0 and not have_previous) else warm_alternating_iterations
        for _ in range(int(n_rounds)):
            a = prob.z_step(X, fr)
            E_cur = prob.energy(X, a, fr)[0]
            grad, vals, _ = prob.linearize(X, a, fr)
            try:
                _factorize(prob, grad, vals)
            except NotPositiveDefiniteError:
                st = -2
                break
            dX = -prob.chol.solve(grad)
            step, X, a, E_new, _ = _line_search(prob, X, a, dX, None, E_cur, float(grad @ dX), fr)
            n_alt += 1
            if step == 0.0:
                break
            E_cur = E_new
        timings["alternating"] += time.perf_counter() - ta
        # ------------------------------------------------ joint
        tj = time.perf_counter()
        n_joint = 0
        converged = False
        if st == 0:
            if J:
                a_opt = prob.z_step(X, fr)  # exact in alpha for the current X: a better joint start
                E_opt = prob.energy(X, a_opt, fr)[0]
                if E_opt <= E_cur:
                    a, E_cur = a_opt, E_opt
            for _ in range(int(joint_iterations)):
                try:
                    dX, da, slope = _joint_step(prob, X, a, fr)
                except NotPositiveDefiniteError:
                    st = -2
                    break
                if prob.chol.shift and t not in regularized:
                    regularized.append(t)
                n_joint += 1
                if slope >= 0:
                    converged = True
                    break
                step, X, a, E_new, _ = _line_search(prob, X, a, dX, da, E_cur, slope, fr)
                if step == 0.0:
                    converged = True  # no decrease left at this precision
                    break
                dec = E_cur - E_new
                E_cur = E_new
                if dec <= ftol * max(E_cur, 1e-300) or step * np.abs(dX).max() <= xtol * size:
                    converged = True
                    break
        timings["joint"] += time.perf_counter() - tj
        if st == 0:
            st = 2 if not usable else (0 if converged else 1)
        status[t] = st
        iters[t] = (n_alt, n_joint)
        out_X[t] = X
        out_a[t] = a
        out_z[t] = lengths_and_angles(X, prob.topology, check=False)
        energy[t] = prob.energy(X, a, fr)
        if prolong is not None:
            tp = time.perf_counter()
            fine = np.asarray(prolong(X, a), float)
            if out_fine is None:
                if fine.ndim != 2 or fine.shape[1] != 3:
                    raise InputError(f"prolongation must return (V_fine, 3) vertices, got {fine.shape}")
                out_fine = np.empty((T,) + fine.shape)
            out_fine[t] = fine
            timings["prolongation"] += time.perf_counter() - tp
        seconds[t] = time.perf_counter() - t0
    report(progress, T, T, "done")

    P = surface_points(out_X, prob.faces, binding)
    res = np.linalg.norm(P - x_all, axis=2)                  # NaN where occluded
    n_vis = np.isfinite(res).sum(1)
    frame_rms = np.full(T, np.nan)
    frame_rms[n_vis > 0] = np.sqrt(np.nansum(res ** 2, axis=1)[n_vis > 0] / n_vis[n_vis > 0])
    finite = np.isfinite(res)
    marker_rms = float(np.sqrt(np.mean(res[finite] ** 2))) if finite.any() else float("nan")
    worst = max(status.tolist(), key=lambda s: _SEVERITY[s]) if T else 0
    counts = {s: int(np.sum(status == s)) for s in np.unique(status)}
    message = "; ".join(f"{n} frame{'s' if n != 1 else ''}: {FRAME_STATUS[int(s)]}" for s, n in counts.items())
    timings["total"] = time.perf_counter() - t_start
    return MarkerFitResult(
        vertices=out_X, coefficients=out_a, z=out_z, marker_residuals=res, frame_rms=frame_rms,
        marker_rms=marker_rms, frame_energy=energy[:, 0], frame_data=energy[:, 1], frame_prior=energy[:, 2],
        frame_status=status, frame_messages=[FRAME_STATUS[int(s)] for s in status], frame_iterations=iters,
        frame_seconds=seconds, visible=np.isfinite(x_all[:, :, 0]).sum(1), success=bool(np.all(status >= 0)),
        status=int(worst), message=message, iterations=int(iters.sum()), timings=timings,
        prior_weight=float(prior_weight), temporal_weight=float(temporal_weight), regularized_frames=regularized,
        fine_vertices=out_fine)
