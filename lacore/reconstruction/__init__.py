"""Reconstruction of vertex positions from lengths and angles (thesis 3.4).

:func:`reconstruct` is the one entry point: it validates the input and
dispatches to

``"gn"``
    energy-based reconstruction (Def. 3.15): Gauss-Newton for
    ``min_X W[z*, Z(X)]`` (3.26), :mod:`.gauss_newton`;
``"bfs"``, ``"mst"``, ``"spt"``
    frame-based reconstruction along a dual spanning tree (Algorithm 1 with a
    breadth-first tree, Algorithm 2 with an adaptive minimal spanning or
    shortest path tree), :mod:`.frame_based`;
``"lsq"``
    the linear least-squares relaxation of the frame-based method,
    :mod:`.least_squares`;
``"hybrid"``
    the least-squares relaxation (default ``hybrid_start="lsq"``), with
    ``hybrid_start="tree"`` a frame-based walk (tree ``hybrid_kind``, default
    ``"mst"``), or with ``hybrid_start="given"`` the ``initial_vertices``,
    smoothed by at most ``smoothing_iterations`` Gauss-Newton
    iterations (section 3.4.3, "smoothing").

Fast smoothing
--------------
The preset :data:`~lacore.reconstruction.settings.FAST` (the default projection
of ``lacore interpolate``, of :mod:`lacore.shapes.interpolation` and the Blender
operators' 'FAST') is ``"hybrid"`` with ``hybrid_start="given"`` and one
smoothing iteration, extended where a step does not agree with its quadratic
model: :func:`lacore.shapes.interpolation.project_targets` gives every
in-between the extrapolation through the frames before it (continuation along
``t``), so one Gauss-Newton step finishes a frame of a smooth motion
(``benchmarks/bench_continuation.py``).  The least-squares start
(``hybrid_start="lsq"``) suits a single target with no neighbours: on long
meshes the errors of a tree walk accumulate along the tree, and a few
Gauss-Newton iterations do not remove them, while the least-squares relaxation
spreads them (``tests/test_hybrid.py``).

Every method returns a :class:`ReconstructionResult` whose ``vertices`` lie in
the frame of the reference mesh (the fixed face placed as the reference has it,
see :mod:`.context`) and whose ``energy`` is ``W[z*, Z(vertices)]`` under
the chosen energy, so all methods are comparable.  Its ``success`` is decided
the same way for every method by :mod:`.checks` (finite, no folded edge, and
the target reproduced within ``LENGTH_RTOL`` / ``ANGLE_ATOL`` or a converged
minimizer); ``failure`` names a failed check.  Gauss-Newton (``"gn"``, and
``"hybrid"`` from a given or tree start) checks its start
(``start_check``, :mod:`.gauss_newton`): when its first damped step gets less
than halfway, it continues from the least-squares relaxation if that is 1000
times better.  A ``"gn"`` run that fails after a stall (status -1 or -3), or
ends folded at the iteration limit (status 0), and did not continue from the
relaxation, is restarted once from it.

Reuse
-----
Everything that does not depend on the target (weights, fixed face, sparsity
pattern, symbolic factorization, spanning trees) lives in a
:class:`ReconstructionContext`.  :func:`reconstruct` takes one via ``context=``;
without it, one is looked up in a small per-topology cache keyed by the
reference vertices and the settings.  For a sequence of targets (an animation)
pass the previous result's vertices as ``initial_vertices``.
"""

import time
from dataclasses import replace

import numpy as np

from ..errors import InputError, LengthsAnglesError, format_indices
from ..geometry.lengths_angles import DEGENERACY_RTOL, check_z, lengths_and_angles, wrap_angle
from ..geometry.topology import MeshTopology, check_vertices
from ..geometry.trigonometry import triangle_inequality_margin
from .checks import ANGLE_ATOL, LENGTH_RTOL, apply_checks, check_reconstruction
from .context import ReconstructionContext, get_context
from .frame_based import frame_based_reconstruction
from .gauss_newton import SWITCH_NOTE, gauss_newton_reconstruction
from .least_squares import least_squares_start
from .result import STATUS_MESSAGES, GaussNewtonResult, ReconstructionResult
from .settings import (SETTINGS_FIELDS, GaussNewtonOptions, HybridOptions, ReconstructionSettings, ReconstructionSetup,
                       split_options)

