"""Interpolation, extrapolation and keyframe in-betweens in lengths and angles (thesis 4.2, eqs. 4.9, 4.10).

Shapes ``X_0, ..., X_{K-1}`` in dense correspondence (vertex arrays ``(V, 3)``)
are encoded as lengths and angles ``z_k = Z[X_k]`` (``(2E,)``, layout of
:mod:`lacore.geometry.lengths_angles`) and placed at increasing *keyframe times*
``k_0 < k_1 < ... < k_{K-1}`` (default ``0, 1, ..., K-1``).  A frame at time
``t`` gets the target

* piecewise linear in ``z`` (:func:`piecewise_linear_z`)::

      z~(t) = (1 - u) z_s + u z_{s+1},    u = (t - k_s) / (k_{s+1} - k_s)

  on the segment ``s`` containing ``t``; the first and last segment are extended
  linearly beyond the keyframes, so ``t < k_0`` or ``t > k_{K-1}`` extrapolates.
  For two shapes at times 0 and 1 this is ``(1 - t) z_0 + t z_1``: the
  equidistant linear path is the unconstrained discrete geodesic of ``W_q`` in
  the ambient space (4.9);
* or a cubic spline in ``z`` through the keyframes (:func:`spline_z`,
  :class:`scipy.interpolate.CubicSpline` along the time axis) with *natural*
  boundary conditions (zero second derivative at the first and last keyframe);
  beyond the keyframes it continues linearly with the end slopes, which matches
  the natural end condition (C2).  With two keyframes it is the linear
  interpolation.

Then every target is projected onto the admissible set by reconstruction
(4.10), ``P_Z[z~] = Z[R[z~]]`` (:func:`lacore.reconstruction.reconstruct`;
``method="gn"`` is the energy-based projection of Definition 4.3 run to
convergence).  Without a method the projection is
:data:`lacore.reconstruction.settings.DEFAULT_PROJECTION` (the preset ``"fast"``:
continuation and one Gauss-Newton step per frame), the default of the CLI and
the Blender add-on too.

Sharing work between frames
---------------------------
* One :class:`~lacore.reconstruction.ReconstructionContext` (weights, fixed
  face, Gauss-Newton sparsity pattern and symbolic Cholesky factorization) is
  made for the reference shape and passed to every frame, so all frames share
  one symbolic factorization (``result.context``).
* Frames are processed in order of ``t``; with warm starts (default) each
  Gauss-Newton projection (``"gn"``, and ``"hybrid"`` with
  ``hybrid_start="given"``) starts from a prediction made of the already known
  shapes: input shapes given as vertices (at their keyframe times) and the
  computed frames.  ``warm_start="secant"`` (default, also ``True``)
  extrapolates linearly through the nearest known shape and the next one on the
  same side (:func:`predicted_start`, continuation along ``t``: the error of
  the start is second order in the frame spacing, so one or two Gauss-Newton
  steps finish a frame) and keeps that prediction if its energy for the frame's
  target is below the nearest shape's (a linear extrapolation of positions
  shrinks rotating parts: across a whole bend it is worse than the key);
  ``"nearest"`` starts from the nearest known shape.
* Frame-based methods (``"bfs"``, ``"mst"``, ``"spt"``, ``"hybrid"``) use one
  spanning tree for all frames, preassembled from the keyframe samples ``z_k``
  (remark after Algorithm 2, :func:`~lacore.reconstruction.spanning_trees.preassembled_tree`).

Output placement
----------------
All frames are returned in the frame of the reference shape (``reference``,
default the first): the fixed triangle of the reconstruction sits exactly
where the reference shape has it, so an animation made of the frames does not
jump.
"""

import queue
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import InputError, LengthsAnglesError, MeshError
from ..geometry.lengths_angles import check_z, lengths_and_angles
from ..parallel import WorkerProcess, check_workers, frame_chains, raise_worker_error
from ..progress import report
from ..reconstruction import METHODS, get_context, reconstruct, reconstruction_errors, tree_kind
from ..reconstruction.settings import projection_preset, split_options
from ..reconstruction.spanning_trees import bfs_tree, preassembled_tree
from ..result import SolverResult
from ..geometry.topology import MeshTopology, check_vertices

__all__ = [
    "InterpolationResult",
    "ChainWorkers",
    "interpolate",
    "keyframe_inbetweens",
    "project_targets",
    "shapes_to_z",
    "check_keyframes",
    "piecewise_linear_z",
    "spline_z",
    "predicted_start",
    "WARM_STARTS",
]

#: Values of ``warm_start`` (besides ``True`` = ``"secant"`` and ``False`` = cold starts from the reference).
WARM_STARTS = ("secant", "nearest")

#: The secant prediction extrapolates at most this many times the spacing of the two shapes it goes through.
MAX_EXTRAPOLATION = 1.0


