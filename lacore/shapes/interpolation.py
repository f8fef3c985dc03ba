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
(4.10), ``P_Z[z~] = Z[R[z~]]``, frame by frame in
:class:`lacore.shapes.projection.SequenceProjection`.  Without a method the projection is
:data:`lacore.reconstruction.settings.DEFAULT_PROJECTION` (the preset ``"fast"``:
continuation along ``t`` and one Gauss-Newton step per frame, the default of the CLI
and the Blender add-on too); ``method="gn"`` is the energy-based projection of
Definition 4.3 run to convergence.  One shared set-up, warm starts
continuing along ``t`` from the input shapes given as vertices (at their keyframe
times) and the computed frames (``warm_start="secant"``, the default, also ``True``;
``"nearest"``; ``False``: cold starts), chains of frames side by side in worker
processes (``workers``), and for the frame-based methods one spanning tree
preassembled from the keyframe samples ``z_k``.

All frames are returned in the frame of the reference shape (``reference``,
default the first): the fixed triangle of the reconstruction sits exactly
where the reference shape has it, so an animation made of the frames does not
jump.
"""

import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import InputError, LengthsAnglesError, MeshError, as_float_array
from ..geometry.lengths_angles import check_z, lengths_and_angles, wrap_angle
from ..geometry.topology import MeshTopology, check_vertices
from ..linalg.heap import retained_heap
from ..reconstruction import reconstruction_errors
from ..result import SolverResult
from .projection import SequenceProjection, check_times, projection_options

__all__ = [
    "PATH",
    "path_frames",
    "InterpolationResult",
    "interpolate",
    "keyframe_inbetweens",
    "project_targets",
    "sequence_result",
    "shapes_to_z",
    "check_keyframes",
    "keyframe_targets",
    "piecewise_linear_z",
    "spline_z",
    "lift_angles",
]


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
    indicator : (N,) ndarray or None
        ``method="path"``: the error estimate of every frame (RMS distance to the projection over the frame's
        own size, :func:`lacore.shapes.mixing.path_inbetweens`); None for the other methods.
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
    indicator: np.ndarray | None = None

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
    InputError
        Entries that are no numbers, a count different from the number of shapes, NaN/inf, or times that are
        not strictly increasing.
    """
    if keyframes is None:
        return np.arange(n_shapes, dtype=float)
    k = as_float_array(keyframes, "keyframes")
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


# --------------------------------------------------------------------------- targets
def lift_angles(z_keys):
    """Keys ``(K, 2E)`` whose angles differ from the previous key's by at most ``pi``: each moved by a multiple of
    ``2 pi`` (lengths unchanged), so that a blend of keys turns every edge the short way round the circle.

    An edge folded to ``3.1`` in one key and ``-3.1`` in the next stays folded between them (``pi``), instead of
    opening through 0.  The keys are returned as they are when no angle needs moving.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.shapes.interpolation import lift_angles
    >>> print(lift_angles(np.array([[1.0, 3.1], [1.0, -3.1]]))[:, 1].round(6))
    [3.1      3.183185]
    """
    Z = np.asarray(z_keys, float)
    E = Z.shape[1] // 2
    turn = np.diff(Z[:, E:], axis=0)
    step = wrap_angle(turn) - turn
    if not step.any():
        return Z
    out = Z.copy()
    out[1:, E:] += np.cumsum(step, axis=0)
    return out


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
        last keyframe, where ``u < 0`` resp. ``u > 1`` extrapolates); angles on the
        circle (:func:`lift_angles`, then wrapped to ``(-pi, pi]``).
    """
    Z0 = np.asarray(z_keys, float)
    Z = lift_angles(Z0)
    k = np.asarray(keyframes, float)
    t = np.atleast_1d(np.asarray(times, float))
    s = np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2)
    u = (t - k[s]) / (k[s + 1] - k[s])
    # row by row into one output array: no (N, 2E) temporaries (at 50k vertices and 10 times each is 23 MB)
    # (the same arithmetic as (1 - u) z_s + u z_{s+1} on whole arrays, bit for bit)
    out, row = np.empty((len(t), Z.shape[1])), np.empty(Z.shape[1])
    for i, (si, ui) in enumerate(zip(s.tolist(), u.tolist(), strict=True)):
        np.multiply(Z[si], 1.0 - ui, out=out[i])
        np.multiply(Z[si + 1], ui, out=row)
        out[i] += row
    if Z is not Z0:
        E = Z.shape[1] // 2
        out[:, E:] = wrap_angle(out[:, E:])
    # exact keyframe values (no round-off from 1 - u)
    hit = np.searchsorted(k, t)
    exact = (hit < len(k)) & (k[np.minimum(hit, len(k) - 1)] == t)
    out[exact] = Z0[hit[exact]]
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
        Angles on the circle (:func:`lift_angles`, then wrapped to ``(-pi, pi]``).

    Raises
    ------
    InputError
        A ``bc_type`` that :class:`~scipy.interpolate.CubicSpline` does not take, or ``"periodic"`` with a last
        key that is not the first (also with ``K = 2``, where the spline is not built).
    """
    Z0 = np.asarray(z_keys, float)
    k = np.asarray(keyframes, float)
    t = np.atleast_1d(np.asarray(times, float))
    Z = lift_angles(Z0)
    try:  # built with two keys too, where only its check of bc_type is used
        S = CubicSpline(k, Z, axis=0, bc_type=bc_type)
    except (TypeError, ValueError) as exc:
        raise InputError(f"bc_type={bc_type!r} does not fit the cubic spline: {str(exc).rstrip('.')}; use "
                         "'natural' (the default), 'not-a-knot', 'clamped', or 'periodic' when the last key "
                         "repeats the first") from None
    if len(k) == 2:
        return piecewise_linear_z(Z0, k, t)
    out = S(np.clip(t, k[0], k[-1]))
    for end, mask in ((k[0], t < k[0]), (k[-1], t > k[-1])):
        if np.any(mask):
            out[mask] = S(end)[None] + (t[mask] - end)[:, None] * S(end, 1)[None]
    if Z is not Z0:
        E = Z.shape[1] // 2
        out[:, E:] = wrap_angle(out[:, E:])
    hit = np.searchsorted(k, t)
    exact = (hit < len(k)) & (k[np.minimum(hit, len(k) - 1)] == t)
    out[exact] = Z0[hit[exact]]
    return out


