# SPDX-License-Identifier: GPL-3.0-or-later
"""The computations of the long operators as jobs: step functions without bpy.

A *job* is what :class:`.runs.Run` drives (the modal operators once per timer tick in a
worker thread, scripts and background mode to the end):

``total``, ``done`` : int
    Units of work (frames, stages ...), read by the progress bar at any time.
``finished`` : bool
``step()``
    One unit of work (lacore only, never bpy: it runs in a worker thread).
``cancel()``
    Stop: kill worker processes, make a running ``step()`` end early; its result is dropped.
``status`` : str
    What is being done, for the status bar (e.g. ``"frame 3 of 10"``).
``failures``, ``notes`` : list of str
    Results that failed their checks (written anyway, with a WARNING), and other things the
    report should say.
``all_in_workers`` : bool, optional
    Set by the modal runner: compute in worker processes, keep Blender's Python free.

:class:`ProjectionJob`
    The frames of a motion through shape keys (thesis 4.2: piecewise-linear or cubic-spline
    ``z`` through the keys, projected onto admissible lengths and angles, eq. 4.10), one frame
    per step, by lacore's one projection loop
    (:class:`lacore.shapes.projection.SequenceProjection`).  Frames found in the session
    cache (:mod:`.session`) are not computed again: they join the keys as known shapes.
:class:`MultiresJob`
    The same frames by coarse solve + prolongation + fine steps (not offered in the UI).
:class:`PathJob`
    The same frames (piecewise linear only) by a reduced model of the path between every two keys
    (:func:`lacore.shapes.mixing.path_inbetweens`): a few factorizations per segment, not per frame.
:class:`MixerJob`
    The same frames by a live mixer of the keys (:class:`lacore.shapes.ShapeMixer`): one mix per frame.
:class:`CallJob`
    One lacore call that takes a progress callback (shape model, binding, marker fit): a job
    of one step whose progress and cancellation go through :mod:`lacore.progress`.
:class:`DoneJob`
    Nothing to compute (the run only writes).
"""

import numpy as np

from ..lacore.errors import LengthsAnglesError
from ..lacore.geometry.rigid import rigid_align
from ..lacore.multiresolution import MultiresolutionReconstruction
from ..lacore.parallel import call_in_process, default_workers
from ..lacore.progress import Cancelled, report
from ..lacore.shapes.interpolation import PATH, keyframe_inbetweens, keyframe_targets, path_frames, piecewise_linear_z
from ..lacore.shapes.projection import SequenceProjection
from . import session

__all__ = ["ProjectionJob", "MultiresJob", "PathJob", "CallJob", "DoneJob", "projection_job", "run_job", "job_workers",
           "MULTIRES", "AUTO_WORKERS_MIN_VERTICES", "AUTO_WORKERS_MIN_FRAMES"]

#: The method of :func:`projection_job` that solves coarse, prolongs and finishes with a few fine
#: Gauss-Newton steps (:class:`lacore.multiresolution.MultiresolutionReconstruction`).
MULTIRES = "multires"

#: "Auto" processes (``workers=0``) only for meshes at least this large ...
AUTO_WORKERS_MIN_VERTICES = 20000
#: ... with at least this many frames to compute: a worker process costs the start of an interpreter and its
#: own solver set-up (~2-4 s at 50k vertices, about two Fast frames; benchmarks/bench_continuation.py).
AUTO_WORKERS_MIN_FRAMES = 6


def job_workers(requested, n_vertices, n_frames):
    """Processes computing a job's frames: ``requested >= 1`` as given; ``0`` (Auto):
    :func:`lacore.parallel.default_workers` for a mesh of at least :data:`AUTO_WORKERS_MIN_VERTICES` vertices
    with at least :data:`AUTO_WORKERS_MIN_FRAMES` frames to compute, else 1."""
    if requested >= 1:
        return int(requested)
    if n_vertices >= AUTO_WORKERS_MIN_VERTICES and n_frames >= AUTO_WORKERS_MIN_FRAMES:
        return default_workers()
    return 1