@dataclass(kw_only=True, repr=False)
class InterpolationResult(SolverResult):
    """Frames of :func:`interpolate` / :func:`keyframe_inbetweens` / :func:`project_targets`.

    A :class:`lacore.result.SolverResult` whose ``status`` and ``iterations``
    hold one entry per frame.

    Arrays have one entry per requested frame, in the order requested.

    Attributes
    ----------
    vertices : (N, V, 3) ndarray
        Projected frames, all in the frame of the reference shape.
    times : (N,) ndarray
        Frame times in keyframe-time units (the ``factors`` or ``frames``).
    z_targets : (N, 2E) ndarray
        The targets ``z~(t)`` before projection.
    energy : (N,) ndarray
        ``W[z~, Z(vertices)]`` of every frame (the projection's residual energy).
    iterations : (N,) ndarray of int
        Gauss-Newton iterations per frame (0 for direct frame-based methods).
    seconds : (N,) ndarray
        Wall time of every projection (the reconstruction call).
    max_length_error, max_angle_error : (N,) ndarray
        ``max |l - l~|`` (mesh units) and ``max |theta - theta~|`` (radians) of
        every frame, see :func:`lacore.reconstruction.reconstruction_errors`.
    status : (N,) ndarray of int
        Reconstruction status codes (:data:`lacore.reconstruction.STATUS_MESSAGES`).
    warm_start_times : (N,) ndarray
        Time of the neighbour whose vertices started the Gauss-Newton projection
        (NaN: started from the reference shape).
    order : (N,) ndarray of int
        Processing order (indices into the frames): the chains one after another
        (:func:`lacore.parallel.frame_chains`; one chain: increasing time).
    workers : int
        Chains computed side by side (this process and ``workers - 1`` worker
        processes, :mod:`lacore.parallel`).
    reconstructions : list of ReconstructionResult
    context : ReconstructionContext
        The set-up shared by all frames (one symbolic factorization).
    tree : DualSpanningTree or None
        The preassembled spanning tree of frame-based methods.
    keyframes : (K,) ndarray or None
        Keyframe times of the input shapes (:func:`interpolate`, :func:`keyframe_inbetweens`;
        None from :func:`project_targets`).
    smooth : bool
        Whether the targets come from the cubic spline (:func:`spline_z`).
    method : str
    success : bool
        Every frame's reconstruction passed its checks (``ReconstructionResult.success``,
        :mod:`lacore.reconstruction.checks`).
    message : str
    timings : dict
        ``total``: wall time of the whole call (as ``total_seconds``).
    total_seconds : float
        Wall time of the whole call (including encoding and set-up).
    total_iterations : int
    """

    vertices: np.ndarray
    times: np.ndarray
    z_targets: np.ndarray
    energy: np.ndarray
    seconds: np.ndarray
    max_length_error: np.ndarray
    max_angle_error: np.ndarray
    warm_start_times: np.ndarray
    order: np.ndarray
    reconstructions: list = field(default_factory=list)
    context: object = None
    tree: object = None
    keyframes: np.ndarray | None = None
    smooth: bool = False
    method: str = "gn"
    total_seconds: float = 0.0
    total_iterations: int = 0
    workers: int = 1

    _summary_exclude = ("vertices", "z_targets", "reconstructions", "context", "tree")



# --------------------------------------------------------------------------- inputs
def shapes_to_z(shapes, topology):
    """Lengths and angles of a sequence of shapes.

    Parameters
    ----------
    shapes : sequence of (V, 3) vertex arrays and/or (2E,) lengths-and-angles vectors
        Also a single array ``(K, V, 3)`` or ``(K, 2E)``.
    topology : MeshTopology

    Returns
    -------
    z : (K, 2E) ndarray
    vertices : list of K (V, 3) ndarrays or None (for shapes given as ``z``)

    Raises
    ------
    MeshError
        A vertex array with the wrong vertex count (not in dense correspondence) or NaN coordinates.
    LengthsAnglesError
        A ``z`` of the wrong size, with NaN or non-positive lengths.
    ValueError
        Fewer than 2 shapes.
    """
    if not isinstance(topology, MeshTopology):
        raise TypeError(f"topology must be a MeshTopology, got {type(topology).__name__}")
    if isinstance(shapes, np.ndarray) and shapes.ndim in (2, 3):
        items = list(shapes)
    else:
        items = list(shapes)
    if len(items) < 2:
        raise InputError(f"interpolation needs at least 2 shapes, got {len(items)}")
    zs, Xs = [], []
    V, E2 = topology.n_vertices, 2 * topology.n_edges
    for k, s in enumerate(items):
        a = np.asarray(s, dtype=float)
        if a.ndim == 2:
            if a.shape[0] != V:
                raise MeshError(f"shape {k} has {a.shape[0]} vertices but shape 0 / the mesh has {V} "
                                "(shapes must be in dense correspondence)")
            X = check_vertices(a, V, name=f"shape {k}")
            zs.append(lengths_and_angles(X, topology))
            Xs.append(X)
        elif a.ndim == 1:
            if a.shape != (E2,):
                raise LengthsAnglesError(f"shape {k} is a vector of length {a.size}; lengths and angles of this "
                                         f"mesh have 2E = {E2} entries")
            zs.append(check_z(a, topology, name=f"shape {k} (lengths and angles)"))
            Xs.append(None)
        else:
            raise MeshError(f"shape {k} must be a (V, 3) vertex array or a (2E,) vector, got shape {a.shape}")
    return np.array(zs), Xs


