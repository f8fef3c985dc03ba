"""Results of the reconstruction solvers (subclasses of :class:`lacore.result.SolverResult`)."""

from dataclasses import dataclass, field

import numpy as np

from ..result import SolverResult

__all__ = ["ReconstructionResult", "GaussNewtonResult", "IterativeResult", "STATUS_MESSAGES"]

#: Meaning of :attr:`ReconstructionResult.status` (and :attr:`GaussNewtonResult.status`).
STATUS_MESSAGES = {
    -3: "the iteration stalled (10 damped steps -- partial or regularized -- decreased the energy by less than 1 %)",
    -2: "the linear system could not be solved (not positive definite even after regularization)",
    -1: "the line search found no step that decreases the energy",
    0: "the iteration limit was reached",
    1: "the energy reached the floating-point noise level (target reproduced)",
    2: "the relative energy decrease fell below ftol",
    3: "the gradient norm fell below gtol",
    4: "the step size fell below xtol",
    5: "direct (non-iterative) reconstruction",
    6: "the smoothing iterations of the hybrid method are done",
}


@dataclass(kw_only=True, repr=False)
class IterativeResult(SolverResult):
    """A :class:`~lacore.result.SolverResult` with the counters of an energy-minimizing iteration.

    Attributes
    ----------
    energy, initial_energy : float
        Energy at the final and at the starting point (``nan`` if not computed).
    energy_history : list of float
        Energy after every iteration, starting with the initial energy.
    gradient_norm : float
        Max-norm of the gradient in the free coordinates at the final point (``nan`` if not computed).
    step_sizes : list of float
        Accepted line-search step sizes (1.0 = full step).
    regularization : list of float
        Diagonal shift added to the Gauss-Newton matrix per numeric factorization (0.0 = exact).
    function_evaluations : int
        Evaluations of ``Z`` (energies), including line-search trials.
    factorizations : int
        Numeric Cholesky factorizations of the Gauss-Newton matrix.
    pcg_iterations : list of int
        Per step, the conjugate-gradient iterations of a step solved with an earlier factorization as
        preconditioner (0: a fresh factorization and a direct solve).
    newton_steps : int
        Steps that used the full Hessian instead of the Gauss-Newton matrix
        (:attr:`~lacore.reconstruction.settings.GaussNewtonOptions.newton`).
    """

    energy: float = float("nan")
    initial_energy: float = float("nan")
    energy_history: list = field(default_factory=list)
    gradient_norm: float = float("nan")
    step_sizes: list = field(default_factory=list)
    regularization: list = field(default_factory=list)
    function_evaluations: int = 0
    factorizations: int = 0
    pcg_iterations: list = field(default_factory=list)
    newton_steps: int = 0


@dataclass(kw_only=True, repr=False)
class GaussNewtonResult(IterativeResult):
    """Outcome of :func:`lacore.reconstruction.gauss_newton.run_gauss_newton` (canonical coordinates).

    Attributes
    ----------
    x : (V, 3) ndarray
        The final iterate, in the canonical coordinates of the context.
    success, status, message, iterations, timings
        See :class:`lacore.result.SolverResult`; ``status`` codes in
        :data:`STATUS_MESSAGES` (``success`` is ``status > 0``).  Timings:
        ``assembly, factorization, solve, line_search, acceleration``.
    energy, energy_history, step_sizes, factorizations, ...
        The counters of :class:`IterativeResult`.
    alternative_energy, checked_energy : float
        When the start check tried the alternative start
        (``run_gauss_newton(alternative_start=...)``): its energy and the energy
        it was compared with; else ``nan``.
    checked_iteration : int
        Iterations done when the start check tried it (``-1``: not tried).
    switched : bool
        The iteration continued from the alternative start.
    """

    x: np.ndarray
    alternative_energy: float = float("nan")
    checked_energy: float = float("nan")
    checked_iteration: int = -1
    switched: bool = False

    _summary_exclude = ("x",)


@dataclass(kw_only=True, repr=False)
class ReconstructionResult(IterativeResult):
    """Outcome of a reconstruction ``z* -> X`` (:func:`lacore.reconstruction.reconstruct`).

    Attributes
    ----------
    vertices : (V, 3) ndarray
        The reconstructed immersion, in the frame of the reference mesh (see
        :mod:`lacore.reconstruction.context`, "Rigid motions").
    success : bool
        Whether the result is what was asked for, decided the same way for every
        method by :mod:`lacore.reconstruction.checks`: finite, no folded edge, and
        the target reproduced within the stated tolerances or (``"gn"``,
        ``"hybrid"``) a converged minimizer.
    status : int
        Why the solver stopped, see :data:`STATUS_MESSAGES` (independent of the checks).
    message : str
        Why the method stopped, in words, followed by ``"; check failed: ..."`` when a check failed.
    failure : str
        ``""`` on success, else the failed check (``"non_finite"``, ``"folded"``,
        ``"not_converged"``, ``"not_reproduced"``), see
        :class:`~lacore.reconstruction.checks.ReconstructionCheck`.
    checks : dict
        :meth:`ReconstructionCheck.summary() <lacore.reconstruction.checks.ReconstructionCheck.summary>`:
        the errors, fold counts and tolerances the decision used.
    notes : list of str
        Remarks on the input or the run (faces of the target violating the
        triangle inequality, a restart from the least-squares start, ...).
    method : str
        ``"gn"``, ``"bfs"``, ``"mst"``, ``"spt"``, ``"lsq"`` or ``"hybrid-<kind>"``.
    iterations : int
        Gauss-Newton iterations (0 for direct methods).
    energy : float
        ``W[z*, Z(vertices)]`` under the chosen energy (3.19 or 3.25).
    energy_name : str
        ``"quadratic"`` or ``"shells"``.
    initial_energy : float
        Energy of the starting point of Gauss-Newton (``nan`` for direct methods).
    energy_history : list of float
        Energy after every Gauss-Newton iteration, starting with the initial energy.
    gradient_norm : float
        Max-norm of the energy gradient in the free coordinates at the output
        (``nan`` if not computed).
    step_sizes : list of float
        Accepted line-search step sizes (1.0 = full Gauss-Newton step).
    regularization : list of float
        Diagonal shift added to the Gauss-Newton matrix per numeric
        factorization (0.0 = exact).
    function_evaluations : int
        Number of evaluations of ``Z`` (energies), including line-search trials.
    factorizations : int
        Numeric Cholesky factorizations of the Gauss-Newton matrix.
    pcg_iterations : list of int
        Per Gauss-Newton step: conjugate-gradient iterations of a step solved
        with an earlier factorization as preconditioner (0: a fresh
        factorization and a direct solve).
    timings : dict
        Seconds spent in ``assembly`` (Jacobian, gradient, Gauss-Newton matrix),
        ``factorization``, ``solve``, ``line_search``, ``acceleration`` (geodesic
        acceleration of Gauss-Newton steps), ``initialization`` (set-up),
        ``frame_based`` / ``least_squares`` (a direct method, the hybrid
        start, or the relaxation the start check computed) and ``total``.
    fixed_face : int
        The face fixing the rigid motion (and the root face of frame-based methods).
    backend : str
        Sparse Cholesky backend used (``""`` if no linear system was solved).
    """

    vertices: np.ndarray
    method: str
    energy_name: str = "quadratic"
    fixed_face: int = -1
    backend: str = ""
    failure: str = ""
    checks: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    _summary_exclude = ("vertices",)