class _FrameJob:
    """What the frame jobs share: keys, targets, placement, the session cache, failure notes.

    Every result is placed by a rigid fit to the piecewise-linear blend of the key coordinates at its
    time (so in-betweens follow the keys) and stored in the session cache under the key hashes,
    keyframes, spline flag, method label and time (a redo that changes some times recomputes those).
    """

    def __init__(self, data, keys, keyframes, times, smooth, label):
        self.data = data
        self.keys = list(keys)
        self.keyframes = np.asarray(keyframes, float)
        self.times = np.asarray(times, float)
        idx = [data.index(k) for k in self.keys]
        self.key_vertices = data.coords[idx]
        z_keys = np.stack([session.key_z(data, k) for k in self.keys])
        self.z_targets = keyframe_targets(z_keys, self.keyframes, self.times, smooth)
        V = data.topology.n_vertices
        flat = self.key_vertices.reshape(len(self.keys), 3 * V)
        self._placement = piecewise_linear_z(flat, self.keyframes, self.times).reshape(-1, V, 3)
        self._key = (data.topology_hash, tuple(data.key_hashes[i] for i in idx), tuple(self.keyframes.tolist()),
                     bool(smooth), label)
        self.results = [None] * len(self.times)
        self.failures = []  # "t = ...: <failure>: <message>" of frames failing their checks (written anyway)
        self.done = 0
        self.computed = 0  # frames not taken from the session cache
        self.cancelled = False
        for i in range(len(self.times)):
            hit = session.cached_result(self._frame_key(i))
            if hit is not None:
                self._record(i, *hit)

    @property
    def total(self):
        return len(self.times)

    @property
    def finished(self):
        return self.done >= self.total

    @property
    def status(self):
        return f"frame {min(self.done + 1, self.total)} of {self.total}"

    @property
    def notes(self):
        return []

    def _frame_key(self, i):
        return (*self._key, float(self.times[i]))

    def _record(self, i, X, note):
        if self.results[i] is None:
            self.done += 1
        if note:
            self.failures.append(note)
        self.results[i] = X

    def _store(self, i, result, lsq):
        """Place a computed frame, note a failed check, put it in the session cache and record it."""
        t = float(self.times[i])
        Xr = np.asarray(result.vertices, float)
        if not np.all(np.isfinite(Xr)):
            raise LengthsAnglesError(f"the reconstruction at {t:g} is not finite (the lengths and angles are "
                                     "too far from any shape; try smaller factors)")
        note = None
        failure = getattr(result, "failure", "") or "failed"
        # the least-squares relaxation (which minimizes nothing) not reproducing a target is expected; folds are not
        if not result.success and not (lsq and failure == "not_reproduced"):
            note = f"t = {t:g}: {failure}: {result.message}"
        X = rigid_align(Xr, self._placement[i])
        session.store_result(self._frame_key(i), X, note)
        self.computed += 1
        self._record(i, X, note)

    def cancel(self):
        self.cancelled = True