__all__ = [
    "reconstruct",
    "reconstruction_errors",
    "ReconstructionResult",
    "GaussNewtonResult",
    "ReconstructionContext",
    "ReconstructionSettings",
    "GaussNewtonOptions",
    "HybridOptions",
    "ReconstructionSetup",
    "get_context",
    "METHODS",
    "STATUS_MESSAGES",
    "tree_kind",
    "check_reconstruction",
    "LENGTH_RTOL",
    "ANGLE_ATOL",
]

METHODS = ("gn", "bfs", "mst", "spt", "lsq", "hybrid")
_FRAME_KINDS = ("bfs", "mst", "spt")
#: Gauss-Newton statuses after which a failed ``"gn"`` run restarts from the least-squares relaxation.
_STALLED = (-3, -1)


def tree_kind(method, hybrid=None):
    """The spanning tree kind ``method`` walks (``"bfs"``, ``"mst"``, ``"spt"``), or None if it uses no tree.

    ``"gn"`` and ``"lsq"`` use none, nor does ``"hybrid"`` with the (default)
    least-squares start; ``hybrid`` is its :class:`HybridOptions`.
    """
    if method in _FRAME_KINDS:
        return method
    if method == "hybrid":
        hybrid = hybrid if hybrid is not None else HybridOptions()
        return hybrid.kind if hybrid.uses_tree else None
    return None


def _check_target(z_target, topology, method, energy):
    """Validated ``z*`` and notes; LengthsAnglesError for targets no method can use.

    Faces whose target lengths violate the triangle inequality (fewer than half
    of them), or satisfy it only within rounding (relative margin at most
    :data:`~lacore.geometry.lengths_angles.DEGENERACY_RTOL`), are accepted and named in the returned
    notes: the frame-based methods treat them as in the remark after Algorithm 2, Gauss-Newton with
    ``W_q`` minimizes the energy (no immersion reproduces such a target).
    """
    z = check_z(z_target, topology, name="target z")
    margin = triangle_inequality_margin(z[: topology.n_edges][topology.face_edges])
    bad = np.flatnonzero(~(margin > 0))
    if bad.size and energy == "shells" and method in ("gn", "hybrid"):
        raise LengthsAnglesError(f"the thin shells energy needs target lengths satisfying the triangle inequality; "
                                 f"violated at {bad.size} faces: {format_indices(bad)}")
    if bad.size * 2 > topology.n_faces:
        raise LengthsAnglesError(f"the target lengths violate the triangle inequality at {bad.size} of "
                                 f"{topology.n_faces} faces ({format_indices(bad)}): they do not describe "
                                 "this mesh (wrong edge order?)")
    notes = []
    L = z[: topology.n_edges][topology.face_edges]
    near = np.flatnonzero(~(margin > DEGENERACY_RTOL * L.sum(axis=1)))  # scale-free, as check_nondegenerate
    if near.size:
        notes.append(f"the target lengths violate the triangle inequality at {near.size} faces "
                     f"({format_indices(near)}) (relative margin <= {DEGENERACY_RTOL:g}): the target is not "
                     "admissible")
    return z, notes