# --------------------------------------------------------------------------- projection of many frames
def project_targets(z_targets, topology, reference_vertices, times=None, anchors=None, method=None,
                    warm_start=True, tree=None, z_keys=None, *, settings=None, options=None, hybrid=None,
                    progress=None, on_frame=None, workers=1, **reconstruct_kw):
    """Project many targets onto the admissible set with shared set-up and warm starts (4.10).

    Runs :class:`lacore.shapes.projection.SequenceProjection` to the end (step that object
    yourself to compute one frame at a time, e.g. from an event loop).

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
        neighbours in time (``True`` / ``"secant"``, :func:`~lacore.shapes.projection.predicted_start`), from
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

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import lengths_and_angles
    >>> from lacore.shapes.interpolation import project_targets
    >>> z0, z1 = lengths_and_angles(bar_pose(X, 0.5, 0.0), topo), lengths_and_angles(bar_pose(X, 0.0, 0.5), topo)
    >>> targets = [(1 - t) * z0 + t * z1 for t in (0.25, 0.5, 0.75)]
    >>> res = project_targets(targets, topo, X, times=[0.25, 0.5, 0.75], anchors=[(0.0, bar_pose(X, 0.5, 0.0))])
    >>> bool(res.success), res.warm_start_times.tolist()
    (True, [0.0, 0.25, 0.5])
    """
    t_start = time.perf_counter()
    opts = projection_options(method, warm_start, tree, settings, options, hybrid, reconstruct_kw, "project_targets")
    run = SequenceProjection(z_targets, topology, reference_vertices, times, anchors, opts, samples=z_keys,
                             workers=workers)
    return sequence_result(run.run(progress, on_frame), t_start)