class ProjectionJob(_FrameJob):
    """Frames of a motion through shape keys by :class:`lacore.shapes.projection.SequenceProjection`.

    Parameters
    ----------
    data : session.MeshData
    keys : list of str
        Shape keys at ``keyframes`` (at least 2).
    keyframes : (K,) strictly increasing floats
    times : (N,) floats
        Frames (or factors) to compute; may extrapolate.
    smooth : bool
        Cubic spline in ``z`` (else piecewise linear).
    options : lacore.shapes.projection.ProjectionOptions
    label : str
        Distinguishes cached results of different option sets (the operator's method item).
    workers : int
        Processes computing the frames (:func:`job_workers`; 0 = Auto).

    Attributes
    ----------
    results : list of N (V, 3) arrays or None
        Placed results, by ``times`` order (cached ones from the start).
    projection : SequenceProjection or None
        lacore's loop over the frames not in the cache (None when all are).
    """

    def __init__(self, data, keys, keyframes, times, smooth, options, label, workers=1):
        super().__init__(data, keys, keyframes, times, smooth, label)
        todo = [i for i in range(self.total) if self.results[i] is None]
        known = [(float(t), X) for t, X in zip(self.keyframes, self.key_vertices, strict=True)]
        known += [(float(self.times[i]), self.results[i]) for i in range(self.total) if self.results[i] is not None]
        self._todo = todo
        self._lsq = options.method == "lsq"
        self.projection = None
        if todo:  # fail here (validation), naming the frame, before any work
            n = job_workers(workers, data.topology.n_vertices, len(todo))
            self.projection = SequenceProjection(self.z_targets[todo], data.topology, self.key_vertices[0],
                                                 self.times[todo], known, options, workers=n, take_over=True)

    @property
    def all_in_workers(self):
        return self.projection is not None and self.projection.all_in_workers

    @all_in_workers.setter
    def all_in_workers(self, value):
        if self.projection is not None:
            self.projection.all_in_workers = bool(value)

    @property
    def processes(self):
        """Processes that computed frames (1 when all came from the cache)."""
        return 1 if self.projection is None or self.projection.processes is None else self.projection.processes

    @property
    def local_frames(self):
        """Frames computed in this process."""
        return 0 if self.projection is None else self.projection.local_frames

    @property
    def notes(self):
        """A worker process's frames taken over by this process (lacore says so)."""
        return [] if self.projection is None else list(self.projection.notes)

    def step(self):
        """The next frame (of this process's chain, or one a worker process finished)."""
        if self.cancelled:
            raise Cancelled("the job was cancelled")
        if self.finished:
            return
        for j in self.projection.step():
            self._store(self._todo[j], self.projection.frames[j].result, self._lsq)

    def cancel(self):
        super().cancel()
        if self.projection is not None:
            self.projection.close()


class MultiresJob(_FrameJob):
    """The frames by :meth:`lacore.multiresolution.MultiresolutionReconstruction.reconstruct` (coarse solve,
    prolongation, ``options`` of its fine steps), the hierarchy built once per keys (session cache)."""

    def __init__(self, data, keys, keyframes, times, smooth, options, label):
        super().__init__(data, keys, keyframes, times, smooth, label)
        self.options = dict(options)
        self._weights = piecewise_linear_z(np.eye(len(self.keys)), self.keyframes, self.times)  # hat functions
        self.processes = 1
        self.local_frames = 0

    def step(self):
        if self.cancelled:
            raise Cancelled("the job was cancelled")
        i = next(i for i in range(self.total) if self.results[i] is None)
        key = (self.data.topology_hash, self._key[1], "multires")
        options = dict(self.options)
        setup = options.pop("setup", {})
        mr = session.cached_object(key, lambda: MultiresolutionReconstruction(self.key_vertices, self.data.topology,
                                                                              **setup))
        # the coarse solve starts from the coarse key of largest weight (a bend far from the previous frame's
        # coarse solution is reached more reliably from the nearer key)
        result = mr.reconstruct(self._weights[i], z_target=self.z_targets[i], **options)
        self.local_frames += 1
        self._store(i, result, lsq=False)


def projection_job(data, keys, keyframes, times, smooth, method, options, label, workers=1):
    """The job computing frames with ``method``: :data:`MULTIRES` (``options``: keywords of the fine steps) or
    lacore's loop (``options``: :class:`~lacore.shapes.projection.ProjectionOptions`)."""
    if method == MULTIRES:
        return MultiresJob(data, keys, keyframes, times, smooth, options, label)
    return ProjectionJob(data, keys, keyframes, times, smooth, options, label, workers)