def check_keyframes(keyframes, n_shapes):
    """Validated keyframe times ``(K,)`` float; default ``0..K-1``.

    Raises
    ------
    ValueError
        A count different from the number of shapes, NaN/inf, or times that are not strictly increasing.
    """
    if keyframes is None:
        return np.arange(n_shapes, dtype=float)
    k = np.asarray(keyframes, dtype=float)
    if k.ndim != 1:
        raise InputError(f"keyframes must be a 1-d sequence of times, got shape {k.shape}")
    if len(k) != n_shapes:
        raise InputError(f"{len(k)} keyframes given for {n_shapes} shapes: give one keyframe time per shape")
    if not np.all(np.isfinite(k)):
        raise InputError(f"keyframes must be finite numbers, got {k.tolist()}")
    bad = np.flatnonzero(np.diff(k) <= 0)
    if bad.size:
        i = int(bad[0])
        raise InputError(f"keyframes must be strictly increasing: keyframe {i + 1} ({k[i + 1]:g}) does not come "
                         f"after keyframe {i} ({k[i]:g})")
    return k


def _check_times(times, name="factors"):
    t = np.atleast_1d(np.asarray(times, dtype=float))
    if t.ndim != 1 or t.size == 0:
        raise InputError(f"{name} must be a non-empty 1-d sequence of numbers, got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise InputError(f"{name} must be finite; entries {bad.tolist()} are NaN or infinite")
    return t


# --------------------------------------------------------------------------- targets
def piecewise_linear_z(z_keys, keyframes, times):
    """Piecewise linear interpolation in ``z`` with linear extension of the end segments.

    Parameters
    ----------
    z_keys : (K, 2E) array_like
        Lengths and angles at the keyframes, K >= 2.
    keyframes : (K,) array_like
        Strictly increasing times.
    times : (N,) array_like

    Returns
    -------
    (N, 2E) ndarray
        ``(1 - u) z_s + u z_{s+1}`` with ``u = (t - k_s) / (k_{s+1} - k_s)`` on the
        segment ``s`` of ``t`` (``s = 0`` before the first and ``s = K-2`` after the
        last keyframe, where ``u < 0`` resp. ``u > 1`` extrapolates).
    """
    Z = np.asarray(z_keys, float)
    k = np.asarray(keyframes, float)
    t = np.atleast_1d(np.asarray(times, float))
    s = np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2)
    u = (t - k[s]) / (k[s + 1] - k[s])
    out = (1.0 - u)[:, None] * Z[s] + u[:, None] * Z[s + 1]
    # exact keyframe values (no round-off from 1 - u)
    hit = np.searchsorted(k, t)
    exact = (hit < len(k)) & (k[np.minimum(hit, len(k) - 1)] == t)
    out[exact] = Z[hit[exact]]
    return out


def spline_z(z_keys, keyframes, times, bc_type="natural"):
    """Cubic spline in ``z`` through the keyframes, linear beyond them.

    Parameters
    ----------
    z_keys : (K, 2E) array_like
    keyframes : (K,) array_like
        Strictly increasing times.
    times : (N,) array_like
    bc_type : str or tuple
        Boundary condition of :class:`scipy.interpolate.CubicSpline`; default
        ``"natural"`` (zero second derivative at the end keyframes).

    Returns
    -------
    (N, 2E) ndarray
        ``S(t)`` inside ``[k_0, k_{K-1}]``; outside, ``S(k_end) + S'(k_end) (t - k_end)``
        (C1, and C2 for natural boundary conditions).  Passes exactly through
        ``z_keys`` at the keyframes; with ``K = 2`` it is the linear interpolation.
    """
    Z = np.asarray(z_keys, float)
    k = np.asarray(keyframes, float)
    t = np.atleast_1d(np.asarray(times, float))
    if len(k) == 2:
        return piecewise_linear_z(Z, k, t)
    S = CubicSpline(k, Z, axis=0, bc_type=bc_type)
    out = S(np.clip(t, k[0], k[-1]))
    for end, mask in ((k[0], t < k[0]), (k[-1], t > k[-1])):
        if np.any(mask):
            out[mask] = S(end)[None] + (t[mask] - end)[:, None] * S(end, 1)[None]
    hit = np.searchsorted(k, t)
    exact = (hit < len(k)) & (k[np.minimum(hit, len(k) - 1)] == t)
    out[exact] = Z[hit[exact]]
    return out


