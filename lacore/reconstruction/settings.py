"""Settings of a reconstruction: one frozen dataclass per concern, the one place of every default.

:class:`ReconstructionSettings`
    What defines the problem and the shared set-up (a
    :class:`~lacore.reconstruction.context.ReconstructionContext`): energy,
    weights, bending weight, fixed face, solver backend.
:class:`GaussNewtonOptions`
    How Gauss-Newton iterates and stops
    (:func:`~lacore.reconstruction.gauss_newton.run_gauss_newton`).
:class:`HybridOptions`
    The start and the smoothing budget of ``method="hybrid"``.
:class:`ProjectionPreset`
    A named method with its options for projecting many targets (in-betweens):
    :data:`FAST`, :data:`GAUSS_NEWTON`; :data:`DEFAULT_PROJECTION` is the one
    ``lacore interpolate``, :func:`lacore.shapes.interpolation.interpolate` (and
    ``keyframe_inbetweens``, ``project_targets``) use when no method is given, and
    the Blender add-on's default method Fast.

:func:`reconstruct`, :func:`~lacore.shapes.interpolation.interpolate`, the CLI and
the Blender add-on take these objects, or the same names as keyword arguments
(``reconstruct(z, topo, X, energy="shells", max_iterations=20,
smoothing_iterations=3)``); :func:`split_options` maps such keywords to the
three objects.  The keyword names of the hybrid options keep their historical
prefix: ``hybrid_start``, ``hybrid_kind`` (fields ``start``, ``kind``).
"""

from dataclasses import dataclass, fields, replace

import numpy as np

from ..errors import InputError, MeshError
from ..linalg.sparse_cholesky import ORDERINGS

__all__ = ["ReconstructionSettings", "GaussNewtonOptions", "HybridOptions", "ProjectionPreset", "split_options",
           "make_settings", "projection_preset", "FAST", "GAUSS_NEWTON", "PROJECTION_PRESETS", "DEFAULT_PROJECTION",
           "ENERGIES", "WEIGHTS", "SOLVERS", "HYBRID_STARTS", "FRAME_KINDS", "NEWTON_MODES"]

ENERGIES = ("quadratic", "shells")
WEIGHTS = ("frohlich_botsch", "heeren", "uniform")
SOLVERS = ("cholmod", "scipy")
HYBRID_STARTS = ("lsq", "tree", "given")
NEWTON_MODES = ("never", "auto", "always")
FRAME_KINDS = ("bfs", "mst", "spt")


def _fixed_face_key(fixed_face):
    """``None``, or the fixed face(s) as a tuple of ints (hashable)."""
    if fixed_face is None:
        return None
    a = np.atleast_1d(np.asarray(fixed_face))
    if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer):
        raise MeshError(f"fixed_face must be a face index (or one per component), got {fixed_face!r}")
    return tuple(int(v) for v in a)


@dataclass(frozen=True)
class ReconstructionSettings:
    """The target-independent definition of a reconstruction (thesis 3.4).

    Attributes
    ----------
    energy : {"quadratic", "shells"}
        ``W_q`` (3.19) or ``W_TS`` (3.25): minimized by Gauss-Newton, reported by all methods.
    weights : {"frohlich_botsch", "heeren", "uniform"}
        Weights of ``W_q``: (3.20), (3.21) or 1.
    bending_weight : float
        ``eta`` in (3.19)/(3.25).
    fixed_face : None or tuple of int
        Face fixing the rigid motion (one per connected component, components
        not given get a central, well-shaped face of the reference mesh); also
        the root face of the frame-based methods.  An int is stored as a 1-tuple.
    fix_triangle_shape : bool
        Gauss-Newton holds all nine coordinates of the fixed face instead of
        only the six rigid motions.
    solver : {None, "cholmod", "scipy"}
        Sparse Cholesky backend; ``None``: CHOLMOD if cvxopt is installed.
    ordering : {None, "metis", "geometric"}
        Fill-reducing ordering CHOLMOD tries besides AMD (keeping the one that
        fills less; :func:`lacore.linalg.sparse_cholesky.vertex_ordering`): METIS
        (needs pymetis) or the geometric nested dissection; ``None``: METIS if
        pymetis is installed.  Changes speed and round-off only.

    Raises
    ------
    InputError
        An unknown energy, weights, solver or ordering, a negative or non-finite bending weight.
    """

    energy: str = "quadratic"
    weights: str = "frohlich_botsch"
    bending_weight: float = 1e-3
    fixed_face: tuple | None = None
    fix_triangle_shape: bool = False
    solver: str | None = None
    ordering: str | None = None

    def __post_init__(self):
        if self.energy not in ENERGIES:
            raise InputError(f"unknown energy {self.energy!r}; use 'quadratic' or 'shells'")
        if self.weights not in WEIGHTS:
            raise InputError(f"unknown weights {self.weights!r}; use 'frohlich_botsch', 'heeren' or 'uniform'")
        try:
            eta = float(self.bending_weight)
        except (TypeError, ValueError):
            eta = np.nan
        if not (np.isfinite(eta) and eta >= 0):
            raise InputError(f"bending_weight must be a finite number >= 0, got {self.bending_weight!r}")
        if self.solver is not None and self.solver not in SOLVERS:
            raise InputError(f"unknown solver {self.solver!r}; use 'cholmod' or 'scipy'")
        if self.ordering is not None and self.ordering not in ORDERINGS:
            raise InputError(f"unknown ordering {self.ordering!r}; use one of {', '.join(ORDERINGS)}")
        object.__setattr__(self, "bending_weight", eta)
        object.__setattr__(self, "fixed_face", _fixed_face_key(self.fixed_face))
        object.__setattr__(self, "fix_triangle_shape", bool(self.fix_triangle_shape))


