"""Energy-based reconstruction by Gauss-Newton (thesis 3.4.1, eq. 3.26, Def. 3.15).

Given target lengths and angles ``z* = (l*, theta*)`` (shape ``(2E,)``, see
:mod:`lacore.geometry.lengths_angles`), find vertex positions ``X`` minimizing::

    W[z*, Z(X)]                                                     (3.26)

For the quadratic energy ``W_q`` (3.19) this is the nonlinear least-squares
problem ``sum_j w_j (Z_j(X) - z*_j)^2`` with the residual weights ``w`` of
:class:`lacore.energies.QuadraticEnergy` (``w_s`` on lengths, ``eta w_b`` on
angles, (3.20) or (3.21) from a reference mesh).  With ``J = dZ/dX``
(``(2E, 3V)``) every iteration solves::

    (2 J^T W J) d = -g,     g = 2 J^T W (Z(X) - z*),     W = diag(w)

For another energy in ``z`` (the thin shells energy ``W_TS`` (3.25)) the
Gauss-Newton matrix is ``J^T (d^2W/dz^2) J`` with the element blocks of
``d^2W/dz^2`` projected to be positive semi-definite
(:mod:`lacore.reconstruction.objectives`).

The pieces live in their own modules: the shared set-up and the rigid-motion
gauge in :mod:`~lacore.reconstruction.context`, the objectives in
:mod:`~lacore.reconstruction.objectives`, the matrix pattern and assembly in
:mod:`~lacore.reconstruction.assembly`, the line search in
:mod:`~lacore.reconstruction.line_search`, PCG in :mod:`~lacore.reconstruction.pcg`,
the options in :class:`~lacore.reconstruction.settings.GaussNewtonOptions`.
``benchmarks/bench_gauss_newton.py`` measures the rules below.

Iteration
---------
* Far from the solution every step is an exact Gauss-Newton step with a fresh
  numeric factorization (solving with an older factorization as a CG
  preconditioner needs many iterations there: the matrix changes a lot with a
  displacement of a fraction of an edge length).
* Near the solution (``reuse_near_convergence``, default on: the last step was
  a full step and the vertices moved by at most 5 % of the mean target edge
  length -- sum of the steps' max-norms -- since the last factorization, or
  the step's energy decrease matched the quadratic model's prediction within
  5 %, so the linearization held over it) the
  factorization made earlier in the same call preconditions CG on the current
  Gauss-Newton matrix (matrix-free products ``J^T W J v``), solved to a
  relative residual ``min(1e-2, W_k / W_{k-1})`` (an Eisenstat-Walker-type
  forcing term: superlinear convergence at zero residual, enough for the
  linear phase of a non-zero residual) but no tighter than reaching the noise
  floor needs; a step whose CG does not reach its tolerance in 8 iterations
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
  straight line overshoots.  With the acceleration on, no trial step (of
  either path) may fold an edge -- its dihedral angle more than ``pi / 2`` off
  the target -- that is not folded at the iteration's start (unless only such
  a step decreases the energy): on strongly extrapolated targets the parabola
  can otherwise lead into a folded local minimum.
* Newton steps (``newton``, default ``"auto"``, ``W_q`` only): Gauss-Newton
  drops the second-order term ``2 sum_j w_j r_j d2 Z_j`` of the Hessian, which
  is large when the target is far from admissible (a blend of a bend and a
  twist): its steps then overshoot (the line search cuts them), converge
  linearly and slowly, or stall.  After the
  first cut step, or after two full steps in a row whose energy decreases
  shrank by less than a factor of 10, the steps use the full Hessian (per-edge blocks of
  :mod:`lacore.geometry.hessians`, the same sparsity pattern and symbolic
  factorization); a Hessian that is not positive definite (its factorization
  fails, no shift is tried) gives a Gauss-Newton step instead, and the next
  step is one too.  The result's ``newton_steps`` counts them.
* Line search (:func:`~lacore.reconstruction.line_search.armijo_line_search`):
  Armijo backtracking (``c1 = 1e-4``) starting at the full step 1 (never
  larger), shrinking by safeguarded quadratic interpolation; when a step
  ``t < 1`` is accepted, a few more trials between it and the last rejected
  step look for a lower energy.
* Stopping (first rule that holds, see :data:`~lacore.reconstruction.result.STATUS_MESSAGES`):
  energy at the floating-point noise level of ``W`` around ``z*`` (status 1);
  relative energy decrease of a full step ``W_k - W_{k+1} <= ftol W_k``, predicted
  Gauss-Newton decrease ``-g.d / 2 <= ftol W_k``, or -- in the linear
  convergence phase of a non-zero residual, two full steps in a row with
  decrease ratio ``r = dW_k / dW_{k-1} < 1/2`` -- estimated remaining decrease
  ``10 dW_k r / (1 - r) <= ftol W_{k+1}`` (2), which saves the final
  factorization that would only confirm convergence; scale-free gradient
  ``|g|_inf * size <= gtol * W`` (3); step ``|t d|_inf <= xtol * size`` (4);
  ``size`` = bounding-box diagonal of the reference mesh (times the target's scale beyond the band of sizes
  the weights are for: :mod:`.context`, "Target scale").  The iteration cap
  gives status 0, a line search without decrease status -1, ten iterations
  with damped steps (partial, ``t < 1``, or solved with a diagonal shift) that
  together decreased the energy by less than 1 % status -3 (a stall: on
  a flat strip of triangles of aspect 1e4 the Gauss-Newton matrix needs a
  diagonal shift far above its bending block, and each step moves almost
  nothing).  Only a full step (``t = 1``) may stop by rule 2's decrease or
  rule 4: a line search that only finds tiny steps is stalling, not converged.
  Statuses 1-4 are "converged"; whether the result is a success is decided by
  :mod:`lacore.reconstruction.checks`.
* Budget (``budget``, the hybrid method's smoothing iterations): the loop stops
  with status 6 after that many iterations; with ``extend_budget``
  (:attr:`~lacore.reconstruction.settings.HybridOptions.extend_smoothing`, the
  preset Fast) only if every step agreed with its quadratic model (full,
  unshifted, energy decrease within 5 % of the prediction), else it iterates on
  under the rules above: one step per in-between of a smooth motion, Gauss-Newton
  where the continuation is not enough.
* Start check (``alternative_start``; :func:`gauss_newton_reconstruction` with
  ``start_check``, on by default in :func:`lacore.reconstruction.reconstruct`):
  when the first damped step (partial or shifted) removes less than half of
  the energy, or the line search finds no decrease, the start is far from the
  target in a way the linearization does not describe, and another start is
  computed once -- the least-squares relaxation of the frame-based method,
  which integrates the target's rotations directly -- and the iteration
  continues from it when its energy is below 1e-3 of the energy reached (the
  iteration budgets counted from there).  (A full step that removes little is
  close to a minimum of a non-admissible target: no check.)  Rolling a flat plate or
  strip is such a way: the bending is isometric, but a Gauss-Newton step is
  linear in the positions, so it stretches the edges to second order, the
  stiff membrane term cuts the step to a sliver (the plate4SD rolled up: 268
  iterations from the flat plate, 2 from the relaxation); on triangles of
  aspect 1e4 the Gauss-Newton matrix is moreover numerically singular
  (condition ~ aspect^4 with the weights (3.20): the bending of the short
  edges is ~1e-20 of the largest entry, below its round-off), so the diagonal
  shift of the factorization suppresses exactly the bending that is needed
  and nothing moves.  The relaxation of such a (nearly) admissible target is
  exact to round-off; the 1e-3 keeps the given start for non-admissible
  targets, whose relaxation may lie in a worse basin (an extrapolated finger:
  5.7 against 26.7 after the first step, but Gauss-Newton from the reference
  reaches 0.067 and from the relaxation stalls at 4.6).

Angle residuals are not wrapped: ``theta`` lies in ``(-pi, pi]`` and a target
angle near ``+-pi`` whose reconstruction crosses the branch cut is penalized by
``~2 pi``, as in the thesis.
"""

