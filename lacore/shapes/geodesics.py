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
satisfy the Euler integrability conditions ``I~(z_i) = 0`` (3.13) and, on meshes
with holes or handles, the global conditions of Theorem 3.2 -- and the triangle
inequalities ``T_f(z_i) > 0``, which are checked, not imposed.

The solvers live in :mod:`lacore.shapes.geodesic_solvers`, the path energy in
:mod:`lacore.shapes.path_energy`; this module holds the entry point
:func:`discrete_geodesic`, its options and result, and the approximate
geodesic of section 4.2, :func:`projected_linear_path`.

``method="sqp"`` solves (4.6) in ``z`` by sequential quadratic programming,
``method="vertices"`` by Gauss-Newton in vertex positions (every point an
immersion, admissible by construction).  Both start by default from the
projected linear path (4.9, 4.10).

Energies
--------
:func:`~.path_energy.path_energy` and :func:`~.path_energy.path_energy_profile` take any energy with
``value(z_a, z_b)`` (also :class:`lacore.energies.ThinShellsEnergy`).  The
solvers need a quadratic energy -- anything with a ``residual_weights``
attribute ``w`` of shape ``(2E,)``, ``W = sum_j w_j (z_a - z_b)_j^2``, such as
:class:`lacore.energies.QuadraticEnergy` (default: ``W_q`` (3.19) with the
weights and ``eta`` of the settings, from the start shape) -- which they use in
closed form; weights of lengths and interior angles must be positive.

Scale
-----
Meant for small and medium meshes: every iteration factorizes a system over
all ``K - 1`` interior points.  The SQP Schur complement couples all time
steps (``(K-1)^2`` sparse blocks), the Gauss-Newton matrix only neighbouring
ones, so ``"vertices"`` scales better in ``K``.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, LengthsAnglesError, check_integer
from ..geometry.lengths_angles import check_z, lengths_and_angles
from ..geometry.topology import check_vertices
from ..integrability.checks import check_integrability
from ..reconstruction import GaussNewtonOptions, ReconstructionSettings, get_context, reconstruct
from ..result import SolverResult
from .geodesic_solvers import max_constraint_violation, min_triangle_margin, solve_sqp, solve_vertices
from .interpolation import interpolate
from .path_energy import (QuadraticPathModel, default_energy, linear_path, path_energy_profile,
                          quadratic_energy_weights)

__all__ = ["GeodesicOptions", "GeodesicResult", "discrete_geodesic", "projected_linear_path"]


@dataclass(frozen=True)
class GeodesicOptions:
    """Iteration and stopping options of :func:`discrete_geodesic`.

    Attributes
    ----------
    max_iterations : int
        Iteration cap (status 1).
    tol : float
        ``"sqp"``: relative KKT stationarity ``|g + A^T lambda|_inf <= tol |g|_inf``;
        ``"vertices"``: step ``<= tol * size`` (bounding-box diagonal of the reference).
    constraint_tol : float
        ``max |I~(z_i)|`` required for convergence of ``"sqp"``.
    regularization : float
        Proximal multiplier regularization ``delta`` of the SQP KKT system,
        relative to the largest diagonal entry of ``A H^-1 A^T``.
    reconstruct_vertices : bool
        For ``"sqp"``: reconstruct immersions of the (admissible) solution into
        ``result.vertices`` (Gauss-Newton projections, warm-started along the path).
    projection : GaussNewtonOptions
        Options of the Gauss-Newton projections (the projected linear start and
        ``reconstruct_vertices``).

    Raises
    ------
    InputError
        A negative or non-integer iteration cap, a non-positive tolerance, a negative regularization.
    """

    max_iterations: int = 200
    tol: float = 1e-8
    constraint_tol: float = 1e-10
    regularization: float = 1e-12
    reconstruct_vertices: bool = False
    projection: GaussNewtonOptions = GaussNewtonOptions()

    def __post_init__(self):
        object.__setattr__(self, "max_iterations", check_integer(self.max_iterations, "max_iterations", 0))
        for name in ("tol", "constraint_tol"):
            if not float(getattr(self, name)) > 0:
                raise InputError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not float(self.regularization) >= 0:
            raise InputError(f"regularization must be >= 0, got {self.regularization!r}")
        if not isinstance(self.projection, GaussNewtonOptions):
            raise InputError(f"projection must be a GaussNewtonOptions, got {type(self.projection).__name__}")
        object.__setattr__(self, "reconstruct_vertices", bool(self.reconstruct_vertices))


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
        ``max |I~(z_i)|`` and global conditions (holonomy angles, relative gaps) over the interior
        points (0 up to round-off for ``"vertices"``).
    min_triangle_margin : float
        ``min T_f(z_i)`` over all faces and path points (3.7); positive iff all
        triangle inequalities hold.
    multipliers : (K-1, 3 V_int + 6 n_loops) ndarray or None
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


