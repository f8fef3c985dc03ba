"""Worker processes: the frames of one projection computed side by side.

Continuation along ``t`` (:func:`lacore.shapes.projection.predicted_start`) makes a
sequence of frames sequential: every frame starts from the ones before it.  The
frames are therefore split into *chains* of consecutive times (:func:`frame_chains`),
each starting next to a known shape (a key) and running away from it; the calling
process computes the first chain and every other chain runs in a
:class:`WorkerProcess`.  Processes, not threads: the numeric Cholesky
factorization, a frame's main cost, runs on one core in cvxopt's CHOLMOD and
holds the interpreter lock, so threads would take turns.

:func:`call_in_process` runs one long call (e.g. a shape mixer's build) in a worker so
that the caller's interpreter stays responsive (progress, a cancel that kills the
worker at once).

A worker is a fresh interpreter (``sys.executable``, so Blender's own Python inside
Blender) with the caller's ``sys.path``, importing this ``lacore`` under the same
package name (inside Blender ``bl_ext.<repository>.<extension>.lacore``: the parent
packages are registered as bare namespaces, the add-on itself is never imported,
so a worker never loads bpy).  Jobs and results cross a pipe as pickles, so lacore
objects arrive as the same classes; a topology arrives without its cache
(:class:`lacore.cache.DerivedCache`), and the worker builds its own reconstruction
context.  Each worker costs the start of an interpreter, the solver set-up
(pattern, ordering, symbolic factorization: seconds for a large mesh) and the
memory of one more solver.

:func:`close_workers` ends them all (a cancelled run, the add-on's unregister).
"""

import contextlib
import os
import pickle
import queue
import subprocess
import sys
import threading
import traceback

import numpy as np

from .errors import InputError, check_integer

__all__ = ["frame_chains", "WorkerProcess", "WorkerError", "call_in_process", "check_workers", "close_workers",
           "default_workers"]

_LACORE_PACKAGE = __package__  # "lacore", or "bl_ext.<repository>.<extension>.lacore" inside Blender
_LACORE_DIR = os.path.dirname(os.path.abspath(__file__))

# The worker's main program.  It ignores Ctrl-C (the caller stops its workers), reads the header pickle (only
# built-in types, so it unpickles before any import; a caller gone already ends it quietly), makes the caller's
# lacore importable under its package name and hands the pipe to serve().
_BOOTSTRAP = r"""
import importlib, os, pickle, signal, sys, types
signal.signal(signal.SIGINT, signal.SIG_IGN)
channel_in, channel_out = sys.stdin.buffer, sys.stdout.buffer
sys.stdout = sys.stderr
try:
    header = pickle.load(channel_in)
except EOFError:
    os._exit(0)
sys.path[:] = header["sys_path"]
for name, path in header["parents"]:
    if name not in sys.modules:
        module = types.ModuleType(name)
        module.__path__ = [path]
        sys.modules[name] = module
        if "." in name:
            parent, _, child = name.rpartition(".")
            setattr(sys.modules[parent], child, module)
importlib.import_module(header["module"]).serve(channel_in, channel_out)
"""


class WorkerError(RuntimeError):
    """A worker process failed with an error that is not a :class:`lacore.errors.LengthsAnglesError`
    (the message carries the worker's traceback), or could not be started."""


def check_workers(workers):
    """``workers`` as an int >= 1 (``InputError`` otherwise)."""
    return check_integer(workers, "workers", 1)