import time
from dataclasses import fields, replace

import numpy as np

from ..errors import InputError, LengthsAnglesError, MeshError
from ..geometry.lengths_angles import check_z, wrap_angle
from ..linalg.heap import retained_heap
from ..linalg.sparse_cholesky import NotPositiveDefiniteError
from ..geometry.topology import check_vertices
from .assembly import gauss_newton_pattern
from .checks import apply_checks
from .context import ReconstructionContext, get_context, triangle_frame
from .least_squares import least_squares_start
from .line_search import armijo_line_search
from .pcg import dot, preconditioned_cg
from .result import STATUS_MESSAGES, GaussNewtonResult, IterativeResult, ReconstructionResult
from .settings import SETTINGS_FIELDS, GaussNewtonOptions, split_options

__all__ = [
    "ReconstructionContext",
    "get_context",
    "gauss_newton_reconstruction",
    "run_gauss_newton",
    "gauss_newton_pattern",
    "preconditioned_cg",
    "triangle_frame",
    "GaussNewtonOptions",
    "GaussNewtonResult",
    "GN_OPTIONS",
    "SWITCH_NOTE",
]

#: The defaults of :class:`GaussNewtonOptions` as a dict (derived from the dataclass, for code that wants a dict).
GN_OPTIONS = {f.name: f.default for f in fields(GaussNewtonOptions)}