def reconstruct(z_target, topology, reference_vertices, method="gn", *, settings=None, options=None, hybrid=None,
                initial_vertices=None, tree=None, context=None, **kwargs):
    """Reconstruct vertex positions from lengths and angles (thesis 3.4).

    Parameters
    ----------
    z_target : (2E,) array_like
        Target lengths and dihedral angles ``z*`` (layout of :mod:`lacore.geometry.lengths_angles`).
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh: weights (3.20)/(3.21) of ``W_q``, start of Gauss-Newton,
        output frame.  May be None when ``context`` is given.
    method : {"gn", "bfs", "mst", "spt", "lsq", "hybrid"}
        See the module docstring.
    settings : ReconstructionSettings, optional
        Energy (``W_q`` (3.19) or ``W_TS`` (3.25), minimized by ``"gn"``/``"hybrid"``,
        reported by all methods), weights, bending weight, fixed face (also the
        root of the frame-based methods), ``fix_triangle_shape``, solver backend.
        When ``context`` is given, leave it out (the context's settings apply) or
        give settings that match the context's (a ``None`` fixed face, solver or
        ordering matches any).
    options : GaussNewtonOptions, optional
        Iteration and stopping options of ``"gn"`` and of the smoothing of ``"hybrid"``.
    hybrid : HybridOptions, optional
        Start (``"lsq"``, default, or ``"tree"``), tree kind and smoothing
        iterations of ``"hybrid"``.
    initial_vertices : (V, 3) array_like, optional
        Start of ``"gn"`` (default: the reference) and of ``"hybrid"`` with
        ``hybrid_start="given"``; ignored by the other methods.
    tree : DualSpanningTree, optional
        A precomputed tree for ``"bfs"``/``"mst"``/``"spt"`` and the tree start of ``"hybrid"``
        (e.g. :func:`~lacore.reconstruction.spanning_trees.preassembled_tree`).
    context : ReconstructionContext, optional
        Shared set-up (weights, fixed face, pattern, symbolic factorization).
    **kwargs
        Convenience: the fields of the three objects as keywords, overriding
        them (:func:`~lacore.reconstruction.settings.split_options`):
        ``energy, weights, bending_weight, fixed_face, fix_triangle_shape,
        solver, ordering``; ``max_iterations, ftol, gtol, xtol, atol,
        reuse_factorization, pcg_rtol, pcg_maxiter, reuse_near_convergence,
        geodesic_acceleration, newton, start_check, c1, max_backtracks``; ``hybrid_start,
        hybrid_kind, smoothing_iterations, extend_smoothing``.  See
        :mod:`lacore.reconstruction.settings` for their meaning and defaults.

    Returns
    -------
    ReconstructionResult

    Raises
    ------
    LengthsAnglesError
        ``z_target`` of the wrong length, with NaN/inf or non-positive lengths,
        violating the triangle inequality at most faces (or at any face for
        ``energy="shells"``).
    MeshError
        Reference (or initial) vertices that do not match the topology, a bad
        fixed face.
    InputError
        Unknown method, energy, weights, an invalid option value, settings that
        differ from the given context.
    TypeError
        Unknown keyword.

    Notes
    -----
    Reference coordinates of magnitude outside ``2^-100 .. 2^100`` (about
    1e-30 .. 1e30) are computed in units of an exact power of two by the
    context (:mod:`.context`, "Units"); vertices and energies are in the input's
    units, and a note says so.

    Frame-based methods need the triangle inequality only where they walk;
    they treat violating faces as in Algorithm 2 (see
    :mod:`.frame_based`).  ``"gn"`` with ``W_q`` accepts any positive lengths
    (best effort: the energy is defined for every target, cf. Figure 3.3).

    Examples
    --------
    The lengths and angles of a bent bar give the bent bar back, in the frame of the reference:

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import reconstruct
    >>> from lacore.geometry.rigid import rigid_rms
    >>> bent = bar_pose(X, 0.5, 0.0)
    >>> res = reconstruct(lengths_and_angles(bent, topo), topo, X)
    >>> res.success, res.method, res.energy_name
    (True, 'gn', 'quadratic')
    >>> bool(rigid_rms(res.vertices, bent) < 1e-9)
    True

    Settings objects (or the same names as keywords) choose the energy and the solver:

    >>> from lacore import GaussNewtonOptions, ReconstructionSettings
    >>> res = reconstruct(lengths_and_angles(bent, topo), topo, X, settings=ReconstructionSettings(energy="shells"),
    ...                   options=GaussNewtonOptions(max_iterations=50))
    >>> res.success, res.energy_name
    (True, 'shells')
    >>> res = reconstruct(lengths_and_angles(bent, topo), topo, X, method="lsq")
    >>> res.success, res.status
    (True, 5)
    """
    t_start = time.perf_counter()
    if not isinstance(topology, MeshTopology):
        raise TypeError(f"topology must be a MeshTopology, got {type(topology).__name__}")
    if method not in METHODS:
        raise InputError(f"unknown reconstruction method {method!r}; use one of {', '.join(METHODS)}")
    # what the caller gave ("not given": settings None, a keyword absent); a settings object gives every field
    given = SETTINGS_FIELDS if settings is not None else SETTINGS_FIELDS & set(kwargs)
    settings, options, hybrid = split_options(kwargs, settings, options, hybrid)
    if context is None:
        context = get_context(topology, reference_vertices, settings)
    else:
        _check_context(context, topology, reference_vertices, settings, given)
    z, notes = _check_target(z_target, topology, method, context.energy_name)
    if context.units_note:
        notes.append(context.units_note)
    if initial_vertices is not None:
        initial_vertices = check_vertices(initial_vertices, topology.n_vertices, name="initial vertices")

    if method == "gn":
        res = gauss_newton_reconstruction(z, topology, initial_vertices=initial_vertices, context=context,
                                          options=options, started=t_start,
                                          start_check=options.start_check)  # checked there
        # a warm start in a poor basin stalls, or on some CPUs creeps on to the iteration limit, folded
        poor_basin = res.status in _STALLED or (res.status == 0 and res.failure == "folded")
        if poor_basin and not res.success and not any(SWITCH_NOTE in n for n in res.notes):
            res = _restart_from_least_squares(res, z, topology, context, options, t_start)
        return replace(res, notes=notes + res.notes)

    given_start = method == "hybrid" and hybrid.start == "given" and initial_vertices is not None
    if given_start:
        X, direct = initial_vertices, {}
    else:
        X, direct = _direct(z, topology, context, kind=tree_kind(method, hybrid), tree=tree)
    if method == "hybrid":
        n = hybrid.smoothing_iterations
        name = "given" if given_start else (tree_kind(method, hybrid) or "lsq")
        extend = hybrid.extend_smoothing
        res = gauss_newton_reconstruction(
            z, topology, initial_vertices=X, context=context,
            options=replace(options, max_iterations=max(n, options.max_iterations) if extend else n),
            method_name=f"hybrid-{name}", extra_timings=direct, started=t_start, budget=n, extend_budget=extend,
            success_status=(6, f"{n} smoothing iterations done" + (" (until a step agreed with its model)"
                                                                    if extend else "")),
            start_check=options.start_check and name != "lsq")
        return replace(res, notes=notes + res.notes)
    energy_value = context.energy(z, X)
    res = ReconstructionResult(vertices=X, success=True, status=5, message=STATUS_MESSAGES[5], method=method,
                               energy=energy_value, energy_name=context.energy_name, energy_history=[energy_value],
                               timings={**direct, "total": time.perf_counter() - t_start},
                               fixed_face=context.fixed_face, notes=notes)
    return apply_checks(res, z, topology, minimizer=False)