# --------------------------------------------------------------------------- warm starts
def _warm_start_kind(warm_start):
    if warm_start is True:
        return "secant"
    if warm_start is False or warm_start is None:
        return None
    if warm_start not in WARM_STARTS:
        raise InputError(f"warm_start must be True, False or one of {', '.join(WARM_STARTS)}, got {warm_start!r}")
    return warm_start


def predicted_start(t, known_times, known_vertices, kind="secant", place=None):
    """Starting vertices for the frame at ``t`` from shapes known at other times.

    Parameters
    ----------
    t : float
    known_times : (K,) array_like
        Times of the known shapes (K >= 1).
    known_vertices : sequence of K (V, 3) arrays
        The known shapes.
    place : callable, optional
        ``X -> X`` moving a shape into one common placement (e.g.
        :meth:`~lacore.reconstruction.ReconstructionContext.align`), applied to
        the two shapes a secant combines; default: they already share one.
    kind : {"secant", "nearest"}
        ``"nearest"``: the known shape ``X_j`` nearest in time (the first one on
        ties).  ``"secant"``: ``X_j + r (X_j - X_k)``, ``r = (t - t_j) / (t_j - t_k)``,
        with ``X_k`` the known shape nearest to ``t_j`` on the other side of
        ``t_j`` than ``t`` (linear extrapolation of the path ``t -> X(t)``, error
        ``O(h^2)`` for a frame spacing ``h``); ``X_j`` alone when there is no such
        shape or ``r > MAX_EXTRAPOLATION``.

    Returns
    -------
    vertices : (V, 3) ndarray
    source_time : float
        ``t_j``.
    """
    kt = np.asarray(known_times, float)
    dist = np.abs(kt - t)
    j = int(np.argmin(dist))
    Xj = np.asarray(known_vertices[j], float)
    if kind == "nearest" or dist[j] == 0.0:
        return Xj, float(kt[j])
    side = (kt - kt[j]) * (t - kt[j]) < 0.0   # beyond t_j, away from t
    if not np.any(side):
        return Xj, float(kt[j])
    cand = np.flatnonzero(side)
    k = int(cand[np.argmin(np.abs(kt[cand] - kt[j]))])
    r = (t - kt[j]) / (kt[j] - kt[k])
    if r > MAX_EXTRAPOLATION * (1.0 + 1e-9):  # (equal spacings give r = 1 only up to round-off)
        return Xj, float(kt[j])
    Xk = np.asarray(known_vertices[k], float)
    if place is not None:
        Xj, Xk = place(Xj), place(Xk)
    return Xj + r * (Xj - Xk), float(kt[j])


# --------------------------------------------------------------------------- projection of many frames
def _frame_tree(method, hybrid, z_keys, topology, context, tree):
    """The shared spanning tree of the frame-based methods; None for methods that walk no tree.

    ``"gn"``, ``"lsq"`` and the (default) least-squares start of ``"hybrid"`` use no tree
    (:func:`lacore.reconstruction.tree_kind`), so none is built for them.
    """
    kind = tree_kind(method, hybrid)
    if tree is not None or kind is None:
        return tree if kind is not None else None
    if kind == "bfs":
        return bfs_tree(topology, context.fixed_faces)
    return preassembled_tree(z_keys, topology, root_face=context.fixed_faces, kind=kind)


