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
    the least-squares relaxation (default ``hybrid_start="lsq"``) or, with
    ``hybrid_start="tree"``, a frame-based walk (tree ``hybrid_kind``, default
    ``"mst"``), smoothed by at most ``smoothing_iterations`` Gauss-Newton
    iterations (section 3.4.3, "smoothing").

Fast smoothing
--------------
The Blender operator's 'FAST' method is ``"hybrid"`` with
``hybrid_start="lsq", reuse_factorization=True``: on long meshes errors of a
tree walk accumulate along the tree (a 50k-vertex bar blended from a bend to a
twist: edge lengths off by 160 % after the MST walk and still after three
Gauss-Newton iterations), while the least-squares relaxation spreads them
(1.4 %).  The Gauss-Newton steps solve their systems by conjugate gradients
preconditioned with the factorization held by the context (made at an earlier
iteration or frame), refactorizing only when PCG stalls, so an interpolation
pays about one numeric factorization instead of one per iteration and frame.

Every method returns a :class:`ReconstructionResult` whose ``vertices`` lie in
the frame of the reference mesh (the fixed face placed as the reference has it,
see :mod:`.gauss_newton`) and whose ``energy`` is ``W[z*, Z(vertices)]`` under
the chosen energy, so all methods are comparable.

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

import numpy as np

from ..errors import LengthsAnglesError, MeshError, format_indices
from ..lengths_angles import check_z, lengths_and_angles
from ..topology import MeshTopology, check_vertices
from ..trigonometry import triangle_inequality_margin
from .gauss_newton import GN_OPTIONS, ReconstructionContext, gauss_newton_reconstruction, get_context
from .result import STATUS_MESSAGES, ReconstructionResult

__all__ = [
    "reconstruct",
    "reconstruction_errors",
    "ReconstructionResult",
    "ReconstructionContext",
    "get_context",
    "METHODS",
    "STATUS_MESSAGES",
]

METHODS = ("gn", "bfs", "mst", "spt", "lsq", "hybrid")
_FRAME_KINDS = ("bfs", "mst", "spt")


def _check_target(z_target, topology, method, energy):
    """Validated ``z*``; LengthsAnglesError for targets no method can use."""
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
    return z