#: PCG has stalled (refactorize) when ``pcg_maxiter`` iterations reduced the relative residual less than this.
_PCG_STALL = 0.5

#: Near convergence (``reuse_near_convergence``): the last step was a full step and the vertices moved by at most
#: this fraction of the mean target edge length (sum of the steps' max-norms) since the held factorization ...
_NEAR_DRIFT = 0.05
#: ... then PCG with the held factor solves to the relative residual
#: ``min(_NEAR_RTOL_MAX, max(W_k / W_{k-1}, 0.1 sqrt(atol / W_k), _NEAR_RTOL_MIN))`` in at most
#: ``_NEAR_MAXITER`` iterations, else the step refactorizes.
_NEAR_RTOL_MAX = 1e-2
#: ... also after a larger full step whose energy decrease matched the quadratic model's prediction within this
#: (the linearization held over the step, so the factorization still fits the matrix at its end).
_MODEL_AGREEMENT = 0.05
_NEAR_RTOL_MIN = 1e-12
_NEAR_MAXITER = 8

#: Stall: ``_STALL_WINDOW`` iterations, all with damped steps (partial, ``t < 1``, or solved with a diagonal
#: shift), decreased the energy by less than ``_STALL_DECREASE`` of it (status -3).
_STALL_WINDOW = 10
_STALL_DECREASE = 0.01

#: Start check (``alternative_start``): a first damped step that leaves more than this fraction of the energy makes the
#: loop try the alternative start once ...
_START_CHECK_FRACTION = 0.5
#: ... and continue from it if its energy is below this fraction of the energy it is compared with.
_START_SWITCH_RATIO = 1e-3
#: The note of a run that continued from the least-squares relaxation (:func:`gauss_newton_reconstruction`).
SWITCH_NOTE = "continued from the least-squares relaxation"

#: ``newton="auto"``: Newton steps after a cut step or after two full steps in a row whose energy decreases have
#: a ratio (later / earlier) of at least this (linear convergence of Gauss-Newton at large residuals).
_NEWTON_RATE = 0.1
#: A decrease ratio below this is no linear rate: the previous step came from a start far off the target (a given
#: start 1e7 times the target's size fell by 1e16 in one step and the rule stopped 5 % short of the lengths).
_MIN_RATE = 1e-8

#: Geodesic acceleration (``geodesic_acceleration``): finite-difference step (fraction of the step ``d``), ...
_ACCEL_FD_STEP = 0.1
#: ... only for steps ``max|d|`` above this fraction of the mean target edge length (below, Gauss-Newton converges
#: fast and the finite difference loses digits) ...
_ACCEL_MIN_STEP = 1e-3
#: ... and only when ``2 |a| <= _ACCEL_MAX_RATIO |d|``.
_ACCEL_MAX_RATIO = 1.5