def project_targets(z_targets, topology, reference_vertices, times=None, anchors=None, method=None,
                    warm_start=True, tree=None, z_keys=None, *, settings=None, options=None, hybrid=None,
                    progress=None, on_frame=None, workers=1, **reconstruct_kw):
    """Project many targets onto the admissible set with shared set-up and warm starts (4.10).

    Parameters
    ----------
    z_targets : (N, 2E) array_like
        Targets ``z~`` (need not be admissible).
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference shape: weights of ``W_q``, fixed face, output frame, cold start.
    times : (N,) array_like, optional
        Time of every target (processing order and warm-start neighbours);
        default ``0..N-1``.
    anchors : sequence of (time, (V, 3) vertices), optional
        Known shapes (e.g. the input keyframes) usable as warm starts.
    method : {None, "fast", "gn", "hybrid", "bfs", "mst", "spt", "lsq"}
        Reconstruction method (:func:`lacore.reconstruction.reconstruct`) or the
        name of a :class:`~lacore.reconstruction.settings.ProjectionPreset`
        (``"fast"``; its options where ``options`` / ``hybrid`` are not given);
        None: :data:`~lacore.reconstruction.settings.DEFAULT_PROJECTION`.
    warm_start : {True, "secant", "nearest", False}
        Start every Gauss-Newton projection from a prediction through the known
        neighbours in time (``True`` / ``"secant"``, :func:`predicted_start`), from
        the nearest one (``"nearest"``), or from the reference shape (``False``).
    tree : DualSpanningTree, optional
        Spanning tree for frame-based methods; default preassembled from ``z_keys``.
    z_keys : (n_s, 2E) array_like, optional
        Samples for the preassembled tree; default the targets themselves.
    settings, options, hybrid : optional
        :class:`~lacore.reconstruction.ReconstructionSettings` (defines the shared
        context), :class:`~lacore.reconstruction.GaussNewtonOptions`,
        :class:`~lacore.reconstruction.HybridOptions`.
    progress : callable, optional
        ``progress(done, total, message)`` after every frame (:mod:`lacore.progress`);
        returning True stops with :class:`lacore.progress.Cancelled`.
    on_frame : callable, optional
        ``on_frame(index, result)`` as soon as the frame ``index`` (position in
        the given times) is projected, with its
        :class:`~lacore.reconstruction.ReconstructionResult` (frames finish in
        time order, with ``workers > 1`` chain by chain, interleaved): stream
        results to disk as they finish.
    workers : int
        Chains of frames computed side by side, see :func:`interpolate` (default 1).
    **reconstruct_kw
        The fields of these objects as keywords of :func:`~lacore.reconstruction.reconstruct`
        (``energy, weights, bending_weight, fixed_face, fix_triangle_shape,
        solver, hybrid_start, hybrid_kind, smoothing_iterations`` and Gauss-Newton options).

    Returns
    -------
    InterpolationResult

    Raises
    ------
    Cancelled
        The progress callback asked to stop; ``partial`` is None.
    """
    method, options, hybrid = projection_preset(method, options, hybrid)
    return _project(z_targets, topology, reference_vertices, times, anchors, method, warm_start, tree, z_keys,
                    split_options(reconstruct_kw, settings, options, hybrid, caller="project_targets")[:3],
                    progress, keyframes=None, smooth=False, t_start=time.perf_counter(), on_frame=on_frame,
                    workers=workers)