def _direct(z, topology, context, kind, tree=None):
    """Frame-based (``kind`` a tree kind) or least-squares (``kind=None``) vertices in the context's frame."""
    t0 = time.perf_counter()
    if kind is None:
        X = least_squares_start(z, topology, context)
    else:  # in the context's units (exact; the walk multiplies lengths)
        X = frame_based_reconstruction(context.internal_z(z), topology, tree=tree, kind=kind,
                                       root_face=context.fixed_faces, reference_vertices=context.internal_reference)
        # the fixed face placed exactly as for Gauss-Newton; a degenerate one (the target violates the triangle
        # inequality there) keeps the method's placement
        X = context.align(context.external_vertices(X), keep_degenerate=True)
    return X, {"frame_based" if kind is not None else "least_squares": time.perf_counter() - t0}


def _restart_from_least_squares(first, z, topology, context, options, t_start):
    """Gauss-Newton again from the least-squares relaxation after ``first`` stalled (status -1 or -3) or ended
    folded at the iteration limit.

    On very thin triangles (aspect ~1e4) the Gauss-Newton matrix at a flat
    start is too ill-conditioned for progress (condition ~ aspect^4 with the
    weights (3.20)), and a warm start can stall in a poor basin; the
    least-squares relaxation of the frame-based method starts in the right
    shape.  Returns the result that passed its checks, else the one with the
    lower energy, with a note saying what happened; ``iterations`` counts both
    runs, the history and counters are the returned run's.
    """
    try:
        X, direct = _direct(z, topology, context, kind=None)
    except (InputError, np.linalg.LinAlgError):
        return first
    if not np.all(np.isfinite(X)):
        return first
    second = gauss_newton_reconstruction(z, topology, initial_vertices=X, context=context, options=options,
                                         extra_timings=direct, started=t_start)
    note = (f"Gauss-Newton from the given start failed ({first.failure}: energy {first.energy:.6g} after "
            f"{first.iterations} iterations); restarted from the least-squares relaxation")
    best = second if (second.success or not second.energy >= first.energy) else first
    timings = dict(best.timings, total=time.perf_counter() - t_start)
    return replace(best, iterations=first.iterations + second.iterations, timings=timings,
                   notes=best.notes + [note + ("" if best is second else ", which was worse")])