class _State:
    """Mutable bookkeeping of one :func:`run_gauss_newton` call."""

    def __init__(self, X):
        self.X = X
        self.history, self.steps, self.shifts, self.pcg_its = [], [], [], []
        self.factorizations = self.evaluations = self.iterations = 0
        self.timings = {"assembly": 0.0, "factorization": 0.0, "solve": 0.0, "line_search": 0.0,
                        "acceleration": 0.0}
        self.own_factor = False   # the held factorization was made in this call ...
        self.drift = np.inf       # ... at a point this far (sum of max-norm steps) from X
        self.prev_energy = np.inf
        self.prev_decrease = np.inf
        self.newton = False       # steps use the full Hessian (options.newton) ...
        self.newton_pause = 0     # ... except for this many steps after a Hessian that was not positive definite
        self.newton_steps = 0
        self.model_ratio = np.nan  # energy decrease of the last full step / the decrease its quadratic model predicted
        self.damped = []          # per step: partial (t < 1) or solved with a diagonal shift
        self.start = 0            # steps before this index (and their iterations) belong to an abandoned start
        self.budget_from = 0
        self.alternative = None   # energy of the alternative start once tried ...
        self.switched = False     # ... and whether the iteration continued from it
        self.checked_energy = np.nan  # the energy it was compared with, after this many iterations
        self.checked_iteration = -1
        self.agreed = True        # every step since the start agreed with its quadratic model (extend_budget)

    def restart(self, X, newton):
        """Continue from ``X`` as from a new start (counters and history kept)."""
        self.X = X
        self.own_factor, self.drift = False, np.inf
        self.prev_energy = self.prev_decrease = np.inf
        self.newton, self.newton_pause = newton, 0
        self.model_ratio = np.nan
        self.agreed = True
        self.start, self.budget_from = len(self.steps), self.iterations

    def add_time(self, phase, t0):
        t1 = time.perf_counter()
        self.timings[phase] += t1 - t0
        return t1


def _linearize(objective, state, fixed):
    t0 = time.perf_counter()
    energy, grad, matrix = objective.linearize(state.X)
    state.evaluations += 1
    grad[fixed] = 0.0
    state.add_time("assembly", t0)
    return energy, grad, matrix


def _inexact_direction(state, options, context, grad, matrix, energy, atol, max_drift, second_order=False):
    """A Gauss-Newton (Newton with ``second_order``) direction by PCG with the held factorization, or None."""
    solver, fixed = context.solver, context.fixed_dofs
    if options.reuse_factorization and solver.has_factor:
        rtol, maxiter, accept = options.pcg_rtol, options.pcg_maxiter, _PCG_STALL
    elif (options.reuse_near_convergence and state.own_factor and state.steps[-1] == 1.0
          and (state.drift <= max_drift or abs(state.model_ratio - 1.0) <= _MODEL_AGREEMENT)):
        # forcing term W_k / W_{k-1}: superlinear convergence; no more accuracy than the noise floor needs
        # (a residual rtol |g| leaves about rtol^2 W_k of the linearized energy)
        rtol = min(_NEAR_RTOL_MAX, max(_NEAR_RTOL_MIN, energy / state.prev_energy, 0.1 * np.sqrt(atol / energy)))
        maxiter, accept = _NEAR_MAXITER, rtol
    else:
        return None
    t0 = time.perf_counter()
    matvec = (lambda v: matrix.dot(v, second_order=True)) if second_order else matrix.dot
    d, n_cg, rel = preconditioned_cg(matvec, -grad, solver.solve, fixed, rtol, maxiter)
    state.add_time("solve", t0)
    if rel <= accept and dot(grad, d) < 0:
        state.pcg_its.append(n_cg)
        return d
    return None  # PCG stalled / not close enough to the factorized point: refactorize


def _exact_direction(state, context, grad, matrix, second_order=False):
    """A Gauss-Newton direction with a fresh factorization, or None if the matrix cannot be factorized.

    With ``second_order`` the Newton direction of the full Hessian, or None when
    it is not positive definite (no regularizing shift is tried).
    """
    solver, fixed = context.solver, context.fixed_dofs
    t0 = time.perf_counter()
    H = context.eliminate_fixed(matrix(second_order=True) if second_order else matrix())
    t0 = state.add_time("assembly", t0)
    try:
        solver.factorize(H, regularize=not second_order)
    except NotPositiveDefiniteError:
        state.add_time("factorization", t0)
        return None
    state.factorizations += 1
    state.own_factor, state.drift = True, 0.0
    state.shifts.append(solver.shift)
    state.pcg_its.append(0)
    t0 = state.add_time("factorization", t0)
    d = solver.solve(-grad)
    state.add_time("solve", t0)
    d[fixed] = 0.0
    return d


