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
:class:`ReconstructionSetup`
    The three together, as the projections of many targets pass them on.
:class:`ProjectionPreset`
    A named method with its options for projecting many targets (in-betweens):
    :data:`FAST`, :data:`GAUSS_NEWTON`; :data:`DEFAULT_PROJECTION` is the one
    ``lacore interpolate``, :func:`lacore.shapes.interpolation.interpolate` (and
    ``keyframe_inbetweens``, ``project_targets``) use when no method is given, and
    the Blender add-on's default method Fast.

The defaults are the fields' defaults; the energy's weight scheme and ``eta``
are :data:`lacore.energies.DEFAULT_WEIGHTS` and
:data:`lacore.energies.DEFAULT_BENDING_WEIGHT` (an energy built alone has the
same).  Every consumer -- :func:`~lacore.reconstruction.reconstruct`, the
projections of :mod:`lacore.shapes`, geodesics, shape models, multiresolution,
the CLI and the Blender add-on -- takes these objects; shape models use their
own defaults (:mod:`lacore.models.settings`), stated as objects of these classes.

Settings objects are the canonical form.  As a convenience,
:func:`~lacore.reconstruction.reconstruct`,
:func:`~lacore.shapes.interpolation.interpolate`,
:func:`~lacore.shapes.interpolation.keyframe_inbetweens`,
:func:`~lacore.shapes.interpolation.project_targets` and the context
constructors also take the fields as keyword arguments
(``reconstruct(z, topo, X, energy="shells", max_iterations=20)``);
:func:`split_options` is the one function that maps them onto the objects.  The
keyword names of the hybrid options carry a prefix: ``hybrid_start``,
``hybrid_kind`` (fields ``start``, ``kind``).

"Not given" is ``None`` for a whole object and absence for a keyword: a
settings object passed explicitly gives every one of its fields, also those at
their default (a reconstruction with a ``context`` checks them against it).

Examples
--------
>>> from lacore.reconstruction.settings import ReconstructionSettings, split_options
>>> s = ReconstructionSettings(energy="shells")
>>> s.energy, s.weights, s.bending_weight
('shells', 'frohlich_botsch', 0.001)
>>> setup = split_options({"bending_weight": 0.01, "max_iterations": 5}, s)
>>> setup.settings.bending_weight, setup.options.max_iterations, setup.hybrid.start
(0.01, 5, 'lsq')
"""

from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np

from ..energies import DEFAULT_BENDING_WEIGHT, DEFAULT_WEIGHTS, WEIGHT_SCHEMES
from ..errors import InputError, MeshError
from ..linalg.sparse_cholesky import ORDERINGS

__all__ = ["ReconstructionSettings", "GaussNewtonOptions", "HybridOptions", "ReconstructionSetup", "ProjectionPreset",
           "split_options", "projection_preset", "SETTINGS_FIELDS", "FAST", "GAUSS_NEWTON", "PROJECTION_PRESETS",
           "DEFAULT_PROJECTION", "ENERGIES", "WEIGHTS", "SOLVERS", "HYBRID_STARTS", "FRAME_KINDS", "NEWTON_MODES"]

ENERGIES = ("quadratic", "shells")
WEIGHTS = WEIGHT_SCHEMES
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
        ``W_q`` (3.19) (default) or ``W_TS`` (3.25): minimized by Gauss-Newton, reported by all methods.
    weights : {"frohlich_botsch", "heeren", "uniform"}
        Weights of ``W_q``: (3.20) (default), (3.21) or 1.
    bending_weight : float
        ``eta`` in (3.19)/(3.25), default ``1e-3``.
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

    Examples
    --------
    >>> from lacore import ReconstructionSettings
    >>> s = ReconstructionSettings(energy="shells", fixed_face=3)
    >>> s.energy, s.weights, s.bending_weight, s.fixed_face
    ('shells', 'frohlich_botsch', 0.001, (3,))
    >>> s == ReconstructionSettings(energy="shells", fixed_face=(3,))    # frozen, compared by value
    True
    """

    energy: str = "quadratic"
    weights: str = DEFAULT_WEIGHTS
    bending_weight: float = DEFAULT_BENDING_WEIGHT
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

    Examples
    --------
    >>> from dataclasses import replace
    >>> from lacore import GaussNewtonOptions
    >>> options = GaussNewtonOptions(max_iterations=20)
    >>> options.max_iterations, options.newton, options.geodesic_acceleration
    (20, 'auto', True)
    >>> replace(options, newton="never").newton
    'never'
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
        smoothing iterations do not remove: ``tests/test_hybrid.py``), or the
        caller's ``initial_vertices`` (e.g. the
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

    Examples
    --------
    >>> from lacore import HybridOptions
    >>> h = HybridOptions(start="tree", kind="spt", smoothing_iterations=3)
    >>> h.uses_tree, h.smoothing_iterations
    (True, 3)
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
#: (:func:`lacore.shapes.projection.predicted_start`, error second order in the frame spacing) and takes one
#: step; a frame that starts from a key itself (the first after a key) takes up to three, stopping once the
#: predicted decrease is below ``ftol = 1e-4`` of the energy; where a step does not agree with its quadratic
#: model, more (``extend_smoothing``).  Exact on smooth motions at one factorization per in-between; strongly
#: mixed blends (a bend blended into a twist) stay above Gauss-Newton's energy: use :data:`GAUSS_NEWTON` there
#: (``benchmarks/bench_continuation.py`` measures both).
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


