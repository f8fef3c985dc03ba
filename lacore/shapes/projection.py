"""Projection of lengths and angles onto the admissible set (thesis 4.2, Definitions 4.3 and 4.4, eq. 4.10).

Working in the ambient space ``R^{2E}`` (e.g. linear interpolation or
extrapolation of lengths and angles, section 4.2) produces vectors ``z~`` that
are in general not admissible.  A projection maps them back onto ``Z``:

* energy-based projection (Def. 4.3, (4.7)), the default::

      P_Z^W[z~] = Z[ argmin_X W[z~, Z[X]] ]

  i.e. ``Z`` of the Gauss-Newton reconstruction (``method="gn"``);
* projection by reconstruction (Def. 4.4, (4.8)) for any other reconstruction
  method ``R``: ``P_Z^R[z~] = Z[R[z~]]``.

For admissible ``z`` both return ``z`` up to round-off (``P_Z[z] = z``).

One target: :func:`project`.  A sequence of targets at times ``t`` (the frames of
an interpolation, 4.10): :class:`SequenceProjection`, the one projection loop of
lacore, computing ONE FRAME PER :meth:`SequenceProjection.step` (callers with an
event loop, such as the Blender add-on, step it; :meth:`SequenceProjection.run`
steps to the end).  It shares the set-up between frames and continues along ``t``:

* one :class:`~lacore.reconstruction.ReconstructionContext` (weights, fixed face,
  Gauss-Newton pattern, symbolic Cholesky factorization) made for the reference
  shape serves every frame;
* frames are processed in *chains* of consecutive times
  (:func:`lacore.parallel.frame_chains`), each starting next to a known shape (an
  *anchor*, e.g. an input key); a Gauss-Newton projection (``"gn"``, and
  ``"hybrid"`` with ``start="given"``) starts from :func:`predicted_start`
  through the known shapes: the anchors and the chain's own finished frames
  (continuation along ``t``: the error of the secant start is second order in the
  frame spacing, so one or two Gauss-Newton steps finish a frame);
* frame-based methods (``"bfs"``, ``"mst"``, ``"spt"``) walk one spanning tree
  preassembled from samples (remark after Algorithm 2);
* with ``workers > 1`` the first chain is computed in this process and every other
  one in a worker process (:class:`ChainWorkers`, :mod:`lacore.parallel`), which
  runs this same loop on its chain.  Every chain depends only on the anchors and
  its own frames, so the result does not depend on timing.

Frames come out in the frame of the reference shape (the fixed triangle of the
reconstruction sits where the reference has it).
"""

import queue
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError, LengthsAnglesError, as_float_array
from ..geometry.lengths_angles import check_z, lengths_and_angles
from ..geometry.topology import check_vertices
from ..parallel import WorkerError, WorkerProcess, check_workers, frame_chains, raise_worker_error
from ..progress import Cancelled, report
from ..reconstruction import METHODS, get_context, reconstruct, reconstruction_errors, tree_kind
from ..reconstruction.settings import (PROJECTION_PRESETS, GaussNewtonOptions, HybridOptions, ReconstructionSettings,
                                       projection_preset, split_options)
from ..reconstruction.spanning_trees import bfs_tree, preassembled_tree

__all__ = ["project", "ProjectionOptions", "ProjectionTargets", "ProjectedFrame", "SequenceProjection",
           "ChainWorkers", "project_chain", "predicted_start", "check_times", "projection_options", "WARM_STARTS",
           "MAX_EXTRAPOLATION"]

#: Values of ``warm_start`` (besides ``True`` = ``"secant"`` and ``False`` = cold starts from the reference).
WARM_STARTS = ("secant", "nearest")

#: The secant prediction extrapolates at most this many times the spacing of the two shapes it goes through.
MAX_EXTRAPOLATION = 1.0