def reconstruct(z_target, topology, reference_vertices, method="gn", *, energy="quadratic", bending_weight=1e-3,
                weights="frohlich_botsch", fixed_face=None, fix_triangle_shape=False, initial_vertices=None,
                tree=None, hybrid_kind="mst", hybrid_start="lsq", smoothing_iterations=10, solver=None, context=None,
                **gn_options):
    """Reconstruct vertex positions from lengths and angles (thesis 3.4).

    Parameters
    ----------
    z_target : (2E,) array_like
        Target lengths and dihedral angles ``z*`` (layout of :mod:`lacore.lengths_angles`).
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh: weights (3.20)/(3.21) of ``W_q``, start of Gauss-Newton,
        output frame.
    method : {"gn", "bfs", "mst", "spt", "lsq", "hybrid"}
        See the module docstring.
    energy : {"quadratic", "shells"}
        ``W_q`` (3.19) or ``W_TS`` (3.25): minimized by ``"gn"``/``"hybrid"``,
        reported by all methods.
    bending_weight : float
        ``eta``, default ``1e-3``.
    weights : {"frohlich_botsch", "heeren", "uniform"}
        Weights of ``W_q``: (3.20) (default), (3.21) or 1.
    fixed_face : int or sequence of int, optional
        Face fixing the rigid motion (one per connected component); also the
        root of the frame-based methods.  Default: a central, well-shaped face
        of the reference mesh.
    fix_triangle_shape : bool
        Gauss-Newton holds all nine coordinates of the fixed face instead of
        only the six rigid motions (see :mod:`.gauss_newton`).
    initial_vertices : (V, 3) array_like, optional
        Start of ``"gn"`` (default: the reference); ignored by the other methods.
    tree : DualSpanningTree, optional
        A precomputed tree for ``"bfs"``/``"mst"``/``"spt"``/``"hybrid"``
        (e.g. :func:`~lacore.reconstruction.spanning_trees.preassembled_tree`).
    hybrid_kind : {"mst", "spt", "bfs"}
        Tree of the frame-based start of ``"hybrid"``.
    hybrid_start : {"lsq", "tree"}
        Start of ``"hybrid"``: the least-squares relaxation (default; ``tree`` and
        ``hybrid_kind`` are then unused) or the frame-based walk along the tree.
        Measured on the rolled-plate averages, 10 smoothing iterations from the
        least-squares start end within 0.3 % of the full Gauss-Newton energy
        (which needs 111 / 291 iterations from the reference), while from the
        MST walk they stay 80x / 27000x above it.
    smoothing_iterations : int
        At most this many Gauss-Newton iterations of ``"hybrid"`` (default 10;
        they stop earlier once converged).
    solver : {"cholmod", "scipy"}, optional
        Sparse Cholesky backend (default CHOLMOD if cvxopt is installed).
    context : ReconstructionContext, optional
        Shared set-up; when given, the settings above (``energy`` ...
        ``fix_triangle_shape``, ``solver``) must be left at their defaults or
        match the context.
    **gn_options
        Gauss-Newton options, see :data:`~lacore.reconstruction.gauss_newton.GN_OPTIONS`
        (``max_iterations, ftol, gtol, xtol, atol``; ``reuse_factorization,
        pcg_rtol, pcg_maxiter`` for inexact steps by conjugate gradients
        preconditioned with the factorization the context already holds;
        ``reuse_near_convergence`` (default True: such steps only in the final,
        fast-converging phase, to tolerances that vanish with the residual) and
        ``geodesic_acceleration`` (default True, ``W_q``: a second-order
        correction of each step along the residual's curvature, never folding
        an edge that was not folded)).

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
    ValueError
        Unknown method, energy, weights or option.

    Notes
    -----
    Frame-based methods need the triangle inequality only where they walk;
    they treat violating faces as in Algorithm 2 (see
    :mod:`.frame_based`).  ``"gn"`` with ``W_q`` accepts any positive lengths
    (best effort: the energy is defined for every target, cf. Figure 3.3).
    """
    t_start = time.perf_counter()
    if not isinstance(topology, MeshTopology):
        raise TypeError(f"topology must be a MeshTopology, got {type(topology).__name__}")
    if method not in METHODS:
        raise ValueError(f"unknown reconstruction method {method!r}; use one of {', '.join(METHODS)}")
    if hybrid_kind not in _FRAME_KINDS:
        raise ValueError(f"unknown hybrid_kind {hybrid_kind!r}; use one of {', '.join(_FRAME_KINDS)}")
    unknown = sorted(set(gn_options) - set(GN_OPTIONS))
    if unknown:
        raise TypeError(f"reconstruct() got unknown options {unknown}; Gauss-Newton options are {sorted(GN_OPTIONS)}")
    if hybrid_start not in ("tree", "lsq"):
        raise ValueError(f"unknown hybrid_start {hybrid_start!r}; use 'tree' or 'lsq'")
    if int(smoothing_iterations) != smoothing_iterations or smoothing_iterations < 0:
        raise ValueError(f"smoothing_iterations must be a non-negative integer, got {smoothing_iterations!r}")
    settings = {"energy": energy, "weights": weights, "bending_weight": bending_weight, "fixed_face": fixed_face,
                "fix_triangle_shape": fix_triangle_shape, "solver": solver}
    if context is None:
        context = get_context(topology, reference_vertices, **settings)
    else:
        _check_context(context, topology, reference_vertices, settings)
    z = _check_target(z_target, topology, method, context.energy_name)
    if initial_vertices is not None:
        initial_vertices = check_vertices(initial_vertices, topology.n_vertices, name="initial vertices")

    if method == "gn":
        return gauss_newton_reconstruction(z, topology, initial_vertices=initial_vertices, context=context,
                                           **gn_options)

    kind = hybrid_kind if method == "hybrid" else method
    t0 = time.perf_counter()
    if method == "lsq" or (method == "hybrid" and hybrid_start == "lsq"):
        kind = "lsq"
        X = _least_squares(z, topology, context)
    else:
        X = _frame_based(z, topology, context, kind, tree)
    try:
        X = context.align(X)  # the fixed face placed exactly as for Gauss-Newton
    except MeshError:
        pass  # a degenerate fixed face (target violates the triangle inequality there): keep the method's placement
    t_direct = time.perf_counter() - t0
    if method == "hybrid":
        opts = dict(gn_options, max_iterations=int(smoothing_iterations))
        res = gauss_newton_reconstruction(z, topology, initial_vertices=X, context=context,
                                          method_name=f"hybrid-{kind}", **opts)
        if res.status == 0:
            res.success = True
            res.message = f"{smoothing_iterations} smoothing iterations done"
        res.timings["frame_based" if kind != "lsq" else "least_squares"] = t_direct
        res.timings["total"] = time.perf_counter() - t_start
        return res
    energy_value = context.energy(z, X)
    t_total = time.perf_counter() - t_start
    return ReconstructionResult(vertices=X, success=bool(np.all(np.isfinite(X))), status=5,
                                message=STATUS_MESSAGES[5], method=method, energy=energy_value,
                                energy_name=context.energy_name, energy_history=[energy_value],
                                timings={"frame_based" if method != "lsq" else "least_squares": t_direct,
                                         "total": t_total},
                                fixed_face=context.fixed_face)