def projected_linear_path(start, end, topology, n_steps, reference_vertices=None, *, settings=None, options=None):
    """The approximate discrete geodesic of section 4.2: linear path in ``z`` (4.9), every point projected (4.10).

    Parameters
    ----------
    start, end : (V, 3) vertices or (2E,) lengths and angles
    topology : MeshTopology
    n_steps : int
        ``K >= 1``.
    reference_vertices : (V, 3) array_like, optional
        Reference of the projections; default ``start`` (must then be vertices).
    settings : ReconstructionSettings, optional
        Settings of the projections (:func:`lacore.shapes.interpolation.interpolate`, Gauss-Newton).
    options : GaussNewtonOptions, optional
        Their iteration and stopping options.

    Returns
    -------
    z : (K+1, 2E) ndarray
        ``Z`` of the projected points (the end points reproduce the inputs up to
        the solver tolerance); its :func:`path_energy_profile` is the energy
        diagram of figure 4.1.
    vertices : (K+1, V, 3) ndarray
        The projected immersions, in the frame of the reference.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore.shapes.geodesics import projected_linear_path
    >>> z, vertices = projected_linear_path(X, bar_pose(X, 0.0, 0.5), topo, 4)
    >>> z.shape, vertices.shape
    ((5, 120), (5, 22, 3))
    """
    K = check_integer(n_steps, "n_steps", 1)
    # the projection P_Z itself: Gauss-Newton run to convergence (not the in-betweens' default preset)
    res = interpolate([start, end], topology, np.arange(K + 1) / K, method="gn",
                      reference_vertices=reference_vertices, settings=settings, options=options)
    X = np.array(res.vertices, float)
    return np.array([lengths_and_angles(x, topology) for x in X]), X


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