def project(z, topology, reference_vertices, method="gn", **reconstruct_kw):
    """Project lengths and angles onto the admissible set, ``P_Z[z~] = Z[R[z~]]`` (4.7), (4.8).

    Parameters
    ----------
    z : (2E,) array_like
        Lengths and angles ``z~`` to project.
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh of the reconstruction (weights of ``W_q``, start).
    method : str
        Reconstruction method, see :func:`lacore.reconstruction.reconstruct`;
        ``"gn"`` gives the energy-based projection (Def. 4.3).
    **reconstruct_kw
        Keyword arguments of :func:`~lacore.reconstruction.reconstruct`
        (``settings``, ``options``, ``hybrid``, ``initial_vertices``, ``context`` ...).

    Returns
    -------
    z_projected : (2E,) ndarray
        Admissible lengths and angles ``Z[R[z~]]``.
    result : ReconstructionResult
        The reconstruction (its ``vertices`` immerse ``z_projected``).

    Examples
    --------
    The average of the lengths and angles of a bent and a twisted bar is no mesh's; its projection is:

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import euler_integrability_map, project
    >>> bent, twisted = bar_pose(X, 0.5, 0.0), bar_pose(X, 0.0, 0.5)
    >>> z_mid = 0.5 * (lengths_and_angles(bent, topo) + lengths_and_angles(twisted, topo))
    >>> round(float(np.abs(euler_integrability_map(z_mid, topo)).max()), 4)
    0.0021
    >>> z_proj, result = project(z_mid, topo, X)
    >>> result.success, bool(np.abs(euler_integrability_map(z_proj, topo)).max() < 1e-10)
    (True, True)
    """
    result = reconstruct(z, topology, reference_vertices, method=method, **reconstruct_kw)
    return lengths_and_angles(result.vertices, topology), result


# --------------------------------------------------------------------------- what and how
def _warm_start_kind(warm_start):
    if warm_start is True:
        return "secant"
    if warm_start is False or warm_start is None:
        return None
    if warm_start not in WARM_STARTS:
        raise InputError(f"warm_start must be True, False or one of {', '.join(WARM_STARTS)}, got {warm_start!r}")
    return warm_start


@dataclass(frozen=True)
class ProjectionOptions:
    """How every frame of a :class:`SequenceProjection` is projected.

    Attributes
    ----------
    method : {"fast", "gn", "hybrid", "bfs", "mst", "spt", "lsq"}
        Reconstruction method (:func:`lacore.reconstruction.reconstruct`), or the name of a
        :class:`~lacore.reconstruction.settings.ProjectionPreset` (``"fast"``), whose options
        fill ``options`` and ``hybrid`` where they are not given.  Not given:
        :data:`~lacore.reconstruction.settings.DEFAULT_PROJECTION` (also the default of the
        interpolation functions, the CLI and the add-on).  Stored as the reconstruction method.
    warm_start : {"secant", "nearest", None}
        Start of a Gauss-Newton projection: :func:`predicted_start` through the
        known shapes (``"secant"``, also given as True), the nearest known shape
        (``"nearest"``) or the reference shape (None, also given as False).
    tree : DualSpanningTree or None
        Spanning tree of the frame-based methods (default: preassembled from samples).
    settings : ReconstructionSettings
        Defines the shared context.
    options : GaussNewtonOptions
        Default: the preset's, else the fields' defaults.
    hybrid : HybridOptions
        Default: the preset's, else the fields' defaults.

    Examples
    --------
    >>> from lacore.reconstruction import HybridOptions
    >>> ProjectionOptions(method="hybrid", hybrid=HybridOptions(start="given")).takes_start
    True
    >>> ProjectionOptions(warm_start=True).warm_start
    'secant'
    >>> fast = ProjectionOptions()                     # the default projection: the preset "fast"
    >>> fast.method, fast.hybrid.smoothing_iterations, ProjectionOptions("gn").options.ftol == 1e-9
    ('hybrid', 1, True)
    """

    method: str | None = None
    warm_start: object = "secant"
    tree: object = None
    settings: ReconstructionSettings = field(default_factory=ReconstructionSettings)
    options: GaussNewtonOptions | None = None
    hybrid: HybridOptions | None = None

    def __post_init__(self):
        method, options, hybrid = projection_preset(self.method, self.options, self.hybrid)
        object.__setattr__(self, "method", method)
        object.__setattr__(self, "options", GaussNewtonOptions() if options is None else options)
        object.__setattr__(self, "hybrid", HybridOptions() if hybrid is None else hybrid)
        if self.method not in METHODS:
            raise InputError(f"unknown projection method {self.method!r}; use one of "
                             f"{', '.join((*PROJECTION_PRESETS, *METHODS))}")
        object.__setattr__(self, "warm_start", _warm_start_kind(self.warm_start))

    @property
    def takes_start(self):
        """Whether the method starts from given vertices (so warm starts apply)."""
        return self.method == "gn" or (self.method == "hybrid" and self.hybrid.start == "given")