class PathJob(_FrameJob):
    """Frames of a piecewise-linear motion through shape keys by lacore's ``method="path"``
    (:func:`lacore.shapes.interpolation.keyframe_inbetweens`): every segment between two keys by a reduced model
    of its path, all frames in one step (progress and Esc through :mod:`lacore.progress`).

    Every frame has an error estimate (:attr:`indicator`); where the estimate stays above the tolerance lacore
    computes the frame by the full projection, and a frame that is still off is written and listed in
    :attr:`failures`.

    Parameters
    ----------
    data, keys, keyframes, times, label
        As :class:`ProjectionJob` (piecewise linear: the path method has no spline).
    options : lacore.shapes.mixing.PathOptions
    """

    def __init__(self, data, keys, keyframes, times, options, label):
        super().__init__(data, keys, keyframes, times, False, label)
        self.options = options
        self._todo = [i for i in range(self.total) if self.results[i] is None]
        self._message = ""
        self.indicator = np.zeros(self.total)
        self.summary = ""
        self.processes = 1
        self.local_frames = 0
        self.all_in_workers = False

    @property
    def status(self):
        return f"path in-betweens: {self._message}" if self._message else super().status

    def _progress(self, done, total, message=""):
        self._message = message
        return self.cancelled

    def step(self):
        """All frames not in the session cache, placed (in a worker process when :attr:`all_in_workers`: the
        factorizations hold Python's lock, a modal run keeps Blender's Python free)."""
        if self.cancelled:
            raise Cancelled("the job was cancelled")
        if not self._todo:
            return
        todo, self._todo = self._todo, []
        args = (self.key_vertices, self.data.topology.faces, self.keyframes, self.times[todo], self.options)
        if self.all_in_workers:
            vertices, indicator, success, message = call_in_process(path_frames, args, progress=self._progress)
            self.processes = 2
        else:  # the session's topology: its set-up (ordering, symbolic analysis) is cached for the next run
            res = keyframe_inbetweens(self.key_vertices, self.data.topology, self.keyframes, self.times[todo],
                                      method=PATH, options=self.options, progress=self._progress)
            vertices, indicator, success, message = res.vertices, res.indicator, res.success, res.message
        self.local_frames = 0 if self.all_in_workers else len(todo)
        for j, i in enumerate(todo):
            X = np.asarray(vertices[j], float)
            if not np.all(np.isfinite(X)):
                raise LengthsAnglesError(f"the in-between at {float(self.times[i]):g} is not finite: use the "
                                         "Gauss-Newton method")
            self.indicator[i] = indicator[j]
            note = None
            if not success:                    # lacore computed those above the tolerance by the full projection
                note = f"t = {float(self.times[i]):g}: path: {message}"
            X = rigid_align(X, self._placement[i])
            session.store_result(self._frame_key(i), X, note)
            self.computed += 1
            self._record(i, X, note)
        worst = float(np.max(indicator)) if len(todo) else 0.0
        self.summary = f"estimated error at most {100 * worst:.2g} % of the size"
        if "polished" in message:
            self.summary += " (the in-betweens above 0.3 % computed by the full projection)"


class MixerJob(_FrameJob):
    """Frames of a motion through shape keys by a :class:`lacore.shapes.ShapeMixer` of those keys: one mix each.

    The targets are linear in the keys' lengths and angles, so the frame at ``t`` is the mix of the keys'
    weight vectors blended like the keys (basis: all zero, mixer key ``k``: ``e_k``), piecewise linearly or by
    the cubic spline (:func:`lacore.shapes.interpolation.keyframe_targets` is linear in its data).  Results are
    placed like the other jobs' (:class:`_FrameJob`).  A mix outside the mixer's accurate range is written and
    listed in :attr:`failures` (the operator's WARNING suggests Gauss-Newton).

    Parameters
    ----------
    data, keys, keyframes, times, smooth, label
        As :class:`ProjectionJob`.
    mixer : lacore.shapes.ShapeMixer
        Built from the mesh's basis and the keys ``mixer_keys`` (its weights, in order).
    key_weights : (len(keys), K-1) array_like
        The mixer weights of every key of ``keys``.
    token : str
        Identifies the mixer (cached results of another mixer are not reused).
    lock : context manager, optional
        Held during each mix (the live-mix handlers use the same mixer).
    """

    def __init__(self, data, keys, keyframes, times, smooth, label, mixer, key_weights, token, lock=None):
        super().__init__(data, keys, keyframes, times, smooth, f"{label}:{token}")
        self.mixer = mixer
        self.lock = lock
        self.weights = keyframe_targets(np.asarray(key_weights, float), self.keyframes, self.times, smooth)
        self._todo = [i for i in range(self.total) if self.results[i] is None]

    def step(self):
        """The next frame: one mix, placed."""
        if self.cancelled:
            raise Cancelled("the job was cancelled")
        if not self._todo:
            return
        i = self._todo.pop(0)
        if self.lock is not None:
            with self.lock:
                result = self.mixer.mix(self.weights[i])
        else:
            result = self.mixer.mix(self.weights[i])
        t = float(self.times[i])
        X = np.asarray(result.vertices, float)
        if not np.all(np.isfinite(X)):
            raise LengthsAnglesError(f"the mix at {t:g} is not finite (weights {np.round(self.weights[i], 3)}): "
                                     "use the Gauss-Newton method")
        note = None if result.in_range else (f"factor {t:g} (weights {', '.join(f'{w:.3g}' for w in self.weights[i])}"
                                             f"): {result.message}")
        X = rigid_align(X, self._placement[i])
        session.store_result(self._frame_key(i), X, note)
        self.computed += 1
        self._record(i, X, note)