def default_workers():
    """Processes worth running side by side on this machine: the CPU cores available to this process, at most 4
    (each worker holds one more factorization in memory; beyond the cores they only take turns)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


def frame_chains(times, known_times, n_chains):
    """Split frames into chains of consecutive times, each in processing order away from the nearest known time.

    Parameters
    ----------
    times : (N,) array_like
        Frame times.
    known_times : (K,) array_like
        Times of the known shapes (keys); may be empty.
    n_chains : int
        Chains wanted (fewer when there are fewer frames).

    Returns
    -------
    list of int arrays
        Indices into ``times``; together a partition of ``0..N-1``.  The sorted
        frames are cut into ``n_chains`` blocks of (nearly) equal size; a block is
        processed in increasing time unless its last frame is strictly nearer to a
        known time than its first (then decreasing), so every chain starts next to
        a key.  One chain: all frames in increasing time (stable order).
    """
    t = np.asarray(times, float)
    order = np.argsort(t, kind="stable")
    n = max(1, min(int(n_chains), len(t)))
    if n == 1:
        return [order]
    known = np.asarray(known_times, float)
    chains = []
    for block in np.array_split(order, n):
        if known.size:
            first = np.min(np.abs(known - t[block[0]]))
            last = np.min(np.abs(known - t[block[-1]]))
            if last < first:
                block = block[::-1]
        chains.append(block)
    return chains


def _parent_packages():
    """``[(name, directory)]`` of the packages above lacore, outermost first (``bl_ext``,
    ``bl_ext.<repository>``, ``bl_ext.<repository>.<extension>`` inside Blender; none standalone)."""
    names = _LACORE_PACKAGE.split(".")[:-1]
    directories = [os.path.dirname(_LACORE_DIR)]        # the innermost parent holds lacore/
    while len(directories) < len(names):
        directories.append(os.path.dirname(directories[-1]))
    return [(".".join(names[:i + 1]), d) for i, d in enumerate(reversed(directories[:len(names)]))]


_RUNNING = set()  # live workers, for close_workers()
_RUNNING_LOCK = threading.Lock()


class WorkerProcess:
    """A Python interpreter running one job: ``function(*args, send=...)`` from lacore.

    The job calls ``send(message)`` any number of times; every message arrives in
    :attr:`messages` (a :class:`queue.Queue`) as ``(tag, "message", message)``, then
    ``(tag, "done", return value)`` or ``(tag, "error", (type name, text, traceback))``
    (also when the process dies).  A thread writes the job to the process and reads
    its answers, so the caller goes on at once.  :meth:`close` kills the process if
    it is still running.

    Parameters
    ----------
    function : callable
        A module-level function importable in the worker (lacore's, or any module on
        the caller's ``sys.path``), pickled by reference.
    args : tuple
        Its positional arguments (pickled).
    tag : object
        Identifies this worker's messages in a queue shared by several workers.
    messages : queue.Queue, optional
        The queue to deliver into (default: a new one).
    """

    def __init__(self, function, args, tag=0, messages=None):
        self.tag = tag
        self.messages = queue.Queue() if messages is None else messages
        header = {"sys_path": [p for p in sys.path if isinstance(p, str)], "parents": _parent_packages(),
                  "module": __name__}
        try:
            job = pickle.dumps((function, args), protocol=pickle.HIGHEST_PROTOCOL)
            # a session of its own: a terminal's Ctrl-C reaches the caller only (a worker interrupted while its
            # interpreter starts, before the bootstrap ignores Ctrl-C, would print a fatal error)
            self._process = subprocess.Popen([sys.executable, "-c", _BOOTSTRAP], stdin=subprocess.PIPE,
                                             stdout=subprocess.PIPE, start_new_session=True)
            pickle.dump(header, self._process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._process.stdin.flush()
        except (OSError, pickle.PicklingError) as exc:
            self.close()
            raise WorkerError(f"could not start a worker process ({sys.executable}): {exc}") from exc
        with _RUNNING_LOCK:
            _RUNNING.add(self)
        self._reader = threading.Thread(target=self._read, args=(job,), name="lacore-worker-io", daemon=True)
        self._reader.start()

    def _read(self, job):
        stream = self._process.stdout
        finished = False
        try:
            self._process.stdin.write(job)  # blocks while the worker imports lacore: here, not in the caller
            self._process.stdin.flush()
            while True:
                kind, payload = pickle.load(stream)
                self.messages.put((self.tag, kind, payload))
                if kind in ("done", "error"):
                    finished = True
                    return
        except Exception as exc:  # EOF or a broken pipe: the process died (or was killed)
            if not finished:
                code = self._process.poll()
                self.messages.put((self.tag, "error", ("WorkerError", f"the worker process ended unexpectedly "
                                                                      f"(exit code {code}): {exc!r}", "")))

    @property
    def running(self):
        """Whether the process is alive."""
        return getattr(self, "_process", None) is not None and self._process.poll() is None

    def close(self):
        """Kill the process if it is still running and wait for it (idempotent)."""
        process = getattr(self, "_process", None)
        if process is not None:
            if process.poll() is None:
                process.kill()
            process.wait()
            for stream in (process.stdin, process.stdout):
                try:
                    if stream is not None:
                        stream.close()
                except OSError:
                    pass
        with _RUNNING_LOCK:
            _RUNNING.discard(self)


def raise_worker_error(payload):
    """Re-raise a worker's ``("error", (type name, message, traceback))`` in this process:
    :class:`lacore.errors.LengthsAnglesError` (and its subclasses) keep their message, anything else is a
    :class:`WorkerError` carrying the worker's traceback."""
    name, message, trace = payload
    if name in _LACORE_ERRORS:
        raise _LACORE_ERRORS[name](message)
    if name == "WorkerError":  # the reader's own report: the process ended without a result
        raise WorkerError(message)
    raise WorkerError(f"a worker process failed: {name}: {message}" + (f"\n{trace}" if trace else ""))


def _call_with_progress(function, args, kwargs, send):
    """The worker's side of :func:`call_in_process`: ``function(*args, progress=..., **kwargs)`` sending every
    progress report back as ``(done, total, message)``."""
    def progress(done, total, message=""):
        send((int(done), int(total), str(message)))
    return function(*args, progress=progress, **kwargs)


def call_in_process(function, args=(), kwargs=None, progress=None, poll=0.1):
    """``function(*args, progress=..., **kwargs)`` run in a :class:`WorkerProcess`; returns its value.

    The worker's progress reports are relayed to ``progress`` (:mod:`lacore.progress`) and,
    between them, ``progress`` is asked every ``poll`` seconds with the last report; when it
    returns True the worker is killed at once and :class:`lacore.progress.Cancelled` is
    raised.  Errors come back as in :func:`raise_worker_error`.  The value must pickle.

    Parameters
    ----------
    function : callable
        A module-level lacore function taking ``progress=`` (pickled by reference).
    args : tuple
    kwargs : dict, optional
    progress : callable, optional
    poll : float
        Seconds between checks for a cancel.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.parallel import call_in_process
    >>> from lacore.shapes.mixing.mixer import build_mixer_bytes
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, F = bar_mesh(n_along=6, n_side=2)
    >>> data = call_in_process(build_mixer_bytes, (np.stack([X, bar_pose(X, 1.0, 0.0)]), F))  # doctest: +SKIP
    """
    from .progress import report
    worker = WorkerProcess(_call_with_progress, (function, tuple(args), dict(kwargs or {})))
    last = (0, 1, "starting a worker process")
    try:
        while True:
            try:
                _, kind, payload = worker.messages.get(timeout=poll)
            except queue.Empty:
                report(progress, *last)
                continue
            if kind == "message":
                last = payload
                report(progress, *last)
            elif kind == "done":
                return payload
            else:
                raise_worker_error(payload)
    finally:
        worker.close()


def _lacore_errors():
    from . import errors
    return {name: obj for name, obj in vars(errors).items()
            if isinstance(obj, type) and issubclass(obj, InputError)}


_LACORE_ERRORS = _lacore_errors()


def close_workers():
    """Kill every worker process still running (e.g. when the Blender add-on is disabled)."""
    with _RUNNING_LOCK:
        running = list(_RUNNING)
    for worker in running:
        worker.close()


def serve(channel_in, channel_out):
    """The worker's side (called by the bootstrap): run one job, sending its messages back.

    Ctrl-C is left to the caller (which closes its workers); when the caller is
    gone (killed, or exited: its end of the pipe is closed), the worker ends at
    its next message, silently.
    """
    def send(kind, payload):
        pickle.dump((kind, payload), channel_out, protocol=pickle.HIGHEST_PROTOCOL)
        channel_out.flush()

    try:
        try:
            function, args = pickle.load(channel_in)
        except EOFError:  # the caller went away before sending the job
            _exit_quietly()
        try:
            value = function(*args, send=lambda message: send("message", message))
        except _CALLER_GONE:
            raise
        except BaseException as exc:  # every failure goes back to the caller, named
            name = type(exc).__name__
            if isinstance(exc, InputError) and name not in _LACORE_ERRORS:
                name = "InputError"  # e.g. a MixerError: the caller gets its one-line message
            send("error", (name, str(exc), traceback.format_exc()))
            return
        send("done", value)
    except _CALLER_GONE:
        _exit_quietly()


#: What writing to the caller raises once it is gone.
_CALLER_GONE = (BrokenPipeError, ConnectionResetError)


def _exit_quietly():
    """End this worker at once: no traceback, no flush of the dead pipe at interpreter exit."""
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()
    os._exit(0)