def _project(z_targets, topology, reference_vertices, times, anchors, method, warm_start, tree, z_keys,
             setup, progress, keyframes, smooth, t_start, on_frame=None, workers=1, order=None, send=None):
    """Project the targets (see :func:`project_targets`).

    The frames are split into ``workers`` chains (:func:`lacore.parallel.frame_chains`); this process
    computes the first, a :class:`lacore.parallel.WorkerProcess` each other one (running this function on
    its chain with ``order`` = the chain's processing order and ``send`` = the pipe back).  Every chain
    starts from the anchors and its own frames only, so the result does not depend on timing.
    """
    settings, options, hybrid = setup
    if method not in METHODS:
        raise InputError(f"unknown projection method {method!r}; use one of {', '.join(METHODS)}")
    warm_start = _warm_start_kind(warm_start)
    workers = check_workers(workers)
    takes_start = method == "gn" or (method == "hybrid" and hybrid.start == "given")
    Zt = np.asarray(z_targets, float)
    if Zt.ndim != 2 or Zt.shape[1] != 2 * topology.n_edges:
        raise LengthsAnglesError(f"targets must have shape (N, {2 * topology.n_edges}), got {Zt.shape}")
    N = len(Zt)
    times = np.arange(N, dtype=float) if times is None else _check_times(times, "times")
    if len(times) != N:
        raise InputError(f"{len(times)} times for {N} targets")
    if send is None:
        for i in np.argsort(times, kind="stable"):  # fail before any work, naming the frame
            check_z(Zt[i], topology, name=f"target at t = {times[i]:g} (extrapolated too far?)")
    X_ref = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices")
    context = get_context(topology, X_ref, settings)
    tree = _frame_tree(method, hybrid, Zt if z_keys is None else np.asarray(z_keys, float), topology, context, tree)
    anchors = [(float(t), np.asarray(X, float)) for t, X in (anchors or [])]
    known_t = [t for t, _ in anchors]
    known_X = [X for _, X in anchors]
    chains = [np.asarray(order)] if order is not None else frame_chains(times, known_t, workers)

    V = topology.n_vertices
    vertices = np.empty((N, V, 3))
    energy, seconds = np.empty(N), np.empty(N)
    iterations, status = np.zeros(N, np.int64), np.zeros(N, np.int64)
    max_len, max_ang = np.empty(N), np.empty(N)
    warm_times = np.full(N, np.nan)
    results = [None] * N
    done = 0

    def record(i, res, sec, errors, warm_time):
        nonlocal done
        vertices[i] = res.vertices
        results[i], energy[i], seconds[i] = res, res.energy, sec
        iterations[i], status[i] = res.iterations, res.status
        max_len[i], max_ang[i] = errors
        warm_times[i] = warm_time
        if send is not None:
            send((int(i), res, sec, errors, warm_time))
        if on_frame is not None:
            on_frame(int(i), res)
        done += 1
        report(progress, done, N, f"frame {done} of {N} (t = {times[i]:g})")

    pool = ChainWorkers(chains[1:], Zt, topology, X_ref, times, anchors, method, warm_start, tree, setup)
    try:
        report(progress, 0, N, "projecting frames")
        for i in chains[0]:
            t = float(times[i])
            initial, frame_hybrid, warm_time = None, hybrid, np.nan
            if warm_start and takes_start and known_t:  # anchors (listed first) win ties
                initial, warm_time = predicted_start(t, known_t, known_X, "nearest")
                predicted = False
                if warm_start == "secant":
                    guess, _ = predicted_start(t, known_t, known_X, "secant",
                                               place=lambda X: context.align(X, keep_degenerate=True))
                    if guess is not initial and context.energy(Zt[i], guess) < context.energy(Zt[i], initial):
                        initial, predicted = guess, True
                if not predicted and hybrid.nearest_start_iterations is not None:
                    frame_hybrid = replace(hybrid, smoothing_iterations=hybrid.nearest_start_iterations)
            t0 = time.perf_counter()
            try:
                res = reconstruct(Zt[i], topology, X_ref, method=method, context=context, initial_vertices=initial,
                                  tree=tree, options=options, hybrid=frame_hybrid)
            except LengthsAnglesError as exc:
                raise LengthsAnglesError(f"frame at t = {t:g}: {exc}") from exc
            sec = time.perf_counter() - t0
            X = np.asarray(res.vertices, float)
            errors = (np.nan, np.nan)
            if np.all(np.isfinite(X)):
                err = reconstruction_errors(X, Zt[i], topology)
                errors = (err["max_length_error"], err["max_angle_error"])
                known_t.append(t)  # usable as a warm start
                known_X.append(X)
            record(i, res, sec, errors, warm_time)
            pool.collect(record, block=False)
        pool.collect(record, block=True)
    finally:
        pool.close()
    success = all(r.success for r in results)
    failed = [float(times[i]) for i in range(N) if not results[i].success]
    first = next((r for r in results if not r.success), None)
    message = "all frames projected" if success else (f"projection failed its checks at t = {failed} "
                                                      f"(first: {first.failure}: {first.message})")
    total = time.perf_counter() - t_start
    return InterpolationResult(
        vertices=vertices, times=times, z_targets=Zt, energy=energy, iterations=iterations, seconds=seconds,
        max_length_error=max_len, max_angle_error=max_ang, status=status, warm_start_times=warm_times,
        order=np.concatenate(chains), reconstructions=results, context=context, tree=tree, method=method,
        success=bool(success), message=message, keyframes=keyframes, smooth=bool(smooth), timings={"total": total},
        total_seconds=total, total_iterations=int(iterations.sum()), workers=len(chains))


def _project_chain(z_targets, topology, reference_vertices, times, anchors, method, warm_start, tree, setup, *,
                   send):
    """A worker's job (:class:`lacore.parallel.WorkerProcess`): one chain of frames, in the given order,
    every frame sent back as it finishes."""
    _project(z_targets, topology, reference_vertices, times, anchors, method, warm_start, tree, None, setup, None,
             keyframes=None, smooth=False, t_start=time.perf_counter(), order=np.arange(len(times)), send=send)


class ChainWorkers:
    """Chains of frames computed in worker processes (:mod:`lacore.parallel`), one process per chain.

    Parameters
    ----------
    chains : list of int arrays
        Frame indices of every chain in processing order (:func:`lacore.parallel.frame_chains`).
    z_targets, topology, reference_vertices, times, anchors, method, warm_start, tree
        As in :func:`project_targets` (all frames; each worker receives its chain's).
    setup : tuple
        ``(settings, options, hybrid)`` (:func:`lacore.reconstruction.settings.split_options`).

    Every chain starts from the anchors and continues from its own frames.  :meth:`collect`
    hands finished frames to a callback ``record(index, result, seconds, (max length error,
    max angle error), warm-start time)``; :meth:`close` kills the processes still running
    (cancel, error).
    """

    def __init__(self, chains, z_targets, topology, reference_vertices, times, anchors, method, warm_start, tree,
                 setup):
        self._chains = [np.asarray(c) for c in chains]
        self._messages = queue.Queue()
        self._open = set()
        self._workers = []
        Zt, times = np.asarray(z_targets, float), np.asarray(times, float)
        anchors = [(float(t), np.asarray(X, float)) for t, X in (anchors or [])]
        try:
            for tag, chain in enumerate(self._chains):
                job = (Zt[chain], topology, reference_vertices, times[chain], anchors, method, warm_start, tree, setup)
                self._workers.append(WorkerProcess(_project_chain, job, tag=tag, messages=self._messages))
                self._open.add(tag)
        except BaseException:
            self.close()
            raise

    @property
    def finished(self):
        """Whether every worker has sent all its frames."""
        return not self._open

    def collect(self, record, block, limit=None):
        """Record the frames the workers sent; returns how many.

        ``block=False``: only those already there; ``block=True``: wait until every
        worker is done, or until ``limit`` frames were recorded.  A worker's error is
        raised here (:func:`lacore.parallel.raise_worker_error`) after closing all.
        """
        count = 0
        while self._open and (limit is None or count < limit):
            try:
                tag, kind, payload = self._messages.get(block=block)
            except queue.Empty:
                break
            if kind == "message":
                j, res, sec, errors, warm_time = payload
                record(int(self._chains[tag][j]), res, sec, errors, warm_time)
                count += 1
            elif kind == "done":
                self._open.discard(tag)
            else:
                self.close()
                raise_worker_error(payload)
        return count

    def close(self):
        """Kill the worker processes still running (idempotent)."""
        for worker in self._workers:
            worker.close()
        self._open.clear()