class ReconstructionSetup(NamedTuple):
    """The three settings objects of a reconstruction, as one value (unpacks as ``settings, options, hybrid``)."""

    settings: ReconstructionSettings = ReconstructionSettings()
    options: GaussNewtonOptions = GaussNewtonOptions()
    hybrid: HybridOptions = HybridOptions()


#: Names of the :class:`ReconstructionSettings` fields.
SETTINGS_FIELDS = frozenset(f.name for f in fields(ReconstructionSettings))
_GN_KEYS = frozenset(f.name for f in fields(GaussNewtonOptions))
#: keyword name -> field of HybridOptions
_HYBRID_KEYS = {"hybrid_start": "start", "hybrid_kind": "kind", "smoothing_iterations": "smoothing_iterations",
                "extend_smoothing": "extend_smoothing"}
_PART_NAMES = {"settings": "settings are", "options": "Gauss-Newton options", "hybrid": "hybrid options"}


def split_options(keywords, settings=None, options=None, hybrid=None, *, caller="reconstruct",
                  accept=("settings", "options", "hybrid")):
    """The settings objects with the fields named in ``keywords`` replaced: the one reader of flattened keywords.

    Parameters
    ----------
    keywords : dict
        Fields of :class:`ReconstructionSettings` and :class:`GaussNewtonOptions`,
        ``hybrid_start``, ``hybrid_kind``, ``smoothing_iterations``.  They
        override the objects' fields.
    settings, options, hybrid : optional
        Objects to start from (``None``: the defaults).
    caller : str
        Named in the error for unknown keywords.
    accept : tuple of {"settings", "options", "hybrid"}
        Whose fields are accepted as keywords (the context constructors take settings only).

    Returns
    -------
    ReconstructionSetup

    Raises
    ------
    TypeError
        Unknown keywords.
    InputError
        Invalid values.

    Examples
    --------
    >>> from lacore.reconstruction.settings import ReconstructionSettings, split_options
    >>> settings, options, hybrid = split_options({"energy": "shells", "max_iterations": 5, "hybrid_start": "tree"})
    >>> settings == ReconstructionSettings(energy="shells"), options.max_iterations, hybrid.start
    (True, 5, 'tree')
    """
    names = {"settings": SETTINGS_FIELDS, "options": _GN_KEYS, "hybrid": frozenset(_HYBRID_KEYS)}
    unknown = sorted(set(keywords).difference(*(names[part] for part in accept)))
    if unknown:
        known = "; ".join(f"{_PART_NAMES[part]} {sorted(names[part])}" for part in accept)
        raise TypeError(f"{caller}() got unknown options {unknown}; {known}")

    def updated(obj, default, changes):
        obj = obj if obj is not None else default
        return replace(obj, **changes) if changes else obj

    return ReconstructionSetup(
        updated(settings, ReconstructionSettings(), {k: v for k, v in keywords.items() if k in SETTINGS_FIELDS}),
        updated(options, GaussNewtonOptions(), {k: v for k, v in keywords.items() if k in _GN_KEYS}),
        updated(hybrid, HybridOptions(), {_HYBRID_KEYS[k]: v for k, v in keywords.items() if k in _HYBRID_KEYS}))