def sequence_result(run, t_start, keyframes=None, smooth=False):
    """The :class:`InterpolationResult` of a finished :class:`~lacore.shapes.projection.SequenceProjection`
    (``t_start``: :func:`time.perf_counter` when the call began)."""
    tg = run.targets
    N, V = run.total, tg.topology.n_vertices
    vertices = np.empty((N, V, 3))
    energy, seconds = np.empty(N), np.empty(N)
    iterations, status = np.zeros(N, np.int64), np.zeros(N, np.int64)
    max_len, max_ang, warm_times = np.empty(N), np.empty(N), np.full(N, np.nan)
    results = []
    for i, frame in enumerate(run.frames):
        res = frame.result
        vertices[i] = res.vertices
        energy[i], seconds[i], iterations[i], status[i] = res.energy, frame.seconds, res.iterations, res.status
        max_len[i], max_ang[i], warm_times[i] = frame.max_length_error, frame.max_angle_error, frame.warm_start_time
        results.append(res)
    success = all(r.success for r in results)
    failed = [float(tg.times[i]) for i in range(N) if not results[i].success]
    first = next((r for r in results if not r.success), None)
    message = "all frames projected" if success else (f"projection failed its checks at t = {failed} "
                                                      f"(first: {first.failure}: {first.message})")
    total = time.perf_counter() - t_start
    return InterpolationResult(
        vertices=vertices, times=tg.times, z_targets=tg.z_targets, energy=energy, iterations=iterations,
        seconds=seconds, max_length_error=max_len, max_angle_error=max_ang, status=status,
        warm_start_times=warm_times, order=run.order, reconstructions=results, context=run.context, tree=run.tree,
        method=run.options.method, success=bool(success), message=message, keyframes=keyframes, smooth=bool(smooth),
        timings={"total": total}, total_seconds=total, total_iterations=int(iterations.sum()),
        workers=len(run.chains) if run.chains is not None else 1)


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


def keyframe_targets(z_keys, keyframes, times, smooth=False, bc_type="natural"):
    """Targets ``z~(t)`` at ``times``: :func:`spline_z` (``smooth``) or :func:`piecewise_linear_z` of the keys.

    Examples
    --------
    >>> keyframe_targets([[1.0, 0.0], [3.0, 2.0]], [0.0, 1.0], [0.5, 2.0]).tolist()
    [[2.0, 1.0], [5.0, 4.0]]
    """
    if smooth:
        return spline_z(z_keys, keyframes, times, bc_type=bc_type)
    return piecewise_linear_z(z_keys, keyframes, times)


def _run(shapes, topology, times, keyframes, smooth, bc_type, reference, reference_vertices, opts, progress,
         on_frame, workers, mixer=None, path_options=None):
    t_start = time.perf_counter()
    z_keys, Xs = shapes_to_z(shapes, topology)
    k = check_keyframes(keyframes, len(z_keys))
    if mixer is not None:
        return _mixer_run(mixer, z_keys, k, times, smooth, bc_type, reference, reference_vertices, progress, on_frame,
                          t_start)
    with retained_heap():  # every frame's factorizations on one heap (lacore.linalg.heap)
        if opts is PATH:
            return _path_run(Xs, topology, z_keys, k, times, smooth, reference, reference_vertices, progress,
                             on_frame, t_start, path_options)
        targets = keyframe_targets(z_keys, k, times, smooth, bc_type)
        X_ref = _reference(Xs, reference, reference_vertices, topology)
        anchors = [(float(kt), X) for kt, X in zip(k, Xs, strict=True) if X is not None]
        run = SequenceProjection(targets, topology, X_ref, times, anchors, opts, samples=z_keys, workers=workers)
        return sequence_result(run.run(progress, on_frame), t_start, keyframes=k, smooth=smooth)