def _acceleration(state, objective, context, d, matrix):
    """The geodesic acceleration ``a`` of the step ``d`` with the held factorization, or None."""
    t0 = time.perf_counter()
    fixed = context.fixed_dofs
    b = objective.acceleration_gradient(state.X, d, matrix, _ACCEL_FD_STEP)
    state.evaluations += 1
    b[fixed] = 0.0
    accel = None
    if np.all(np.isfinite(b)):
        a = context.solver.solve(-b)
        a[fixed] = 0.0
        if 2.0 * np.sqrt(dot(a, a)) <= _ACCEL_MAX_RATIO * np.sqrt(dot(d, d)):
            accel = a.reshape(-1, 3)
    state.add_time("acceleration", t0)
    return accel


def _search(state, objective, d, accel, energy, slope, matrix, options, fold_guard):
    """Line search along the parabola (if any), else the line, else the line allowing folds."""
    t0 = time.perf_counter()
    theta = None
    if fold_guard:  # no step may fold an edge (angle more than pi/2 off target) that is not folded yet
        E = objective.topology.n_edges
        target = objective.z_target[E:]
        theta = (target, np.abs(wrap_angle(matrix.z[E:] - target)) <= 0.5 * np.pi)
    d = d.reshape(-1, 3)
    attempts = ([(accel, theta)] if accel is not None else []) + [(None, theta)]
    if theta is not None:
        attempts.append((None, None))  # only folding steps decrease the energy: allow them
    t, X_new, E_new = 0.0, state.X, energy
    for acc, th in attempts:
        t, X_new, E_new, n_eval = armijo_line_search(objective, state.X, d, energy, slope, options.c1,
                                                     options.max_backtracks, accel=acc, theta=th)
        state.evaluations += n_eval
        if t != 0.0:
            break
    state.add_time("line_search", t0)
    return t, X_new, E_new


def _try_alternative(state, objective, alternative_start, energy, newton):
    """The start check: continue from ``alternative_start()`` if its energy is far below ``energy``; True if so."""
    t0 = time.perf_counter()
    X = alternative_start()
    state.timings["alternative_start"] = time.perf_counter() - t0
    state.checked_energy, state.checked_iteration = float(energy), state.iterations
    if X is None:
        state.alternative = np.nan
        return False
    E_alt = objective.energy(X)
    state.evaluations += 1
    state.alternative = E_alt
    if not (np.isfinite(E_alt) and E_alt < _START_SWITCH_RATIO * energy):
        return False
    state.restart(np.array(X, dtype=float), newton)
    state.history.append(E_alt)
    state.switched = True
    return True