def _reference(Xs, reference, reference_vertices, topology):
    if reference_vertices is not None:
        return check_vertices(reference_vertices, topology.n_vertices, name="reference_vertices")
    if int(reference) != reference or not 0 <= reference < len(Xs):
        raise InputError(f"reference must be the index of one of the {len(Xs)} shapes, got {reference!r}")
    X = Xs[int(reference)]
    if X is None:
        raise InputError(f"shape {reference} (the reference) is given as lengths and angles: pass "
                         "reference_vertices, or give it as a vertex array")
    return X


def _run(shapes, topology, times, keyframes, smooth, bc_type, method, reference, reference_vertices, warm_start,
         tree, setup, progress, on_frame=None, workers=1):
    t_start = time.perf_counter()
    z_keys, Xs = shapes_to_z(shapes, topology)
    k = check_keyframes(keyframes, len(z_keys))
    if smooth:
        targets = spline_z(z_keys, k, times, bc_type=bc_type)
    else:
        targets = piecewise_linear_z(z_keys, k, times)
    X_ref = _reference(Xs, reference, reference_vertices, topology)
    anchors = [(float(kt), X) for kt, X in zip(k, Xs, strict=True) if X is not None]
    return _project(targets, topology, X_ref, times, anchors, method, warm_start, tree, z_keys, setup, progress,
                    keyframes=k, smooth=smooth, t_start=t_start, on_frame=on_frame, workers=workers)


