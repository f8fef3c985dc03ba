# SPDX-License-Identifier: GPL-3.0-or-later
"""The computation of the long operators as an explicit step function (no bpy).

A :class:`ProjectionJob` computes the frames of a lengths-and-angles motion (thesis 4.2:
piecewise-linear or cubic-spline ``z`` through the keys, projected onto admissible lengths
and angles by reconstruction, eq. 4.10) ONE FRAME PER :meth:`ProjectionJob.step`.  The
modal operators call ``step()`` once per timer tick (Blender stays responsive, Esc
cancels between frames); the synchronous path (scripts, background mode, redo panel)
calls :meth:`ProjectionJob.run`.  Nothing here touches Blender data: cancelling is
dropping the job.

Every frame is looked up in / stored into the session cache (:mod:`.session`) under the
key hashes, keyframes, spline flag, method and time, so a redo that changes only some
factors recomputes only those.

With more than one process (:func:`job_workers`) the frames are split into chains
(:func:`lacore.parallel.frame_chains`, each starting next to a key): this process computes the
first chain, one step per frame as above, while :class:`lacore.shapes.interpolation.ChainWorkers` run
the other chains in worker processes (lacore only); a step records the frames they finished.
With :attr:`ProjectionJob.all_in_workers` (the modal operators) every chain runs in a worker
process and Blender's process only collects: its Python stays free for the UI (a CHOLMOD
factorization in Blender's own process holds Python's lock for ~1-2 s at 50k vertices).
:meth:`ProjectionJob.close` kills them (cancel, error, add-on unregister).
"""

import numpy as np

from ..lacore.errors import LengthsAnglesError
from ..lacore.shapes.interpolation import ChainWorkers, piecewise_linear_z, project_targets, spline_z
from ..lacore.geometry.lengths_angles import check_z
from ..lacore.multiresolution import MultiresolutionReconstruction
from ..lacore.parallel import WorkerError, default_workers, frame_chains
from ..lacore.progress import report
from ..lacore.reconstruction.settings import split_options
from ..lacore.geometry.rigid import rigid_align
from . import session

__all__ = ["ProjectionJob", "key_weights", "job_workers", "MULTIRES", "AUTO_WORKERS_MIN_VERTICES",
           "AUTO_WORKERS_MIN_FRAMES"]

#: The ``method`` of :class:`ProjectionJob` that solves coarse, prolongs and finishes with a few fine
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


def key_weights(keyframes, t):
    """Weights ``(K,)`` of the keys in the piecewise-linear blend at time ``t`` (hat functions; the end
    segments continue linearly beyond the first / last keyframe, as
    :func:`lacore.shapes.interpolation.piecewise_linear_z`)."""
    k = np.asarray(keyframes, float)
    j = int(np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2))
    s = (t - k[j]) / (k[j + 1] - k[j])
    w = np.zeros(len(k))
    w[j], w[j + 1] = 1.0 - s, s
    return w