def _mixer_run(mixer, z_keys, keyframes, times, smooth, bc_type, reference, reference_vertices, progress, on_frame,
               t_start):
    """The frames by a :class:`~lacore.shapes.mixing.ShapeMixer` of the same keys: the targets are linear in the keys'
    lengths and angles (``z~(t) = sum_k a_k(t) z_k`` with ``sum_k a_k = 1``), i.e. the mixer's blend with weights
    ``a_1(t) .. a_{K-1}(t)``; each frame is one warm-started mix."""
    from ..progress import report
    from .mixing import ShapeMixer

    if not isinstance(mixer, ShapeMixer):
        raise InputError(f"mixer must be a ShapeMixer, got {type(mixer).__name__}")
    K = len(z_keys)
    E = mixer.n_edges
    same = (mixer.n_keys == K and mixer.z_keys.shape == z_keys.shape
            and np.allclose(mixer.z_keys[:, :E], z_keys[:, :E], rtol=1e-9, atol=0.0)
            and np.allclose(mixer.z_keys[:, E:], z_keys[:, E:], rtol=0.0, atol=1e-9))
    if not same:
        raise InputError("the mixer was built from other keys than these shapes: build it from the shapes, in "
                         "order, or interpolate without it")
    derived = np.flatnonzero(mixer.derived_keys) + 1
    if derived.size:
        raise InputError(f"the mixer blends key {derived[0]} with a mask or relative to another key, not the shape "
                         "itself: in-betweens of the shapes need a mixer of unmasked keys relative to the basis, or "
                         "none")
    if reference != 0 or reference_vertices is not None:
        raise InputError("with a mixer the reference is its basis, shape 0: leave reference and reference_vertices "
                         "at their defaults")
    coefficients = keyframe_targets(np.eye(K), keyframes, times, smooth, bc_type)   # (N, K), rows sum to 1
    targets = keyframe_targets(z_keys, keyframes, times, smooth, bc_type)
    N, V = len(times), mixer.n_vertices
    vertices = np.empty((N, V, 3))
    energy, seconds, iterations = np.empty(N), np.empty(N), np.zeros(N, np.int64)
    max_len, max_ang = np.empty(N), np.empty(N)
    off = []
    for i in range(N):
        report(progress, i, N, f"frame {i + 1} of {N}")
        r = mixer.mix(coefficients[i, 1:])
        vertices[i], energy[i], seconds[i], iterations[i] = r.vertices, r.energy, r.seconds, r.iterations
        errors = reconstruction_errors(r.vertices, targets[i], mixer.topology)
        max_len[i], max_ang[i] = errors["max_length_error"], errors["max_angle_error"]
        if not r.in_range:
            off.append((float(times[i]), r.message))
        if on_frame is not None:
            on_frame(i, r)
    report(progress, N, N, "done")
    total = time.perf_counter() - t_start
    message = "all frames mixed" if not off else (f"{len(off)} frames outside the mixer's accurate range (first: "
                                                  f"t = {off[0][0]:g}: {off[0][1]})")
    return InterpolationResult(
        vertices=vertices, times=np.asarray(times, float), z_targets=targets, energy=energy, iterations=iterations,
        seconds=seconds, max_length_error=max_len, max_angle_error=max_ang, status=np.zeros(N, np.int64),
        warm_start_times=np.r_[np.nan, np.asarray(times, float)[:-1]], order=np.arange(N), reconstructions=[],
        context=mixer._context, method="mixer", success=not off, message=message, keyframes=keyframes,
        smooth=bool(smooth), timings={"total": total}, total_seconds=total, total_iterations=int(iterations.sum()))


#: ``method="path"`` of :func:`interpolate` and :func:`keyframe_inbetweens`: every segment between two keys by a
#: reduced model of its path (:func:`lacore.shapes.mixing.path_inbetweens`).
PATH = "path"