def projection_options(method=None, warm_start=True, tree=None, settings=None, options=None, hybrid=None,
                       keywords=None, caller="project_targets", also=()):
    """The :class:`ProjectionOptions` of the entry points' arguments: ``keywords`` are
    the flattened fields of ``settings``, ``options`` and ``hybrid``
    (:func:`lacore.reconstruction.settings.split_options`; ``caller`` is named for unknown ones); ``also``: the
    caller's methods besides the projections (named when ``method`` is none of them).

    Examples
    --------
    >>> projection_options("hybrid", keywords={"smoothing_iterations": 2}).hybrid.smoothing_iterations
    2

    An unknown method is named with the ones this caller takes:

    >>> try:
    ...     projection_options("fsat", caller="interpolate", also=("path",))
    ... except InputError as exc:
    ...     print(exc)
    unknown projection method 'fsat'; use one of fast, gn, bfs, mst, spt, lsq, hybrid, path
    """
    known = (*PROJECTION_PRESETS, *METHODS, *also)
    if method is not None and (not isinstance(method, str) or method not in known):
        raise InputError(f"unknown projection method {method!r}; use one of {', '.join(known)}")
    method, options, hybrid = projection_preset(method, options, hybrid)
    settings, options, hybrid = split_options(keywords or {}, settings, options, hybrid, caller=caller)
    return ProjectionOptions(method=method, warm_start=warm_start, tree=tree, settings=settings, options=options,
                             hybrid=hybrid)