def run_gauss_newton(objective, Xc, context, options=None, alternative_start=None, budget=None, extend_budget=False,
                     **kwargs):
    """Gauss-Newton iterations in canonical coordinates (see the module docstring for the rules).

    Parameters
    ----------
    objective : object
        With ``energy(X)``, ``linearize(X) -> (energy, gradient (3V,), matrix)``
        (``matrix()`` returns the Gauss-Newton matrix values in the pattern's
        order; it is only called when a step is computed) and ``noise_floor()``
        (:mod:`lacore.reconstruction.objectives`).
    Xc : (V, 3) ndarray
        Start, in canonical coordinates of ``context`` (fixed coordinates 0).
    context : ReconstructionContext
    options : GaussNewtonOptions, optional
        Iteration and stopping options (default: the defaults).
    alternative_start : callable, optional
        ``() -> (V, 3)`` canonical coordinates (or None) of another start, tried
        once when the first damped step leaves more than half of the energy or
        no decrease is found (the start check of the module docstring); the iteration
        continues from it when its energy is far lower, with the iteration
        budgets counted from there.
    budget : int, optional
        Stop with status 6 after this many iterations (the smoothing budget of
        the hybrid method) ...
    extend_budget : bool
        ... but with ``extend_budget`` only if every step so far agreed with its
        quadratic model (full, unshifted, energy decrease within 5 % of the
        model's prediction: the linearization held over it); otherwise iterate
        on until the stopping rules of the module docstring stop the loop
        (``options.max_iterations`` the cap, status 0).
    **kwargs
        Fields of :class:`GaussNewtonOptions` (override ``options``).

    Returns
    -------
    GaussNewtonResult
        ``x`` (canonical coordinates), ``status`` (:data:`STATUS_MESSAGES`),
        ``success = status > 0``, energies, history (with the alternative
        start's energy when the iteration switched to it), counters and timings
        (``alternative_start``: seconds spent computing it, when it was tried).
    """
    options = options if options is not None else GaussNewtonOptions()
    if kwargs:
        options = replace(options, **kwargs)
    fixed = context.fixed_dofs
    size = getattr(objective, "size", context.size)
    # a target of another size than the reference (context, "Target scale"): the stopping rules measure steps and
    # gradients against the larger of the target's size and the iterate's (a given start can be far larger)
    follows_scale = getattr(objective, "target_scale", 1.0) != 1.0

    def current_size():
        if not follows_scale:
            return size
        X = state.X.reshape(-1, 3)
        return max(size, float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))))
    atol = objective.noise_floor() if options.atol is None else float(options.atol)
    state = _State(np.array(Xc, dtype=float))
    edge = float(np.mean(objective.z_target[: objective.topology.n_edges]))
    max_drift = _NEAR_DRIFT * edge
    accelerate = options.geodesic_acceleration and hasattr(objective, "acceleration_gradient")
    newton_possible = options.newton != "never" and getattr(objective, "second_order", False)
    newton_always = newton_possible and options.newton == "always"
    state.newton = newton_always
    while True:
        energy, grad, matrix = _linearize(objective, state, fixed)
        gnorm = float(np.max(np.abs(grad)))
        if not state.history:
            if not np.isfinite(energy):
                raise LengthsAnglesError("the energy is not finite at the starting point: the start or the target "
                                         "has triangles violating the triangle inequality, or target lengths so far "
                                         "from the start's that the energy overflows (an extrapolation too far?)")
            state.history.append(energy)
        if energy <= atol:
            status = 1
            break
        if gnorm * current_size() <= options.gtol * energy:
            status = 3
            break
        done = state.iterations - state.budget_from
        if budget is not None and done >= budget and done > 0 and (not extend_budget or state.agreed):
            status = 6                                  # (no smoothing step at all is no approximation of a minimum)
            break
        if done >= options.max_iterations:
            status = 0
            break
        # Gauss-Newton (or Newton) direction: PCG with the held factorization, or an exact step with a fresh one
        newton = state.newton and not state.newton_pause
        state.newton_pause = max(0, state.newton_pause - 1)
        d = _inexact_direction(state, options, context, grad, matrix, energy, atol, max_drift, newton)
        fresh = d is None
        if fresh and newton:
            d = _exact_direction(state, context, grad, matrix, second_order=True)
            if d is None:  # the Hessian is not positive definite here: a Gauss-Newton step, and the next one too
                newton, state.newton_pause = False, 1
        if fresh and d is None:
            d = _exact_direction(state, context, grad, matrix)
            if d is None:
                status = -2
                break
        state.newton_steps += int(newton)
        slope = dot(grad, d)
        if not slope < 0:
            status = -1
            break
        # a direction solved with a diagonal shift (a numerically singular matrix) understates the Gauss-Newton
        # decrease: it is a damped step, whose small predicted or actual decrease is no sign of convergence
        shifted = fresh and context.solver.shift > 0.0
        if not shifted and -0.5 * slope <= options.ftol * energy:  # predicted Gauss-Newton decrease negligible
            status = 2
            break
        # geodesic acceleration: second-order correction of the path with the same factorization
        accel = None
        if accelerate and fresh and not newton and float(np.max(np.abs(d))) > _ACCEL_MIN_STEP * edge:
            accel = _acceleration(state, objective, context, d, matrix)
        t, X_new, E_new = _search(state, objective, d, accel, energy, slope, matrix, options, accelerate)
        untried = alternative_start is not None and state.alternative is None
        # the start check: after the first damped step (partial or shifted; a full step that removes little is
        # close to a minimum of a non-admissible target, where the relaxation cannot be far better)
        check_start = untried and (t < 1.0 or shifted)
        if t == 0.0:
            if energy > 1e6 * atol and untried and _try_alternative(state, objective, alternative_start, energy,
                                                                    newton_always):
                continue
            status = 1 if energy <= 1e6 * atol else -1
            break
        state.iterations += 1
        state.steps.append(t)
        state.damped.append(t < 1.0 or shifted)
        if t < 1.0 and newton_possible:  # the Gauss-Newton model overshoots: large residuals, use the Hessian
            state.newton = True
        state.history.append(E_new)
        decrease = energy - E_new
        state.model_ratio = decrease / (-0.5 * slope) if t == 1.0 else np.nan
        state.agreed &= t == 1.0 and not shifted and abs(state.model_ratio - 1.0) <= _MODEL_AGREEMENT
        state.prev_energy = energy
        step_norm = float(np.max(np.abs(X_new - state.X)))
        state.drift += step_norm
        state.X = X_new
        if E_new <= atol:
            continue  # status 1 after evaluating the final gradient
        if (check_start and E_new > _START_CHECK_FRACTION * state.history[-2]
                and _try_alternative(state, objective, alternative_start, E_new, newton_always)):
            continue  # the damped step did not get far: continue from the alternative start
        # linear convergence with full steps: the remaining decrease is about dec r / (1 - r), r = dec / dec_prev
        # (estimated with a safety factor 10)
        damped = state.damped[state.start:]
        full = not damped[-1]
        rate = decrease / state.prev_decrease if len(damped) > 1 and full and not damped[-2] else 1.0
        state.prev_decrease = decrease
        if newton_possible and _NEWTON_RATE <= rate < 1.0:  # slow linear convergence of Gauss-Newton
            state.newton = True
        # a damped step (partial, t < 1, or shifted) that decreases little is a stall, not convergence: only
        # full, unshifted steps may stop by the decrease or the step size; a stall is detected by the next
        # iteration's predicted decrease (scale-free stationarity) or by _STALL_WINDOW iterations without progress
        if full and (decrease <= options.ftol * energy or (
                _MIN_RATE <= rate < 0.5 and 10.0 * decrease * rate / (1.0 - rate) <= options.ftol * E_new)):
            status = 2
        elif full and step_norm <= options.xtol * current_size():
            status = 4
        elif (len(damped) >= _STALL_WINDOW and all(damped[-_STALL_WINDOW:])
              and state.history[-1 - _STALL_WINDOW] - E_new < _STALL_DECREASE * E_new):
            status = -3
        else:
            continue
        # converged after a step: report energy and gradient at the final point (the matrix is not needed)
        energy, grad, _ = _linearize(objective, state, fixed)
        gnorm = float(np.max(np.abs(grad)))
        break
    return GaussNewtonResult(
        x=state.X, success=status > 0, status=status, message=STATUS_MESSAGES[status],
        iterations=state.iterations, timings=state.timings, energy=float(energy), initial_energy=state.history[0],
        energy_history=state.history, gradient_norm=gnorm, step_sizes=state.steps, regularization=state.shifts,
        function_evaluations=state.evaluations, factorizations=state.factorizations,
        pcg_iterations=state.pcg_its, newton_steps=state.newton_steps,
        alternative_energy=np.nan if state.alternative is None else float(state.alternative),
        checked_energy=state.checked_energy, checked_iteration=state.checked_iteration, switched=state.switched)