def _path_run(Xs, topology, z_keys, keyframes, times, smooth, reference, reference_vertices, progress, on_frame,
              t_start, path_options):
    """The frames segment by segment by :func:`~lacore.shapes.mixing.path_inbetweens` (piecewise linear only).

    A segment's energy weights are those of its first key (for two shapes: the reference's); the frames are moved
    into the frame of the reference shape."""
    from ..reconstruction import get_context
    from .mixing.path import path_inbetweens

    if smooth:
        raise InputError("method 'path' follows straight segments between two keys: use it without the cubic "
                         "spline, or another method")
    if any(X is None for X in Xs):
        raise InputError("method 'path' needs every shape as vertices, not as lengths and angles")
    if reference_vertices is not None:
        raise InputError("method 'path': leave reference_vertices out (the reference is one of the shapes)")
    X_ref = Xs[int(reference)]
    out_ctx = get_context(topology, X_ref)
    k = np.asarray(keyframes, float)
    T = np.asarray(times, float)
    seg = np.clip(np.searchsorted(k, T, side="right") - 1, 0, len(k) - 2)
    N = len(T)
    vertices = np.empty((N, topology.n_vertices, 3))
    energy, indicator, seconds = np.empty(N), np.empty(N), np.empty(N)
    timings, messages, ok = {}, [], True
    done = 0
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        u = (T[idx] - k[s]) / (k[s + 1] - k[s])
        n = len(idx)

        def part(d, total, msg, base=done, n=n):
            return progress(base + (n * d) // max(total, 1), N, msg)
        res = path_inbetweens(Xs[s], Xs[s + 1], topology, u, path_options, progress=part if progress else None)
        V = res.vertices if int(reference) == s else np.array([out_ctx.align(X) for X in res.vertices])
        vertices[idx], energy[idx], indicator[idx] = V, res.energy, res.indicator
        seconds[idx] = res.seconds["total"] / len(idx)
        for name, v in res.seconds.items():
            timings[name] = timings.get(name, 0.0) + v
        ok &= bool(res.success)
        if res.message:
            messages.append(f"keys {s}-{s + 1}: {res.message}")
        done += len(idx)
        if on_frame is not None:
            for j, i in enumerate(idx):
                on_frame(int(i), SimpleNamespace(vertices=V[j], energy=float(res.energy[j]),
                                                 indicator=float(res.indicator[j]), success=bool(res.success)))
    targets = keyframe_targets(z_keys, keyframes, times, False)
    errors = [reconstruction_errors(X, z, topology) for X, z in zip(vertices, targets, strict=True)]
    total = time.perf_counter() - t_start
    timings["total"] = total
    return InterpolationResult(
        vertices=vertices, times=T, z_targets=targets, energy=energy, iterations=np.zeros(N, np.int64),
        seconds=seconds, max_length_error=np.array([e["max_length_error"] for e in errors]),
        max_angle_error=np.array([e["max_angle_error"] for e in errors]), status=np.zeros(N, np.int64),
        warm_start_times=np.full(N, np.nan), order=np.arange(N), reconstructions=[], context=out_ctx, method=PATH,
        success=ok, message="; ".join(messages) or "all frames within the path tolerance", keyframes=keyframes,
        smooth=False, timings=timings, total_seconds=total, total_iterations=0, indicator=indicator)


def interpolate(shapes, topology, factors, keyframes=None, method=None, reference=0, reference_vertices=None,
                warm_start=True, tree=None, *, settings=None, options=None, hybrid=None, progress=None,
                on_frame=None, workers=1, mixer=None, **reconstruct_kw):
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
    method : {None, "fast", "gn", "hybrid", "bfs", "mst", "spt", "lsq", "path"}
        Projection by reconstruction (as in :func:`project_targets`); None (default):
        :data:`~lacore.reconstruction.settings.DEFAULT_PROJECTION`, the preset
        ``"fast"`` (continuation along ``t``, one Gauss-Newton step per frame);
        ``"gn"`` is the energy-based projection (Def. 4.3) run to convergence from
        the same warm starts; the frame-based methods share one preassembled
        spanning tree.  ``"path"``: every segment between two keys by a reduced model of
        its path (:func:`lacore.shapes.mixing.path_inbetweens`: two or three sparse
        factorizations per segment whatever the number of frames, each frame with an error
        estimate in ``indicator``, full Gauss-Newton where the estimate is above its
        tolerance); ``options`` is then a :class:`~lacore.shapes.mixing.PathOptions`,
        ``warm_start``, ``tree``, ``hybrid`` and ``workers`` do not apply, and ``on_frame``
        gets an object with ``vertices, energy, indicator, success`` (after its segment).
    reference : int
        Index of the shape defining the weights of ``W_q``, the fixed triangle and
        the output frame (default 0).
    reference_vertices : (V, 3) array_like, optional
        An explicit reference shape instead (needed if shape ``reference`` is given as ``z``).
    warm_start : {True, "secant", "nearest", False}
        Warm-start every Gauss-Newton projection from the extrapolation through
        the two nearest known shapes on one side (``True`` = ``"secant"``,
        :func:`~lacore.shapes.projection.predicted_start`), from the nearest known shape (``"nearest"``),
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
        own solver (seconds and one more solver's memory for a large mesh),
        so it pays for long runs of frames of large meshes.
        :func:`lacore.parallel.default_workers` tells how many cores there are.
        A worker that cannot start or dies raises
        :class:`lacore.parallel.WorkerError` (the add-on then computes its
        frames itself); an input error in a worker is raised as itself.
    mixer : ShapeMixer, optional
        A :class:`~lacore.shapes.mixing.ShapeMixer` built from these shapes (in this order,
        the reference shape 0 its basis): every frame is one warm-started reduced mix
        (milliseconds) instead of a projection; ``method``, ``warm_start``, ``tree``, the
        options and ``workers`` do not apply, ``on_frame`` gets the
        :class:`~lacore.shapes.mixing.MixResult`, ``method`` of the result is ``"mixer"``,
        ``energy`` the mixer's estimate, ``reconstructions`` empty, and ``success`` False
        when a frame leaves the mixer's accurate range (``message`` says which).
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

    Examples
    --------
    Half-way between a bent and a twisted bar, and one step beyond the twist:

    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import interpolate, lengths_and_angles
    >>> res = interpolate([bar_pose(X, 0.5, 0.0), bar_pose(X, 0.0, 0.5)], topo, [0.5, 1.5])
    >>> res.vertices.shape, bool(res.success)
    ((2, 22, 3), True)
    >>> size = np.linalg.norm(np.ptp(X, axis=0))      # the blend is not admissible: small length errors
    >>> bool(np.all((0 < res.max_length_error) & (res.max_length_error < 1e-3 * size)))
    True
    """
    times = check_times(factors, "factors")
    if method == PATH:
        return _run(shapes, topology, times, keyframes, False, None, reference, reference_vertices, PATH, progress,
                    on_frame, workers, mixer, _path_options(options, settings, reconstruct_kw))
    opts = projection_options(method, warm_start, tree, settings, options, hybrid, reconstruct_kw, "interpolate",
                              also=(PATH,))
    return _run(shapes, topology, times, keyframes, False, None, reference, reference_vertices, opts, progress,
                on_frame, workers, mixer)


def path_frames(shapes, faces, keyframes, frames, options=None, *, progress=None):
    """:func:`keyframe_inbetweens` with ``method="path"`` from plain arrays, returning plain arrays (what a worker
    process of :func:`lacore.parallel.call_in_process` sends and returns).

    Parameters
    ----------
    shapes : (K, V, 3) array_like
    faces : (F, 3) int array_like
    keyframes, frames : array_like
    options : PathOptions, optional
    progress : callable, optional

    Returns
    -------
    vertices : (N, V, 3) ndarray
    indicator : (N,) ndarray
    success : bool
    message : str
    """
    X = np.asarray(shapes, float)
    topology = MeshTopology.from_faces(np.asarray(faces, np.int64), n_vertices=X.shape[1])
    res = keyframe_inbetweens(X, topology, keyframes, frames, method=PATH, options=options, progress=progress)
    return res.vertices, res.indicator, bool(res.success), res.message


def _path_options(options, settings, reconstruct_kw):
    """The :class:`~lacore.shapes.mixing.PathOptions` of ``method="path"``: ``options`` when it is one (else
    the defaults), with the bending weight of ``settings`` / ``bending_weight=``; other settings do not apply."""
    from dataclasses import replace

    from .mixing.path import PathOptions

    kw = dict(reconstruct_kw)
    eta = kw.pop("bending_weight", None)
    if settings is not None and eta is None:
        eta = settings.bending_weight
    if kw:
        raise InputError(f"method 'path' does not take {', '.join(sorted(kw))}")
    if options is not None and not isinstance(options, PathOptions):
        raise InputError(f"method 'path' takes PathOptions as options, got {type(options).__name__}")
    o = options or PathOptions()
    return o if eta is None else replace(o, bending_weight=float(eta))


def keyframe_inbetweens(shapes, topology, keyframes, frames=None, smooth=False, bc_type="natural", method=None,
                        reference=0, reference_vertices=None, warm_start=True, tree=None, *, settings=None,
                        options=None, hybrid=None, progress=None, on_frame=None, workers=1, mixer=None,
                        **reconstruct_kw):
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
    workers, mixer, **reconstruct_kw
        As in :func:`interpolate`.

    Returns
    -------
    InterpolationResult
        ``times`` are the frame numbers.

    Examples
    --------
    Shapes keyed at frames 0, 4 and 8, the frames between them by a cubic spline in ``z``:

    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import keyframe_inbetweens
    >>> keys = [X, bar_pose(X, 0.5, 0.0), bar_pose(X, 0.5, 0.5)]
    >>> res = keyframe_inbetweens(keys, topo, [0, 4, 8], smooth=True)
    >>> res.times.tolist(), res.vertices.shape
    ([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0], (9, 22, 3))
    """
    if keyframes is None:
        raise InputError("keyframe_inbetweens needs the keyframe numbers of the shapes")
    k = as_float_array(keyframes, "keyframes")
    if frames is None:
        kk = check_keyframes(k, len(k))
        frames = np.arange(np.ceil(kk[0]), np.floor(kk[-1]) + 1.0)
    times = check_times(frames, "frames")
    if method == PATH:
        return _run(shapes, topology, times, keyframes, bool(smooth), bc_type, reference, reference_vertices, PATH,
                    progress, on_frame, workers, mixer, _path_options(options, settings, reconstruct_kw))
    opts = projection_options(method, warm_start, tree, settings, options, hybrid, reconstruct_kw,
                              "keyframe_inbetweens", also=(PATH,))
    return _run(shapes, topology, times, keyframes, bool(smooth), bc_type, reference, reference_vertices, opts,
                progress, on_frame, workers, mixer)
