"""The result object of every reconstruction method (like :class:`scipy.optimize.OptimizeResult`)."""

from dataclasses import asdict, dataclass, field

import numpy as np

__all__ = ["ReconstructionResult", "STATUS_MESSAGES"]

#: Meaning of :attr:`ReconstructionResult.status`.
STATUS_MESSAGES = {
    -2: "the linear system could not be solved (not positive definite even after regularization)",
    -1: "the line search found no step that decreases the energy",
    0: "the iteration limit was reached",
    1: "the energy reached the floating-point noise level (target reproduced)",
    2: "the relative energy decrease fell below ftol",
    3: "the gradient norm fell below gtol",
    4: "the step size fell below xtol",
    5: "direct (non-iterative) reconstruction",
}


@dataclass
class ReconstructionResult:
    """Outcome of a reconstruction ``z* -> X``.

    Attributes
    ----------
    vertices : (V, 3) ndarray
        The reconstructed immersion, in the frame of the reference mesh (see
        :mod:`lacore.reconstruction.gauss_newton`, "Rigid motions").
    success : bool
        Whether the method finished normally (converged, or a direct method ran).
    status : int
        Reason code, see :data:`STATUS_MESSAGES`.
    message : str
        Why the method stopped, in words.
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
        acceleration of Gauss-Newton steps), ``initialization`` (frame
        based start, set-up) and ``total``.
    fixed_face : int
        The face fixing the rigid motion (and the root face of frame-based methods).
    backend : str
        Sparse Cholesky backend used (``""`` if no linear system was solved).
    """

    vertices: np.ndarray
    success: bool
    status: int
    message: str
    method: str
    iterations: int = 0
    energy: float = float("nan")
    energy_name: str = "quadratic"
    initial_energy: float = float("nan")
    energy_history: list = field(default_factory=list)
    gradient_norm: float = float("nan")
    step_sizes: list = field(default_factory=list)
    regularization: list = field(default_factory=list)
    function_evaluations: int = 0
    factorizations: int = 0
    pcg_iterations: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    fixed_face: int = -1
    backend: str = ""

    def __repr__(self):
        lines = [f"{type(self).__name__}("]
        for k, v in asdict(self).items():
            if isinstance(v, np.ndarray):
                v = f"<array {v.shape} {v.dtype}>"
            elif isinstance(v, list) and len(v) > 6:
                v = f"[{', '.join(f'{x:.6g}' for x in v[:3])}, ..., {v[-1]:.6g}] ({len(v)} entries)"
            elif isinstance(v, dict):
                v = "{" + ", ".join(f"{a!r}: {b:.4g}" for a, b in v.items()) + "}"
            lines.append(f"    {k}={v},")
        return "\n".join(lines) + "\n)"

    def summary(self):
        """A JSON-serializable dict of the scalar fields (no vertex array)."""
        def clean(x):
            if isinstance(x, float) and not np.isfinite(x):
                return None
            return x
        out = {k: v for k, v in asdict(self).items() if k != "vertices"}
        out["energy_history"] = [clean(float(x)) for x in self.energy_history]
        out["step_sizes"] = [float(x) for x in self.step_sizes]
        out["regularization"] = [float(x) for x in self.regularization]
        out["timings"] = {k: float(v) for k, v in self.timings.items()}
        for k in ("energy", "initial_energy", "gradient_norm"):
            out[k] = clean(float(out[k]))
        out["success"] = bool(self.success)
        out["status"] = int(self.status)
        out["iterations"] = int(self.iterations)
        out["fixed_face"] = int(self.fixed_face)
        out["function_evaluations"] = int(self.function_evaluations)
        out["factorizations"] = int(self.factorizations)
        out["pcg_iterations"] = [int(k) for k in self.pcg_iterations]
        return out