@dataclass(frozen=True)
class GaussNewtonOptions:
    """Iteration and stopping options of Gauss-Newton (see :mod:`lacore.reconstruction.gauss_newton`).

    Attributes
    ----------
    max_iterations : int
        Iteration cap (status 0).
    ftol, gtol, xtol : float
        Relative energy decrease, scale-free gradient and step tolerances.
    atol : float or None
        Absolute energy tolerance; ``None``: the objective's floating-point noise floor.
    reuse_factorization : bool
        Inexact steps by PCG with the factorization the context already holds
        (also from earlier calls), refactorizing when PCG stalls.
    pcg_rtol : float
        Relative residual of those PCG solves, in ``(0, 1)``.
    pcg_maxiter : int
        PCG iterations before refactorizing, ``>= 1``.
    reuse_near_convergence : bool
        PCG with this call's factorization in the final, fast-converging phase.
    geodesic_acceleration : bool
        Second-order correction of each exact Gauss-Newton step (``W_q`` only) and the fold safeguard.
    newton : {"auto", "never", "always"}
        When a step uses the full Hessian ``2 J^T W J + 2 sum_j w_j r_j d2 Z_j``
        (``W_q`` only, :mod:`lacore.geometry.hessians`) instead of the Gauss-Newton
        matrix: ``"auto"`` (default) once the line search has cut a step
        (``t < 1``: the Gauss-Newton model overshoots, the sign of large
        residuals, where Gauss-Newton converges slowly or stalls), ``"always"``
        from the first step, ``"never"``.  A Hessian that is not positive
        definite gives a Gauss-Newton step instead (and the next step is one too).
    start_check : bool
        :func:`~lacore.reconstruction.reconstruct` with ``"gn"`` (and ``"hybrid"``
        from a given or tree start): when the first damped step (partial or
        shifted) removes less than half of the energy (or none), compute the
        least-squares relaxation once and continue from it if its energy is below
        1e-3 of the energy reached
        (:mod:`lacore.reconstruction.gauss_newton`, "Start check").  Default on.
    c1 : float
        Armijo constant of the line search.
    max_backtracks : int
        Line-search trials before giving up.

    Raises
    ------
    InputError
        ``pcg_rtol`` outside ``(0, 1)``, ``pcg_maxiter`` or ``max_iterations`` not a
        positive (non-negative) integer.
    """

    max_iterations: int = 100
    ftol: float = 1e-9
    gtol: float = 1e-8
    xtol: float = 1e-12
    atol: float | None = None
    reuse_factorization: bool = False
    pcg_rtol: float = 0.1
    pcg_maxiter: int = 6
    reuse_near_convergence: bool = True
    geodesic_acceleration: bool = True
    start_check: bool = True
    c1: float = 1e-4
    max_backtracks: int = 40
    newton: str = "auto"

    def __post_init__(self):
        if self.newton not in NEWTON_MODES:
            raise InputError(f"unknown newton mode {self.newton!r}; use one of {', '.join(NEWTON_MODES)}")
        if not 0 < self.pcg_rtol < 1:
            raise InputError(f"pcg_rtol must lie in (0, 1), got {self.pcg_rtol!r}")
        if int(self.pcg_maxiter) != self.pcg_maxiter or self.pcg_maxiter < 1:
            raise InputError(f"pcg_maxiter must be a positive integer, got {self.pcg_maxiter!r}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 0:
            raise InputError(f"max_iterations must be a non-negative integer, got {self.max_iterations!r}")


@dataclass(frozen=True)
class HybridOptions:
    """Options of ``method="hybrid"``: a direct start smoothed by a few Gauss-Newton iterations (section 3.4.3).

    Attributes
    ----------
    start : {"lsq", "tree", "given"}
        The least-squares relaxation (default; no spanning tree is built), the
        frame-based walk along a tree of kind ``kind`` (on long meshes the walk
        accumulates the integrability error along the tree, which a few
        smoothing iterations do not remove: README "Reconstruction",
        ``tests/test_hybrid.py``), or the caller's ``initial_vertices`` (e.g. the
        prediction of :func:`lacore.shapes.interpolation.project_targets` from the
        frames before; the least-squares relaxation when none are given).
    kind : {"mst", "spt", "bfs"}
        Tree of the ``"tree"`` start.
    smoothing_iterations : int
        At most this many Gauss-Newton iterations (they stop earlier once converged).
    nearest_start_iterations : int or None
        The budget instead of ``smoothing_iterations`` for a frame of
        :func:`lacore.shapes.interpolation.project_targets` whose given start is the
        nearest known shape rather than an extrapolation through two of them
        (the first in-between after a key: its start is first-order off in the
        frame spacing, an extrapolation second-order); default ``smoothing_iterations``.
    extend_smoothing : bool
        The budget ends the iteration only if every step agreed with its
        quadratic model (full, unshifted, energy decrease within 5 % of the
        prediction: the linearization held over it); otherwise Gauss-Newton
        iterates on until its own stopping rules (``GaussNewtonOptions.ftol``,
        at most ``max_iterations``).  On a smooth motion the budgeted step agrees
        (one step per in-between); on a blend far from admissible (a plate rolled
        one way into the other way) the steps recover only 40 % of what the
        model predicts, and stopping after them left frames at 49x Gauss-Newton's
        energy.

    Raises
    ------
    InputError
        An unknown start or kind, a negative or non-integer iteration count.
    """

    start: str = "lsq"
    kind: str = "mst"
    smoothing_iterations: int = 10
    nearest_start_iterations: int | None = None
    extend_smoothing: bool = False

    def __post_init__(self):
        if self.start not in HYBRID_STARTS:
            raise InputError(f"unknown hybrid_start {self.start!r}; use one of {', '.join(HYBRID_STARTS)}")
        if self.kind not in FRAME_KINDS:
            raise InputError(f"unknown hybrid_kind {self.kind!r}; use one of {', '.join(FRAME_KINDS)}")
        for name in ("smoothing_iterations", "nearest_start_iterations"):
            n = getattr(self, name)
            if n is None and name == "nearest_start_iterations":
                continue
            if int(n) != n or n < 0:
                raise InputError(f"{name} must be a non-negative integer, got {n!r}")
            object.__setattr__(self, name, int(n))
        object.__setattr__(self, "extend_smoothing", bool(self.extend_smoothing))

    @property
    def uses_tree(self):
        """Whether the start walks a spanning tree (only ``start="tree"``)."""
        return self.start == "tree"


@dataclass(frozen=True)
class ProjectionPreset:
    """A named projection method with its options, for sequences of targets (thesis 4.2, eq. 4.10).

    Attributes
    ----------
    name : str
        What the CLI's ``--method`` and the library's ``method=`` call it.
    method : str
        The reconstruction method (:data:`lacore.reconstruction.METHODS`).
    options : GaussNewtonOptions
    hybrid : HybridOptions

    Examples
    --------
    >>> from lacore.reconstruction.settings import DEFAULT_PROJECTION
    >>> DEFAULT_PROJECTION.name, DEFAULT_PROJECTION.method, DEFAULT_PROJECTION.hybrid.start
    ('fast', 'hybrid', 'given')
    """

    name: str
    method: str
    options: GaussNewtonOptions = GaussNewtonOptions()
    hybrid: HybridOptions = HybridOptions()

    def keywords(self):
        """``{"method", "options", "hybrid"}`` for :func:`lacore.shapes.interpolation.project_targets` and friends."""
        return {"method": self.method, "options": self.options, "hybrid": self.hybrid}


#: Continuation along ``t`` and one Gauss-Newton step per in-between: every frame starts from the
#: extrapolation through the two computed frames or keys before it
#: (:func:`lacore.shapes.interpolation.predicted_start`, error second order in the frame spacing) and takes one
#: step; a frame that starts from a key itself (the first after a key) takes up to three, stopping once the
#: predicted decrease is below ``ftol = 1e-4`` of the energy; where a step does not agree with its quadratic
#: model, more (``extend_smoothing``).  On smooth motions at 50k vertices one factorization per in-between,
#: within 1.8e-6 (a body) and 1.3e-5 (a bent bar) of converged Gauss-Newton's energy in about half its time
#: (``benchmarks/bench_continuation.py``); on a bend blended into a twist up to 10x Gauss-Newton's energy (65x
#: without the extension) in 0.3x its time: use :data:`GAUSS_NEWTON` there.
FAST = ProjectionPreset("fast", "hybrid", GaussNewtonOptions(ftol=1e-4),
                        HybridOptions(start="given", smoothing_iterations=1, nearest_start_iterations=3,
                                      extend_smoothing=True))
#: Gauss-Newton run to convergence from the same continuation starts, with Newton steps where it converges slowly.
GAUSS_NEWTON = ProjectionPreset("gn", "gn")
#: Presets by name (``method=`` of the interpolation functions, ``lacore interpolate --method``).
PROJECTION_PRESETS = {"fast": FAST}
#: The projection used when none is chosen: ``lacore interpolate``, the interpolation functions of
#: :mod:`lacore.shapes.interpolation`, and the add-on's default method (Fast).
DEFAULT_PROJECTION = FAST


def projection_preset(method, options=None, hybrid=None):
    """``(method, options, hybrid)`` for a method name or preset name (None: :data:`DEFAULT_PROJECTION`).

    A preset's options and hybrid options are used where ``options`` / ``hybrid``
    are not given; a plain method name is returned as it is.
    """
    preset = DEFAULT_PROJECTION if method is None else PROJECTION_PRESETS.get(method)
    if preset is None:
        return method, options, hybrid
    return (preset.method, preset.options if options is None else options,
            preset.hybrid if hybrid is None else hybrid)


_SETTINGS_KEYS = frozenset(f.name for f in fields(ReconstructionSettings))
_GN_KEYS = frozenset(f.name for f in fields(GaussNewtonOptions))
#: keyword name -> field of HybridOptions
_HYBRID_KEYS = {"hybrid_start": "start", "hybrid_kind": "kind", "smoothing_iterations": "smoothing_iterations",
                "extend_smoothing": "extend_smoothing"}


def split_options(kwargs, settings=None, options=None, hybrid=None, *, caller="reconstruct"):
    """Map keyword arguments to the three settings objects.

    Parameters
    ----------
    kwargs : dict
        Keyword arguments: fields of :class:`ReconstructionSettings` and
        :class:`GaussNewtonOptions`, ``hybrid_start``, ``hybrid_kind``,
        ``smoothing_iterations``.  Keywords override the objects' fields.
    settings, options, hybrid : optional
        Objects to start from (default: the defaults).
    caller : str
        Named in the error for unknown keywords.

    Returns
    -------
    settings : ReconstructionSettings
    options : GaussNewtonOptions
    hybrid : HybridOptions
    given : frozenset of str
        Names of the :class:`ReconstructionSettings` fields set explicitly (keywords,
        or fields of ``settings`` differing from the defaults).

    Raises
    ------
    TypeError
        Unknown keywords.
    InputError
        Invalid values.
    """
    unknown = sorted(set(kwargs) - _SETTINGS_KEYS - _GN_KEYS - set(_HYBRID_KEYS))
    if unknown:
        raise TypeError(f"{caller}() got unknown options {unknown}; Gauss-Newton options are "
                        f"{sorted(_GN_KEYS)}, settings {sorted(_SETTINGS_KEYS)}, hybrid {sorted(_HYBRID_KEYS)}")
    base = settings if settings is not None else ReconstructionSettings()
    s_kw = {k: v for k, v in kwargs.items() if k in _SETTINGS_KEYS}
    settings = replace(base, **s_kw) if s_kw else base
    given = {k for k in _SETTINGS_KEYS if getattr(base, k) != getattr(ReconstructionSettings(), k)} | set(s_kw)
    g_kw = {k: v for k, v in kwargs.items() if k in _GN_KEYS}
    options = options if options is not None else GaussNewtonOptions()
    options = replace(options, **g_kw) if g_kw else options
    h_kw = {_HYBRID_KEYS[k]: v for k, v in kwargs.items() if k in _HYBRID_KEYS}
    hybrid = hybrid if hybrid is not None else HybridOptions()
    hybrid = replace(hybrid, **h_kw) if h_kw else hybrid
    return settings, options, hybrid, frozenset(given)


def make_settings(settings=None, caller="ReconstructionSettings", **kwargs):
    """``settings`` (default: the defaults) with the fields in ``kwargs`` replaced; TypeError for other names."""
    unknown = sorted(set(kwargs) - _SETTINGS_KEYS)
    if unknown:
        raise TypeError(f"{caller}() got unknown settings {unknown}; settings are {sorted(_SETTINGS_KEYS)}")
    base = settings if settings is not None else ReconstructionSettings()
    return replace(base, **kwargs) if kwargs else base