def interpolate(shapes, topology, factors, keyframes=None, method=None, reference=0, reference_vertices=None,
                warm_start=True, tree=None, *, settings=None, options=None, hybrid=None, progress=None,
                on_frame=None, workers=1, **reconstruct_kw):
    """Interpolate or extrapolate shapes linearly in lengths and angles, then project (4.9), (4.10).

    Parameters
    ----------
    shapes : sequence of K >= 2 shapes
        ``(V, 3)`` vertex arrays in dense correspondence and/or ``(2E,)``
        lengths-and-angles vectors; or one array ``(K, V, 3)`` / ``(K, 2E)``.
    topology : MeshTopology
    factors : float or (N,) array_like
        Frame times in keyframe-time units.  With the default keyframes
        ``0..K-1`` and two shapes, ``t`` in ``[0, 1]`` interpolates and ``t < 0``
        or ``t > 1`` extrapolates; with more shapes the path is piecewise
        linear in ``z`` and extended linearly beyond the end keyframes.
    keyframes : (K,) array_like, optional
        Strictly increasing times of the shapes (default ``0..K-1``).
    method : {None, "fast", "gn", "hybrid", "bfs", "mst", "spt", "lsq"}
        Projection by reconstruction (as in :func:`project_targets`); None (default):
        :data:`~lacore.reconstruction.settings.DEFAULT_PROJECTION`, the preset
        ``"fast"`` (continuation along ``t``, one Gauss-Newton step per frame);
        ``"gn"`` is the energy-based projection (Def. 4.3) run to convergence from
        the same warm starts; the frame-based methods share one preassembled
        spanning tree.
    reference : int
        Index of the shape defining the weights of ``W_q``, the fixed triangle and
        the output frame (default 0).
    reference_vertices : (V, 3) array_like, optional
        An explicit reference shape instead (needed if shape ``reference`` is given as ``z``).
    warm_start : {True, "secant", "nearest", False}
        Warm-start every Gauss-Newton projection from the extrapolation through
        the two nearest known shapes on one side (``True`` = ``"secant"``,
        :func:`predicted_start`), from the nearest known shape (``"nearest"``),
        or (False) from the reference shape (see the module docstring).
    tree : DualSpanningTree, optional
        Spanning tree for the frame-based methods (default preassembled from the shapes).
    settings, options, hybrid : optional
        :class:`~lacore.reconstruction.ReconstructionSettings`,
        :class:`~lacore.reconstruction.GaussNewtonOptions`,
        :class:`~lacore.reconstruction.HybridOptions` of the projection.
    progress : callable, optional
        ``progress(done, total, message)`` after every frame (:mod:`lacore.progress`);
        returning True stops with :class:`lacore.progress.Cancelled`.
    on_frame : callable, optional
        ``on_frame(index, result)`` as soon as the frame ``index`` (position in
        the given times) is projected, with its
        :class:`~lacore.reconstruction.ReconstructionResult` (frames finish in
        time order, with ``workers > 1`` chain by chain, interleaved): stream
        results to disk as they finish.
    workers : int
        Chains of frames computed side by side (:mod:`lacore.parallel`): this
        process computes the first, ``workers - 1`` worker processes the others
        (default 1: all frames here, in increasing time).  Each chain starts
        next to a key and continues from its own frames; each worker builds its
        own solver (about 4 s and one more solver's memory at 50k vertices),
        so it pays for long runs of frames of large meshes.
        :func:`lacore.parallel.default_workers` tells how many cores there are.
        A worker that cannot start or dies raises
        :class:`lacore.parallel.WorkerError` (the add-on then computes its
        frames itself); an input error in a worker is raised as itself.
    **reconstruct_kw
        The fields of these objects as keywords (``energy, weights,
        bending_weight, fixed_face, fix_triangle_shape, solver, hybrid_start,
        hybrid_kind, smoothing_iterations`` and Gauss-Newton options of
        :func:`lacore.reconstruction.reconstruct`).

    Returns
    -------
    InterpolationResult
        ``vertices (N, V, 3)`` in the reference's frame, ``z_targets (N, 2E)`` and
        per-frame ``energy, iterations, seconds, max_length_error, max_angle_error``.

    Raises
    ------
    ValueError
        Fewer than 2 shapes, keyframes not matching the shapes or not strictly
        increasing, NaN factors, unknown method.
    MeshError
        Shapes with different vertex counts.
    LengthsAnglesError
        A target with non-positive lengths (extrapolated too far) or one that
        violates the triangle inequality at most faces.
    """
    times = _check_times(factors, "factors")
    method, options, hybrid = projection_preset(method, options, hybrid)
    setup = split_options(reconstruct_kw, settings, options, hybrid, caller="interpolate")[:3]
    return _run(shapes, topology, times, keyframes, False, None, method, reference, reference_vertices,
                warm_start, tree, setup, progress, on_frame, workers)


def keyframe_inbetweens(shapes, topology, keyframes, frames=None, smooth=False, bc_type="natural", method=None,
                        reference=0, reference_vertices=None, warm_start=True, tree=None, *, settings=None,
                        options=None, hybrid=None, progress=None, on_frame=None, workers=1, **reconstruct_kw):
    """In-between frames of keyed shapes, piecewise linear or cubic spline in lengths and angles.

    Parameters
    ----------
    shapes : sequence of K >= 2 shapes
        See :func:`interpolate`.
    topology : MeshTopology
    keyframes : (K,) array_like
        Strictly increasing frame numbers of the shapes (need not be evenly spaced).
    frames : (N,) array_like, optional
        Frames to produce; default every integer frame from the first to the
        last keyframe.  A frame equal to a keyframe reproduces that shape (up to
        rigid motion; its ``z`` exactly up to the solver tolerance).
    smooth : bool
        False: piecewise linear in ``z`` (:func:`piecewise_linear_z`); True: cubic
        spline in ``z`` through the keyframes (:func:`spline_z`).
    bc_type : str
        Spline boundary condition, default ``"natural"``.
    method, reference, reference_vertices, warm_start, tree, settings, options, hybrid, progress, on_frame
        As in :func:`interpolate`.
    workers, **reconstruct_kw
        As in :func:`interpolate`.

    Returns
    -------
    InterpolationResult
        ``times`` are the frame numbers.
    """
    if keyframes is None:
        raise InputError("keyframe_inbetweens needs the keyframe numbers of the shapes")
    k = np.asarray(keyframes, dtype=float)
    if frames is None:
        kk = check_keyframes(k, len(k))
        frames = np.arange(np.ceil(kk[0]), np.floor(kk[-1]) + 1.0)
    times = _check_times(frames, "frames")
    method, options, hybrid = projection_preset(method, options, hybrid)
    setup = split_options(reconstruct_kw, settings, options, hybrid, caller="keyframe_inbetweens")[:3]
    return _run(shapes, topology, times, keyframes, bool(smooth), bc_type, method, reference, reference_vertices,
                warm_start, tree, setup, progress, on_frame, workers)