class CallJob:
    """One lacore call as a job of one step: ``function(progress)`` with a :mod:`lacore.progress` callback that
    updates :attr:`done` / :attr:`total` (read by the progress bar while the step runs) and returns True after
    :meth:`cancel` (lacore then raises :class:`lacore.progress.Cancelled`).

    Parameters
    ----------
    function : callable
        ``function(progress) -> result`` (lacore only: it runs in a worker thread).
    label : str
        What it computes (status bar), e.g. ``"shape model"``.
    total : int
        Units of work until the call reports its own total.
    process : tuple, optional
        ``(lacore_function, args, convert)`` or ``(lacore_function, args, convert, kwargs)``: the same call in a
        worker process (:func:`lacore.parallel.call_in_process`, the result ``convert(value)``), used when
        :attr:`all_in_workers` is set (a modal run: CHOLMOD holds the interpreter lock, so
        a long call in a thread would freeze Blender's Python; Esc kills the process at once).

    Attributes
    ----------
    result : object
        The call's return value (after the step).
    """

    def __init__(self, function, label, total=1, process=None):
        self.function = function
        self.process = process
        self.all_in_workers = False
        self.label = label
        self.total = max(int(total), 1)
        self.done = 0
        self.message = ""
        self.result = None
        self.finished = False
        self.cancelled = False
        self.failures = []
        self.notes = []

    @property
    def status(self):
        return f"{self.label}: {self.message}" if self.message else self.label

    def _progress(self, done, total, message=""):
        self.total = max(int(total), 1)
        self.done = min(int(done), self.total)
        self.message = message
        return self.cancelled

    def step(self):
        if self.cancelled:
            raise Cancelled(f"{self.label} cancelled")
        if not self.finished:
            if self.all_in_workers and self.process is not None:
                function, args, convert, *kwargs = self.process
                self.result = convert(call_in_process(function, args, *kwargs, progress=self._progress))
            else:
                self.result = self.function(self._progress)
            self.done, self.finished = self.total, True

    def cancel(self):
        self.cancelled = True


class DoneJob:
    """A job with nothing to compute (e.g. a bake whose keys are on consecutive frames): finished from the start."""

    total = done = 0
    finished = True
    status = ""

    def __init__(self):
        self.failures, self.notes, self.results = [], [], []

    def step(self):
        pass

    def cancel(self):
        pass


def run_job(job, progress=None):
    """Step ``job`` to the end (scripts, background mode); ``progress(done, total, message)`` after every step
    (:mod:`lacore.progress`: True cancels the job and raises :class:`lacore.progress.Cancelled`)."""
    try:
        report(progress, job.done, job.total, job.status)
        while not job.finished:
            job.step()
            report(progress, job.done, job.total, job.status)
    except BaseException:
        job.cancel()
        raise
    return job