# --------------------------------------------------------------------------- driver
def discrete_geodesic(start, end, topology, n_steps, *, method="sqp", energy=None, initial=None,
                      reference_vertices=None, settings=None, options=None, progress=None):
    """Discrete geodesic in the space of lengths and angles: solve (4.6).

    Minimize ``K sum_{i=0}^{K-1} W[z_i, z_{i+1}]`` over ``z_1..z_{K-1}`` subject to
    ``I~(z_i) = 0`` (3.13) and, around holes and handles, the global conditions of
    Theorem 3.2, with ``T_f(z_i) > 0`` (3.7) checked on the whole path.

    Parameters
    ----------
    start, end : (V, 3) vertices or (2E,) lengths and angles
        End points ``z_0`` and ``z_K``; lengths and angles must be admissible
        (:func:`lacore.check_integrability`).
    topology : MeshTopology
    n_steps : int
        ``K >= 1``; the path has ``K + 1`` points (``K = 1`` has no unknowns).
    method : {"sqp", "vertices"}
        Constrained SQP in ``z`` or Gauss-Newton in vertex positions (module docstring).
    energy : object, optional
        Quadratic deformation energy with ``value(z_a, z_b)`` and
        ``residual_weights (2E,)`` (:class:`lacore.energies.QuadraticEnergy`); all
        weights of lengths and interior angles must be positive.  Default
        :func:`default_energy` (``W_q`` (3.19) with the weights and bending
        weight of ``settings``, from the reference).
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
    settings : ReconstructionSettings, optional
        Weights and bending weight of the default energy; settings of the
        projections and of the gauge of ``"vertices"`` (fixed face, solver).
        Its energy must be ``"quadratic"``.
    options : GeodesicOptions, optional
        Iteration and stopping options, vertices of the ``"sqp"`` solution,
        options of the projections.
    progress : callable, optional
        ``progress(done, total, message)`` before every iteration (``total`` =
        ``options.max_iterations``, :mod:`lacore.progress`); returning True stops with
        :class:`lacore.progress.Cancelled`.

    Returns
    -------
    GeodesicResult

    Raises
    ------
    LengthsAnglesError, MeshError
        Inputs of the wrong size or with NaN entries; an end point given as
        lengths and angles that are no mesh's; a starting path violating the
        triangle inequality.
    InputError
        ``n_steps < 1``, an unknown method, zero weights, the thin shells energy in ``settings``.

    Examples
    --------
    Two steps from a bent to a twisted bar:

    >>> import numpy as np
    >>> from lacore import MeshTopology, discrete_geodesic, path_energy_profile
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> topo = MeshTopology.from_faces(faces)
    >>> res = discrete_geodesic(bar_pose(X, 0.5, 0.0), bar_pose(X, 0.0, 0.5), topo, 2)
    >>> res.success, res.z.shape, bool(res.constraint_violation < 1e-9)
    (True, (3, 120), True)
    >>> print(np.round(res.step_energies / res.step_energies.mean(), 3))   # equidistant steps
    [1. 1.]
    """
    t0 = time.perf_counter()
    if method not in ("sqp", "vertices"):
        raise InputError(f"unknown geodesic method {method!r}; use 'sqp' or 'vertices'")
    K = check_integer(n_steps, "n_steps", 1)
    z0, X0 = _as_z(start, topology, "start")
    zK, XK = _as_z(end, topology, "end")
    for name, z, X in (("start", z0, X0), ("end", zK, XK)):
        if X is None:  # given as lengths and angles: they must be a mesh's (vertices are one by construction)
            check = check_integrability(z, topology)
            if not check.integrable:
                raise LengthsAnglesError(f"{name} is no mesh's lengths and angles ({check.describe()}): a geodesic "
                                         f"joins two meshes; give {name} as vertices or project it first "
                                         "(lacore.project)")
    if reference_vertices is not None:
        reference_vertices = check_vertices(reference_vertices, topology.n_vertices, name="reference_vertices")
    elif X0 is not None:
        reference_vertices = X0
    settings = settings if settings is not None else ReconstructionSettings()
    options = options if options is not None else GeodesicOptions()
    for name, value, kind in (("settings", settings, ReconstructionSettings), ("options", options, GeodesicOptions)):
        if not isinstance(value, kind):
            raise InputError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
    if settings.energy != "quadratic":
        raise InputError(f"the geodesic solvers need the quadratic energy W_q, got settings.energy="
                         f"{settings.energy!r}")
    if energy is None:
        energy = default_energy(topology, reference_vertices if reference_vertices is not None else z0, settings)
    E = topology.n_edges
    w = quadratic_energy_weights(energy, 2 * E)
    free = np.r_[np.arange(E), E + topology.interior_edges]
    if np.any(w[free] <= 0):
        raise InputError("the geodesic solvers need positive energy weights on all lengths and interior angles "
                         "(bending_weight > 0)")
    model = QuadraticPathModel(w, K)
    projection = {"settings": settings, "options": options.projection}

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
                                                 **projection)
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
        context = get_context(topology, reference_vertices, settings)

    if K < 2:
        out = {"status": 0, "message": "no interior points (n_steps = 1)", "iterations": 0,
               "history": {"path_energy": [initial_energy], "constraint_violation": [0.0], "stationarity": [],
                           "step": []},
               "multipliers": None}
    elif method == "sqp":
        for i, z in enumerate(zs[1:-1]):
            if min_triangle_margin(z, topology) <= 0:
                raise LengthsAnglesError(f"initial path point {i + 1} violates the triangle inequality")
        out = solve_sqp(zs, topology, model, options, progress)
    else:
        Xc = np.array([context.to_canonical(x) for x in Xs])
        out = solve_vertices(zs, Xc, topology, model, context, options, progress)
        Xs = np.array([context.from_canonical(x) for x in Xc])

    vertices = None
    if method == "vertices" and reference_vertices is not None:   # (K = 1 from lengths and angles alone: none)
        context = context or get_context(topology, reference_vertices, settings)
        ends = []
        for X, z in ((X0, z0), (XK, zK)):
            if X is None:  # an end given as (admissible) lengths and angles: its mesh
                X = reconstruct(z, topology, reference_vertices, method="gn", context=context,
                                options=options.projection).vertices
            ends.append(context.align(X))
        inner = Xs if K >= 2 else np.empty((0, topology.n_vertices, 3))
        vertices = np.concatenate([ends[0][None], inner, ends[1][None]])
    elif method == "sqp" and options.reconstruct_vertices:
        need_reference("reconstruct_vertices")
        proj = interpolate(zs, topology, np.arange(K + 1, dtype=float), method="gn",  # P_Z itself: converged GN
                           reference_vertices=reference_vertices, **projection)
        vertices = np.array(proj.vertices)

    profile = path_energy_profile(zs, energy)
    margin = min(min_triangle_margin(z, topology) for z in zs)
    violation = max_constraint_violation(zs[1:-1], topology)
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