def check_times(times, name="times"):
    """``times`` as a non-empty finite 1-d float array (InputError naming ``name`` otherwise)."""
    t = np.atleast_1d(as_float_array(times, name))
    if t.ndim != 1 or t.size == 0:
        raise InputError(f"{name} must be a non-empty 1-d sequence of numbers, got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise InputError(f"{name} must be finite; entries {bad.tolist()} are NaN or infinite")
    return t


@dataclass(frozen=True, eq=False)
class ProjectionTargets:
    """What a :class:`SequenceProjection` projects (validated by :meth:`make`).

    Attributes
    ----------
    z_targets : (N, 2E) ndarray
        Targets ``z~`` (need not be admissible).
    topology : MeshTopology
    reference_vertices : (V, 3) ndarray
        Reference shape: weights of ``W_q``, fixed face, output frame, cold start.
    times : (N,) ndarray
        Time of every target (processing order, warm-start neighbours).
    anchors : tuple of (float, (V, 3) ndarray)
        Known shapes at their times (e.g. the input keys), usable as warm starts.
    """

    z_targets: np.ndarray
    topology: object
    reference_vertices: np.ndarray
    times: np.ndarray
    anchors: tuple = ()

    @classmethod
    def make(cls, z_targets, topology, reference_vertices, times=None, anchors=None):
        """Validated targets: shapes checked, every ``z~`` checked in time order (naming the first bad
        frame: non-positive lengths, NaN), ``times`` default ``0..N-1``."""
        Zt = np.asarray(z_targets, float)
        if Zt.ndim != 2 or Zt.shape[1] != 2 * topology.n_edges:
            raise LengthsAnglesError(f"targets must have shape (N, {2 * topology.n_edges}), got {Zt.shape}")
        N = len(Zt)
        t = np.arange(N, dtype=float) if times is None else check_times(times, "times")
        if len(t) != N:
            raise InputError(f"{len(t)} times for {N} targets")
        for i in np.argsort(t, kind="stable"):  # fail before any work, naming the frame
            check_z(Zt[i], topology, name=f"target at t = {t[i]:g} (extrapolated too far?)")
        X_ref = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices")
        known = tuple((float(s), check_vertices(X, topology.n_vertices, name=f"anchor at t = {float(s):g}"))
                      for s, X in (anchors or ()))
        return cls(Zt, topology, X_ref, t, known)

    def subset(self, indices):
        """The targets ``indices`` (in that order), with all anchors."""
        idx = np.asarray(indices, np.int64)
        return replace(self, z_targets=self.z_targets[idx], times=self.times[idx])


@dataclass
class ProjectedFrame:
    """One projected frame of a :class:`SequenceProjection`.

    Attributes
    ----------
    index : int
        Position in the targets.
    time : float
    result : ReconstructionResult
        ``result.vertices`` is the frame, in the reference's frame.
    seconds : float
        Wall time of the reconstruction.
    max_length_error, max_angle_error : float
        :func:`lacore.reconstruction.reconstruction_errors` (NaN for non-finite vertices).
    warm_start_time : float
        Time of the known shape the projection started next to (NaN: from the reference).
    """

    index: int
    time: float
    result: object
    seconds: float
    max_length_error: float
    max_angle_error: float
    warm_start_time: float


# --------------------------------------------------------------------------- warm starts
def predicted_start(t, known_times, known_vertices, kind="secant", place=None):
    """Starting vertices for the frame at ``t`` from shapes known at other times.

    Parameters
    ----------
    t : float
    known_times : (K,) array_like
        Times of the known shapes (K >= 1).
    known_vertices : sequence of K (V, 3) arrays
        The known shapes.
    kind : {"secant", "nearest"}
        ``"nearest"``: the known shape ``X_j`` nearest in time (the first one on
        ties).  ``"secant"``: ``X_j + r (X_j - X_k)``, ``r = (t - t_j) / (t_j - t_k)``,
        with ``X_k`` the known shape nearest to ``t_j`` on the other side of
        ``t_j`` than ``t`` (linear extrapolation of the path ``t -> X(t)``, error
        ``O(h^2)`` for a frame spacing ``h``); ``X_j`` alone when there is no such
        shape or ``r > MAX_EXTRAPOLATION``.
    place : callable, optional
        ``X -> X`` moving a shape into one common placement (e.g.
        :meth:`~lacore.reconstruction.ReconstructionContext.align`), applied to
        the two shapes a secant combines; default: they already share one.

    Returns
    -------
    vertices : (V, 3) ndarray
    source_time : float
        ``t_j``.

    Examples
    --------
    >>> import numpy as np
    >>> X, source = predicted_start(3.0, [1.0, 2.0], [np.zeros((1, 3)), np.ones((1, 3))])
    >>> X.tolist(), source
    ([[2.0, 2.0, 2.0]], 2.0)
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


def _frame_tree(options, samples, topology, context):
    """The shared spanning tree of the frame-based methods; None for methods that walk no tree.

    ``"gn"``, ``"lsq"`` and the (default) least-squares start of ``"hybrid"`` use no tree
    (:func:`lacore.reconstruction.tree_kind`), so none is built for them.
    """
    kind = tree_kind(options.method, options.hybrid)
    if kind is None:
        return None
    if options.tree is not None:
        return options.tree
    if kind == "bfs":
        return bfs_tree(topology, context.fixed_faces)
    return preassembled_tree(samples, topology, root_face=context.fixed_faces, kind=kind)


# --------------------------------------------------------------------------- the loop
class SequenceProjection:
    """Project a sequence of targets, one frame per :meth:`step` (see the module docstring).

    Parameters
    ----------
    z_targets : (N, 2E) array_like
        Targets ``z~`` (need not be admissible), checked at once.
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference shape: weights of ``W_q``, fixed face, output frame, cold start.
    times : (N,) array_like, optional
        Time of every target; default ``0..N-1``.
    anchors : sequence of (time, (V, 3) vertices), optional
        Known shapes (the input keys, frames computed before) usable as warm starts;
        any rigid placement.
    options : ProjectionOptions, optional
        Method, warm start, tree and settings (default: Gauss-Newton, secant starts).
    samples : (n_s, 2E) array_like, optional
        Samples of the preassembled tree of frame-based methods (default the targets).
    workers : int
        Chains computed side by side: this process and ``workers - 1`` worker processes.
    chains : list of int arrays, optional
        The chains explicitly (each in processing order; default
        :func:`lacore.parallel.frame_chains` of the times away from the anchors).
    all_in_workers : bool
        With more than one chain, compute every chain in a worker process and only
        collect here (keeps this process's Python free, e.g. for a user interface).
    take_over : bool
        A worker process that cannot start or dies (:class:`lacore.parallel.WorkerError`)
        hands its remaining frames to this process, which computes them and adds a line
        to :attr:`notes`; default False raises the error.  Input errors always raise.
    context : ReconstructionContext, optional
        The set-up (and with it the energy) of every frame, made for ``topology`` and ``reference_vertices``
        (default: :func:`lacore.reconstruction.get_context`'s); only with ``workers = 1``.

    Attributes
    ----------
    frames : list of N ProjectedFrame or None
        The finished frames, by target position.
    done, total : int
    finished : bool
    context : ReconstructionContext or None
        The shared set-up (made by the first step).
    tree : DualSpanningTree or None
    chains : list of int arrays or None
        The chains (known after the first step).
    processes : int or None
        Processes computing frames (after the first step; 1 after a take-over).
    local_frames : int
        Frames computed in this process.
    notes : list of str
        What a caller should tell its user (a worker's frames taken over).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> X0 = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> topo = MeshTopology.from_faces([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    >>> z = lengths_and_angles(X0, topo)
    >>> run = SequenceProjection(np.stack([z, 1.5 * z]), topo, X0, times=[0.0, 1.0])
    >>> run.step(), run.done, run.finished
    ([0], 1, False)
    >>> [f.index for f in run.run().frames], run.finished
    ([0, 1], True)
    """

    def __init__(self, z_targets, topology, reference_vertices, times=None, anchors=None, options=None, *,
                 samples=None, workers=1, chains=None, all_in_workers=False, take_over=False, context=None):
        self.options = ProjectionOptions() if options is None else options
        if not isinstance(self.options, ProjectionOptions):
            raise TypeError(f"options must be a ProjectionOptions, got {type(self.options).__name__}")
        self.targets = ProjectionTargets.make(z_targets, topology, reference_vertices, times, anchors)
        self.workers = check_workers(workers)
        if context is not None and self.workers > 1:
            raise InputError("a given context works in this process only: use workers=1 with it")
        self._given_context = context
        self._samples = None if samples is None else np.asarray(samples, float)
        self._explicit_chains = None if chains is None else [np.asarray(c, np.int64) for c in chains]
        self.all_in_workers = bool(all_in_workers)
        self.take_over = bool(take_over)
        N = len(self.targets.times)
        self.frames = [None] * N
        self.done = 0
        self.context = self.tree = self.chains = self.processes = None
        self.local_frames = 0
        self.notes = []
        self._known_t = [t for t, _ in self.targets.anchors]
        self._known_X = [X for _, X in self.targets.anchors]
        self._own = None          # frames of this process still to do, in order (set by the first step)
        self._remote = None       # ChainWorkers of the other chains
        self._remote_frames = []
        self._closed = False

    @property
    def total(self):
        return len(self.frames)

    @property
    def finished(self):
        return self.done >= self.total

    @property
    def order(self):
        """Processing order (the chains one after another; known after the first step)."""
        return np.concatenate(self.chains) if self.chains else np.zeros(0, np.int64)

    def _start(self):
        tg = self.targets
        self.context = self._given_context or get_context(tg.topology, tg.reference_vertices, self.options.settings)
        samples = tg.z_targets if self._samples is None else self._samples
        self.tree = _frame_tree(self.options, samples, tg.topology, self.context)
        self.chains = self._explicit_chains or frame_chains(tg.times, self._known_t, self.workers)
        here = 0 if self.all_in_workers and len(self.chains) > 1 else 1
        self._own = [int(i) for chain in self.chains[:here] for i in chain]
        remote = self.chains[here:]
        self.processes = here + len(remote) if remote else 1
        if remote:
            self._remote_frames = [int(i) for chain in remote for i in chain]
            try:
                self._remote = ChainWorkers(remote, tg, replace(self.options, tree=self.tree))
            except WorkerError as exc:
                self._fall_back(exc)

    def step(self):
        """Compute the next frame of this process's chain and record the frames the worker processes finished
        (with this chain done: wait for the next worker frame).  Returns the indices of the frames finished in
        this step (in the order they finished)."""
        if self._closed:
            raise Cancelled("the projection was closed")
        if self.finished:
            return []
        finished = []
        try:
            if self._own is None:
                self._start()
            if self._own:
                finished.append(self._local_frame(self._own.pop(0)))
                if self._remote is not None:
                    self._collect(finished, block=False)
            elif self._remote is not None:
                self._collect(finished, block=True, limit=1)
        except BaseException:
            self.close()
            raise
        if self.finished and self._remote is not None:
            self._remote.close()
        return finished

    def run(self, progress=None, on_frame=None):
        """Step to the end; returns ``self``.

        ``progress(done, total, message)`` before the first and after every frame (:mod:`lacore.progress`;
        True cancels: :class:`lacore.progress.Cancelled`, the worker processes killed); ``on_frame(index,
        result)`` with every finished frame's :class:`~lacore.reconstruction.ReconstructionResult`.
        """
        try:
            report(progress, self.done, self.total, "projecting frames")
            while not self.finished:
                for i in self.step():
                    if on_frame is not None:
                        on_frame(i, self.frames[i].result)
                    report(progress, self.done, self.total,
                           f"frame {self.done} of {self.total} (t = {self.targets.times[i]:g})")
        except BaseException:
            self.close()
            raise
        return self

    def close(self):
        """Kill the worker processes still running and stop (cancel, error; idempotent)."""
        self._closed = True
        if self._remote is not None:
            self._remote.close()

    # ------------------------------------------------------------------ internals
    def _record(self, frame):
        self.frames[frame.index] = frame
        self.done += 1
        return frame.index

    def _collect(self, finished, block, limit=None):
        try:
            self._remote.collect(lambda frame: finished.append(self._record(frame)), block=block, limit=limit)
        except WorkerError as exc:  # not an input error: a worker that could not start or died
            if self._closed:        # (a closed run's workers were killed on purpose)
                return
            self._fall_back(exc)

    def _fall_back(self, exc):
        """A worker process could not start or died: raise, or (``take_over``) compute its chain's remaining
        frames here and say so."""
        if self._remote is not None:
            self._remote.close()
        self._remote = None
        if not self.take_over:
            raise exc
        pending = [i for i in self._remote_frames if self.frames[i] is None]
        self._own.extend(pending)
        self.processes = 1
        self.notes.append(f"A worker process failed ({str(exc).splitlines()[0]}); its {len(pending)} frame(s) were "
                          "computed in this process instead")

    def _local_frame(self, i):
        tg, opt, context = self.targets, self.options, self.context
        t, z = float(tg.times[i]), tg.z_targets[i]
        known_t, known_X = self._known_t, self._known_X
        initial, hybrid, warm_time = None, opt.hybrid, np.nan
        if opt.warm_start and opt.takes_start and known_t:  # anchors (listed first) win ties
            initial, warm_time = predicted_start(t, known_t, known_X, "nearest")
            predicted = False
            if opt.warm_start == "secant":
                guess, _ = predicted_start(t, known_t, known_X, "secant",
                                           place=lambda X: context.align(X, keep_degenerate=True))
                if guess is not initial and context.energy(z, guess) < context.energy(z, initial):
                    initial, predicted = guess, True
            if not predicted and hybrid.nearest_start_iterations is not None:
                hybrid = replace(hybrid, smoothing_iterations=hybrid.nearest_start_iterations)
        t0 = time.perf_counter()
        try:
            res = reconstruct(z, tg.topology, tg.reference_vertices, method=opt.method, context=context,
                              initial_vertices=initial, tree=self.tree, options=opt.options, hybrid=hybrid)
        except LengthsAnglesError as exc:
            raise LengthsAnglesError(f"frame at t = {t:g}: {exc}") from exc
        seconds = time.perf_counter() - t0
        X = np.asarray(res.vertices, float)
        errors = (np.nan, np.nan)
        if np.all(np.isfinite(X)):
            err = reconstruction_errors(X, z, tg.topology)
            errors = (err["max_length_error"], err["max_angle_error"])
            known_t.append(t)  # usable as a warm start
            known_X.append(X)
        self.local_frames += 1
        return self._record(ProjectedFrame(int(i), t, res, seconds, *errors, warm_time))


def project_chain(targets, options, *, send):
    """A worker's job (:class:`lacore.parallel.WorkerProcess`): the frames of ``targets`` as one chain, in the
    given order, every :class:`ProjectedFrame` sent back as it finishes (indices into ``targets``)."""
    run = SequenceProjection(targets.z_targets, targets.topology, targets.reference_vertices, targets.times,
                             targets.anchors, options, chains=[np.arange(len(targets.times))])
    while not run.finished:
        for i in run.step():
            send(run.frames[i])


class ChainWorkers:
    """Chains of frames computed in worker processes (:mod:`lacore.parallel`), one process per chain.

    Parameters
    ----------
    chains : list of int arrays
        Frame indices of every chain in processing order (:func:`lacore.parallel.frame_chains`).
    targets : ProjectionTargets
        All frames; each worker receives its chain's (and all anchors).
    options : ProjectionOptions

    Every chain starts from the anchors and continues from its own frames (:func:`project_chain`).
    :meth:`collect` hands finished frames (:class:`ProjectedFrame`, indices into ``targets``) to a
    callback; :meth:`close` kills the processes still running (cancel, error).
    """

    def __init__(self, chains, targets, options):
        self._chains = [np.asarray(c, np.int64) for c in chains]
        self._messages = queue.Queue()
        self._open = set()
        self._workers = []
        try:
            for tag, chain in enumerate(self._chains):
                job = (targets.subset(chain), options)
                self._workers.append(WorkerProcess(project_chain, job, tag=tag, messages=self._messages))
                self._open.add(tag)
        except BaseException:
            self.close()
            raise

    @property
    def finished(self):
        """Whether every worker has sent all its frames."""
        return not self._open

    def collect(self, record, block, limit=None):
        """Hand the frames the workers sent to ``record(frame)``; returns how many.

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
            if tag not in self._open:  # a message of a closed (killed) worker
                continue
            if kind == "message":
                record(replace(payload, index=int(self._chains[tag][payload.index])))
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