def gauss_newton_reconstruction(z_target, topology, reference_vertices=None, *, initial_vertices=None,
                                context=None, settings=None, options=None, method_name="gn", extra_timings=None,
                                success_status=None, started=None, start_check=False, budget=None,
                                extend_budget=False, **kwargs):
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
        Shared set-up; default :func:`get_context` with ``settings``.
    settings : ReconstructionSettings, optional
        Settings of the context when none is given.
    options : GaussNewtonOptions, optional
    method_name : str
        Reported as :attr:`ReconstructionResult.method`.
    extra_timings : dict, optional
        Timings of work done before (e.g. the start of the hybrid method), added to the result's.
    success_status : (int, str), optional
        Status and message of a stop by ``budget`` (without ``budget``: replacing
        status 0, the iteration limit, when that limit is the intended budget).
    budget, extend_budget : optional
        The hybrid method's smoothing budget (:func:`run_gauss_newton`).
    started : float, optional
        :func:`time.perf_counter` at the start of the whole call (``timings["total"]``).
    start_check : bool
        When the first damped step leaves more than half of the energy (or no
        decrease is found), compute the least-squares relaxation once and
        continue from it if its energy is 1000 times lower (module docstring,
        "Start check"); the result's ``timings["least_squares"]`` and a note say so.
    **kwargs
        Fields of ``options`` and (without ``context``) of ``settings`` as keywords
        (:func:`~lacore.reconstruction.settings.split_options`).

    Returns
    -------
    ReconstructionResult
        ``success`` decided by :func:`lacore.reconstruction.checks.apply_checks`
        (a converged minimizer without folds, or the target reproduced).
    """
    t_start = time.perf_counter()
    started = t_start if started is None else started
    given = sorted(SETTINGS_FIELDS & set(kwargs)) or (["settings"] if settings is not None else [])
    settings, options, _ = split_options(kwargs, settings, options, caller="gauss_newton_reconstruction",
                                         accept=("settings", "options"))
    if context is None:
        if reference_vertices is None:
            raise InputError("give reference_vertices or a context")
        context = get_context(topology, reference_vertices, settings)
    elif given:
        raise InputError(f"settings {given} are fixed by the given context")
    z_target = check_z(z_target, topology, name="target z")
    X0 = context.reference_vertices if initial_vertices is None else check_vertices(
        initial_vertices, topology.n_vertices, name="initial vertices")
    objective = context.objective(z_target)
    scale = getattr(objective, "target_scale", 1.0)
    if initial_vertices is None and scale != 1.0:  # start at the target's size (context, "Target scale")
        centroid = X0.mean(axis=0)
        X0 = centroid + scale * (X0 - centroid)
    Xc = context.to_canonical(X0)
    t_init = time.perf_counter() - t_start

    def relaxation():
        try:
            X = least_squares_start(z_target, topology, context)
        except (InputError, MeshError, np.linalg.LinAlgError):
            return None
        return context.to_canonical(X) if np.all(np.isfinite(X)) else None

    with retained_heap():  # the iterations' factorizations on one heap (lacore.linalg.heap)
        out = run_gauss_newton(objective, Xc, context, options,
                               alternative_start=relaxation if start_check else None, budget=budget,
                               extend_budget=extend_budget)
    vertices = context.from_canonical(out.x)
    timings = dict(out.timings)
    timings["initialization"] = t_init
    notes = []
    if "alternative_start" in timings:
        timings["least_squares"] = timings.pop("alternative_start")
        notes.append(f"start check: a damped Gauss-Newton step got less than halfway (energy {out.initial_energy:.6g} "
                     f"at the start, {out.checked_energy:.6g} after {out.checked_iteration} iterations); the "
                     f"least-squares relaxation has energy {out.alternative_energy:.6g}: "
                     + (SWITCH_NOTE if out.switched else "kept the given start"))
    timings.update(extra_timings or {})
    status, message = out.status, out.message
    if success_status is not None and status == (6 if budget is not None else 0):
        status, message = success_status
    timings["total"] = time.perf_counter() - started
    counters = {f.name: getattr(out, f.name) for f in fields(IterativeResult)}
    counters.update(success=status > 0, status=status, message=message, timings=timings)
    result = ReconstructionResult(vertices=vertices, method=method_name, energy_name=objective.name,
                                  fixed_face=context.fixed_face, backend=context.backend, notes=notes, **counters)
    return apply_checks(result, z_target, topology, minimizer=True)