def _check_context(context, topology, reference_vertices, settings, given):
    """InputError unless the given settings (names in ``given``) match the context's; ``None`` matches any
    fixed face, solver or ordering."""
    if context.topology is not topology:
        raise InputError("the context was made for another topology")
    if reference_vertices is not None:
        X = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices")
        if not np.array_equal(X, context.reference_vertices):
            raise InputError("the context was made for other reference vertices")
    theirs = context.settings
    for k in sorted(given - {"fixed_face", "solver", "ordering"}):
        if getattr(settings, k) != getattr(theirs, k):
            raise InputError(f"{k}={getattr(settings, k)!r} differs from the context's {getattr(theirs, k)!r}")
    if "ordering" in given and settings.ordering is not None and settings.ordering != theirs.ordering:
        raise InputError(f"ordering={settings.ordering!r} differs from the context's {theirs.ordering!r}")
    if "solver" in given and settings.solver is not None and settings.solver != context.backend:
        raise InputError(f"solver={settings.solver!r} differs from the context's {context.backend!r}")
    ff = settings.fixed_face
    if "fixed_face" in given and ff is not None and not np.all(np.isin(ff, context.fixed_faces)):
        raise InputError(f"fixed_face {list(ff)!r} differs from the context's {context.fixed_faces.tolist()}")


def _rms(x):
    """Root mean square of ``x >= 0`` without overflow or underflow of the squares (any scale)."""
    m = float(x.max()) if x.size else 0.0
    return m * float(np.sqrt(np.mean((x / m) ** 2))) if m > 0 and np.isfinite(m) else m


def reconstruction_errors(vertices, z_target, topology):
    """How well ``vertices`` reproduce target lengths and angles.

    Parameters
    ----------
    vertices : (V, 3) array_like
    z_target : (2E,) array_like
    topology : MeshTopology

    Returns
    -------
    dict
        ``max_length_error`` (absolute, mesh units), ``max_relative_length_error``
        (``max |l - l*| / l*``), ``length_error_per_size`` (``max_length_error``
        over the bounding-box diagonal of ``vertices``), ``max_angle_error``
        (radians, interior edges; boundary angles are 0 by convention),
        ``rms_length_error``, ``rms_angle_error``.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import reconstruction_errors
    >>> z = lengths_and_angles(X, topo)
    >>> errors = reconstruction_errors(X, z, topo)
    >>> errors["max_length_error"], errors["max_angle_error"]
    (0.0, 0.0)
    >>> errors = reconstruction_errors(1.01 * X, z, topo)
    >>> round(errors["max_relative_length_error"], 6), round(errors["max_angle_error"], 6)
    (0.01, 0.0)
    """
    X = check_vertices(vertices, topology.n_vertices)
    z_target = check_z(z_target, topology, name="target z")
    z = lengths_and_angles(X, topology)
    E = topology.n_edges
    dl = np.abs(z[:E] - z_target[:E])
    ie = topology.interior_edges
    da = np.abs(wrap_angle(z[E:][ie] - z_target[E:][ie]))
    extent = X.max(0) - X.min(0)
    m = float(np.max(np.abs(extent)))
    size = m * float(np.linalg.norm(extent / m)) if m > 0 else 1.0  # no overflow of the squares at any scale
    return {
        "max_length_error": float(dl.max()),
        "max_relative_length_error": float(np.max(dl / z_target[:E])),
        "length_error_per_size": float(dl.max() / size),
        "max_angle_error": float(da.max()) if da.size else 0.0,
        "rms_length_error": _rms(dl),
        "rms_angle_error": float(np.sqrt(np.mean(da**2))) if da.size else 0.0,
    }