class ProjectionJob:
    """Frames of a motion through shape keys, computed one per :meth:`step`.

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
    method : str
        lacore reconstruction method (``"lsq"``, ``"hybrid"``, ``"gn"``).
    method_options : dict
        Keywords of :func:`lacore.shapes.interpolation.project_targets` (``hybrid``, ``options``).
    method_label : str
        Distinguishes cached results of different option sets (e.g. the operator's method item).
    workers : int
        Processes computing the frames (:func:`job_workers`; 0 = Auto; the multiresolution method: 1).

    Attributes
    ----------
    results : list of N (V, 3) arrays or None
        Placed results (rigid fit to the piecewise-linear blend of the key coordinates), by ``times`` order.
    done, total : int
    """

    def __init__(self, data, keys, keyframes, times, smooth, method, method_options, method_label, workers=1):
        self.data = data
        self.keys = list(keys)
        self.keyframes = np.asarray(keyframes, float)
        self.times = np.asarray(times, float)
        self.smooth = bool(smooth)
        self.method = method
        self.method_options = dict(method_options)
        idx = [data.index(k) for k in self.keys]
        self.key_vertices = data.coords[idx]
        z_keys = np.stack([session.key_z(data, k) for k in self.keys])
        if self.smooth and len(self.keys) > 2:
            self.z_targets = spline_z(z_keys, self.keyframes, self.times)
        else:
            self.z_targets = piecewise_linear_z(z_keys, self.keyframes, self.times)
        for t, z in zip(self.times, self.z_targets, strict=True):  # fail before any work, naming the frame
            check_z(z, data.topology, name=f"target at {t:g} (extrapolated too far?)")
        V = data.topology.n_vertices
        flat = self.key_vertices.reshape(len(self.keys), 3 * V)
        self._placement = piecewise_linear_z(flat, self.keyframes, self.times).reshape(-1, V, 3)
        self._anchors = [(float(t), X) for t, X in zip(self.keyframes, self.key_vertices, strict=True)]
        self._key = (data.topology_hash, tuple(data.key_hashes[i] for i in idx), tuple(self.keyframes.tolist()),
                     self.smooth, method_label)
        self.results = [None] * len(self.times)
        self.failures = []  # "t = ...: <failure>: <message>" of frames failing their checks (written anyway)
        self.done = 0
        self.computed = 0  # frames not taken from the session cache
        self.workers = int(workers)
        self.processes = None  # processes used (known after the first step)
        self._own = None       # frames of this process's chain still to do (set by the first step)
        self._remote = None    # ChainWorkers of the other chains
        self._remote_frames = []
        self.notes = []        # what the user should know besides failed checks (a worker process failed ...)
        #: with more than one process, compute every chain in a worker process (set before the first step)
        self.all_in_workers = False
        self._closed = False
        self.local_frames = 0  # frames computed in this process

    @property
    def total(self):
        return len(self.times)

    @property
    def finished(self):
        return self.done >= self.total

    def _frame_key(self, i):
        return (*self._key, float(self.times[i]))

    def _start(self):
        """Split the frames into chains and start the worker processes of all but the first (of all with
        :attr:`all_in_workers`; see the module docstring); chains whose frames are all cached stay here."""
        todo = sum(not session.has_result(self._frame_key(i)) for i in range(self.total))
        n = 1 if self.method == MULTIRES else job_workers(self.workers, self.data.topology.n_vertices, todo)
        chains = frame_chains(self.times, self.keyframes, n)
        here = 0 if self.all_in_workers and n > 1 else 1
        self._own = [int(i) for chain in chains[:here] for i in chain]
        remote = []
        for chain in chains[here:]:
            if all(session.has_result(self._frame_key(i)) for i in chain):
                self._own.extend(int(i) for i in chain)
            else:
                remote.append(chain)
        self.processes = here + len(remote) if remote else 1
        if remote:
            self._remote_frames = [int(i) for chain in remote for i in chain]
            options = dict(self.method_options)
            setup = split_options({}, None, options.pop("options", None), options.pop("hybrid", None))
            try:
                self._remote = ChainWorkers(remote, self.z_targets, self.data.topology, self.key_vertices[0],
                                            self.times, self._anchors, self.method, "secant", None, setup)
            except WorkerError as exc:
                self._fall_back(exc)

    def _collect(self, block, limit=None):
        try:
            self._remote.collect(self._record_remote, block=block, limit=limit)
        except WorkerError as exc:  # not a lacore input error: a worker that could not start or died
            if not self._closed:    # (a cancelled job's workers were killed on purpose)
                self._fall_back(exc)

    def _fall_back(self, exc):
        """A worker process could not start or died (not an error of the input, which is raised): compute its
        chain's remaining frames here, and say so."""
        if self._remote is not None:
            self._remote.close()
        self._remote = None
        pending = [i for i in self._remote_frames if self.results[i] is None]
        self._own.extend(pending)
        self.processes = 1
        print(f"Lengths & Angles: {exc}", flush=True)
        self.notes.append(f"A worker process failed ({str(exc).splitlines()[0]}); its {len(pending)} frame(s) were "
                          "computed in this process instead")

    def step(self):
        """Compute the next frame of this process's chain (in its order) and record the frames the worker
        processes finished; with this chain done, wait for the next worker frame.  Returns the frames done."""
        if self.finished:
            return self.done
        try:
            if self._own is None:
                self._start()
            if self._own:
                self._local_frame(self._own.pop(0))
                if self._remote is not None:
                    self._collect(block=False)
            else:
                self._collect(block=True, limit=1)
        except BaseException:
            self.close()
            raise
        if self.finished and self._remote is not None:
            self._remote.close()
        return self.done

    def close(self):
        """Kill the worker processes still running and stop taking over their frames (cancel, error;
        idempotent)."""
        self._closed = True
        if self._remote is not None:
            self._remote.close()

    def _local_frame(self, i):
        t = float(self.times[i])
        key = self._frame_key(i)
        cached = session.cached_result(key)
        if cached is not None:
            X, note = cached
        else:
            if self.method == MULTIRES:
                rec = self._multires(i, t)
            else:
                res = project_targets(self.z_targets[i:i + 1], self.data.topology, self.key_vertices[0], times=[t],
                                      anchors=self._anchors, method=self.method, **self.method_options)
                rec = res.reconstructions[0]
            X, note = self._store(i, rec)
            self.local_frames += 1
        # a known shape, cached or computed (the same placed array either way, so a run with cache hits predicts
        # what a fresh run does): the next frames start from the extrapolation through the last ones
        self._anchors.append((t, X))
        self._record(i, X, note)

    def _record_remote(self, i, rec, seconds, errors, warm_time):
        X, note = self._store(i, rec)
        self._record(i, X, note)

    def _store(self, i, rec):
        """Place a computed frame (rigid fit to the blend of the keys), check it and put it in the session cache."""
        t = float(self.times[i])
        Xr = np.asarray(rec.vertices, float)
        note = self._failure(rec, t)
        if not np.all(np.isfinite(Xr)):
            raise LengthsAnglesError(f"the reconstruction at {t:g} is not finite (the lengths and angles are "
                                     "too far from any shape; try smaller factors)")
        X = rigid_align(Xr, self._placement[i])
        session.store_result(self._frame_key(i), X, note)
        self.computed += 1
        return X, note

    def _record(self, i, X, note):
        if note:
            self.failures.append(note)
        self.results[i] = X
        self.done += 1

    def _multires(self, i, t):
        """One frame by coarse solve + prolongation + fine steps; the hierarchy is built once per keys (session)."""
        key = (self.data.topology_hash, self._key[1], "multires")
        options = dict(self.method_options)
        setup = options.pop("setup", {})
        mr = session.cached_object(key, lambda: MultiresolutionReconstruction(self.key_vertices, self.data.topology,
                                                                              **setup))
        # the coarse solve starts from the coarse key of largest weight (lacore's default: a bend far from the
        # previous frame's coarse solution is reached more reliably from the nearer key)
        return mr.reconstruct(key_weights(self.keyframes, t), z_target=self.z_targets[i], **options)

    def _failure(self, result, t):
        """``"t = ...: <failure>: <message>"`` if the reconstruction failed its checks (lacore's ``success``,
        ``failure``), else None; the least-squares relaxation (which minimizes nothing) not reproducing a
        non-admissible target is expected and not listed, folds are."""
        if result.success:
            return None
        failure = getattr(result, "failure", "") or "failed"
        if self.method == "lsq" and failure == "not_reproduced":
            return None
        return f"t = {t:g}: {failure}: {result.message}"

    def run(self, progress=None):
        """All remaining frames; ``progress(done, total, message)`` after each (:mod:`lacore.progress`)."""
        report(progress, self.done, self.total, "starting")
        while not self.finished:
            self.step()
            report(progress, self.done, self.total, f"frame {self.done} of {self.total}")
        return self.results