def _check_context(context, topology, reference_vertices, settings):
    if context.topology is not topology:
        raise ValueError("the context was made for another topology")
    if reference_vertices is not None:
        X = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices")
        if not np.array_equal(X, context.reference_vertices):
            raise ValueError("the context was made for other reference vertices")
    theirs = {"energy": context.energy_name, "weights": context.weights_kind,
              "bending_weight": context.bending_weight, "fix_triangle_shape": context.fix_triangle_shape,
              "solver": context.backend}
    defaults = {"energy": "quadratic", "weights": "frohlich_botsch", "bending_weight": 1e-3,
                "fix_triangle_shape": False, "solver": None}
    for k, v in theirs.items():
        if settings[k] != defaults[k] and settings[k] != v:
            raise ValueError(f"{k}={settings[k]!r} differs from the context's {v!r}")
    ff = settings["fixed_face"]
    if ff is not None and not np.all(np.isin(np.atleast_1d(ff), context.fixed_faces)):
        raise ValueError(f"fixed_face {ff!r} differs from the context's {context.fixed_faces.tolist()}")


def _frame_based(z, topology, context, kind, tree):
    from .frame_based import frame_based_reconstruction

    return frame_based_reconstruction(z, topology, tree=tree, kind=kind, root_face=context.fixed_faces,
                                      reference_vertices=context.reference_vertices)


def _least_squares(z, topology, context):
    from .least_squares import least_squares_reconstruction

    return least_squares_reconstruction(z, topology, root_face=context.fixed_faces,
                                        reference_vertices=context.reference_vertices)


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
    """
    X = check_vertices(vertices, topology.n_vertices)
    z_target = check_z(z_target, topology, name="target z")
    z = lengths_and_angles(X, topology)
    E = topology.n_edges
    dl = np.abs(z[:E] - z_target[:E])
    ie = topology.interior_edges
    da = np.abs(z[E:][ie] - z_target[E:][ie])
    size = float(np.linalg.norm(X.max(0) - X.min(0))) or 1.0
    return {
        "max_length_error": float(dl.max()),
        "max_relative_length_error": float(np.max(dl / z_target[:E])),
        "length_error_per_size": float(dl.max() / size),
        "max_angle_error": float(da.max()) if da.size else 0.0,
        "rms_length_error": float(np.sqrt(np.mean(dl**2))),
        "rms_angle_error": float(np.sqrt(np.mean(da**2))) if da.size else 0.0,
    }

