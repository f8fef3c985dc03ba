# SPDX-License-Identifier: GPL-3.0-or-later
"""Background runs of the long operators: the one mechanism behind In-betweens, Bake, Build Shape Model,
Bind Markers and Fit to Markers.

An operator validates its input and builds a :class:`Run` before writing anything:

* a *job* (:mod:`.jobs`: ``step()``, ``done`` / ``total``, ``cancel()``; lacore only, no bpy);
* an :class:`ObjectWatch`: what the operator read (the object, its mode, its mesh and connectivity,
  the shape keys it used, and extras such as the stored shape model or the marker take);
* a *write* function ``write(obj, job) -> report text``.

The operator (a :class:`RunOperator`) then runs it

* from the user interface (``interactive``, set by ``invoke``): MODAL.  A timer event every
  :data:`TIMER_SECONDS` polls the job, whose ``step()`` runs in one worker thread (Blender keeps
  redrawing and handling events); the progress bar and the status text follow ``done / total``
  even while a long step runs; Esc or right-click cancels (the job is told to stop, a step being
  computed ends in the worker thread and is dropped);
* from scripts, in background mode and from the redo panel: synchronously (:meth:`Run.run`).

Only when the job has finished does :meth:`Run.finish` write: first the watch checks that nothing
it recorded changed meanwhile (an object deleted or renamed, another mode, an edited mesh or key,
a model rebuilt, a take's empties deleted ...), naming the change and writing nothing.  A failed
or cancelled run changes nothing.

A new long operator plugs in with a job object (or :class:`.jobs.CallJob` around a lacore call
taking a ``progress`` callback), a watch and a write function -- e.g. a calibrate-and-fit of a
marker take (a job whose steps calibrate, then fit frame by frame) or enabling a live mixer (a job
whose steps build the reduced-order mixer; the write stores it and installs the handlers)::

    class MY_OT_thing(RunOperator, bpy.types.Operator):
        def invoke(self, context, event):
            self.interactive = True
            return self.execute(context)

        def execute(self, context):
            return self.start_run(context, lambda context: Run(job, ObjectWatch(obj), write))

The step function stays testable headless (modal operators do not run by themselves there):
:meth:`Run.tick` is one step, and :meth:`RunOperator.modal` can be driven with timer events.
"""

import hashlib
import traceback
from concurrent.futures import ThreadPoolExecutor

import bpy
import numpy as np
from bpy.props import BoolProperty

from ..lacore.errors import InputError
from ..lacore.parallel import close_workers
from . import jobs
from .mesh_access import connectivity_digest, mesh_counts, object_mode

__all__ = ["Run", "ObjectWatch", "RunOperator", "ChangedWhileRunning", "failure_warning", "error_text",
           "shutdown", "object_state", "TIMER_SECONDS", "NOTHING_WRITTEN"]

#: Seconds between the timer events that poll a modal run.
TIMER_SECONDS = 0.05
#: The progress bar's scale (``done / total`` of the job).
PROGRESS_STEPS = 1000
NOTHING_WRITTEN = "nothing was written: run again"


class ChangedWhileRunning(InputError):
    """Something the run read changed before its results were written (nothing is written)."""


def failure_warning(failures, what="in-between"):
    """The report's WARNING text for results that failed their checks (written anyway), or None."""
    if not failures:
        return None
    n = len(failures)
    return (f"{n} {what}{'s' if n != 1 else ''} failed the reconstruction checks and {'were' if n != 1 else 'was'} "
            f"written anyway (inspect, undo, or use the Gauss-Newton method): {failures[0]}")


def error_text(exc):
    """The message of an expected input error (:class:`lacore.errors.InputError` and its subclasses); type and
    traceback (console) for anything else (a bug)."""
    if isinstance(exc, InputError):
        return str(exc)
    traceback.print_exc()
    return f"Lengths & Angles failed ({type(exc).__name__}: {exc}); nothing was changed (details in the console)"


def object_state(name):
    """``(name, pointer)`` of the object ``name`` now, ``(name, None)`` if there is none: a watch extra that
    notices a deleted or replaced object (e.g. a marker empty)."""
    obj = bpy.data.objects.get(name)
    return name, None if obj is None else obj.as_pointer()


def _key_hash(mesh, name):
    """Digest of the coordinates of the shape key ``name`` (None if there is none)."""
    kb = mesh.shape_keys.key_blocks.get(name) if mesh.shape_keys is not None else None
    if kb is None:
        return None
    co = np.empty(3 * len(kb.points), np.float32)
    kb.points.foreach_get("co", co)
    return hashlib.blake2b(co.tobytes(), digest_size=16).hexdigest()


def _mesh_state(obj, keys):
    """``(connectivity digest, {key: coordinate digest})`` of a mesh object (Edit Mode changes included)."""
    if obj.mode == 'EDIT':
        obj.update_from_editmode()
    return connectivity_digest(obj.data), {k: _key_hash(obj.data, k) for k in keys}


class ObjectWatch:
    """What a run read from the scene, checked again before its results are written.

    Parameters
    ----------
    obj : bpy.types.Object
        The object the operator works on: its identity, mode and data, and for a mesh its counts and
        connectivity (the fixed fan triangulation) are recorded.
    keys : sequence of str
        Shape keys whose coordinates the run used (digests recorded).
    extras : dict, optional
        ``{description: getter}``: any other state (``getter()`` values compared with ``==``), e.g.
        ``{"The shape model of 'Body'": ...}``; the description starts the message.
    """

    def __init__(self, obj, keys=(), extras=None):
        self.name, self.pointer = obj.name, obj.as_pointer()
        self.mode = obj.mode
        self.data_pointer = None if obj.data is None else obj.data.as_pointer()
        self.keys = list(dict.fromkeys(keys))
        self.counts = self.state = None
        if obj.type == 'MESH':
            self.counts = mesh_counts(obj.data)
            self.state = _mesh_state(obj, self.keys)
        self.extras = [(label, getter, getter()) for label, getter in (extras or {}).items()]

    def check(self):
        """The object as it is now; :class:`ChangedWhileRunning` naming the first change otherwise."""
        obj = bpy.data.objects.get(self.name)
        if obj is None or obj.as_pointer() != self.pointer:
            raise ChangedWhileRunning(f"Object '{self.name}' was deleted or renamed while computing; "
                                      f"{NOTHING_WRITTEN}")
        if obj.mode != self.mode:
            raise ChangedWhileRunning(f"'{obj.name}' changed from {self.mode.title()} Mode to {obj.mode.title()} "
                                      f"Mode while computing; {NOTHING_WRITTEN}")
        if (None if obj.data is None else obj.data.as_pointer()) != self.data_pointer:
            raise ChangedWhileRunning(f"The data of '{obj.name}' was replaced while computing; {NOTHING_WRITTEN}")
        if self.counts is not None:
            now = mesh_counts(obj.data)
            changed = [f"{k} {self.counts[k]} -> {now[k]}" for k in now if now[k] != self.counts[k]]
            if changed:
                raise ChangedWhileRunning(f"The mesh of '{obj.name}' changed while computing ({', '.join(changed)}); "
                                          f"{NOTHING_WRITTEN}")
            topology, keys = _mesh_state(obj, self.keys)
            if topology != self.state[0]:
                raise ChangedWhileRunning(f"The faces of '{obj.name}' changed while computing; {NOTHING_WRITTEN}")
            edited = [k for k in self.keys if keys[k] != self.state[1][k]]
            if edited:
                raise ChangedWhileRunning(f"Shape key '{edited[0]}' was edited, renamed or deleted while computing; "
                                          f"{NOTHING_WRITTEN}")
        for label, getter, value in self.extras:
            if getter() != value:
                raise ChangedWhileRunning(f"{label} changed while computing; {NOTHING_WRITTEN}")
        return obj


class Run:
    """One run of a long operator as plain Python (no event loop): validated, nothing written yet.

    Parameters
    ----------
    job : object
        A job (:mod:`.jobs`): ``step()``, ``done``, ``total``, ``finished``, ``cancel()``, ``status``,
        ``failures``, ``notes``.
    watch : ObjectWatch
    write : callable
        ``write(obj, job) -> report text``, called by :meth:`finish` with the object as it is now.
    what : str
        What a failed result is called in the warning (``"in-between"``, ``"baked frame"`` ...).
    """

    def __init__(self, job, watch, write, what="result"):
        self.job = job
        self.watch = watch
        self._write = write
        self.what = what
        self.cancelled = False

    @property
    def total(self):
        return self.job.total

    @property
    def done(self):
        return self.job.done

    @property
    def finished(self):
        return self.job.finished

    @property
    def failures(self):
        """Results that failed their checks (written anyway, with a WARNING)."""
        return list(self.job.failures)

    @property
    def notes(self):
        """Other things the report should say (a worker process failed and this process took over ...)."""
        return list(self.job.notes)

    def status(self):
        """The status-bar text."""
        return f"Lengths & Angles: {self.job.status} (Esc to cancel)"

    def tick(self):
        """One step of the job (any thread; lacore only); True when it has finished."""
        if self.cancelled:
            raise RuntimeError("the run was cancelled")
        if not self.job.finished:
            self.job.step()
        return self.job.finished

    def run(self, progress=None):
        """All remaining steps (:func:`.jobs.run_job`; ``progress(done, total, message)``)."""
        jobs.run_job(self.job, progress)

    def cancel(self):
        """Stop the job (worker processes killed; a step being computed is dropped).  Nothing was written."""
        self.cancelled = True
        self.job.cancel()

    def warning(self):
        """What the report adds to the result's text as a WARNING (failed checks, notes), or None for an INFO
        report."""
        texts = [failure_warning(self.failures, self.what), *self.notes]
        return "; ".join(t.rstrip(" .;") for t in texts if t) or None

    def finish(self):
        """Check the watch and write the results (a mesh in Edit Mode in Object Mode, and back: shape keys added or
        removed in Edit Mode are undone on leaving it); returns the report text."""
        if self.cancelled or not self.finished:
            raise RuntimeError("finish() before the job has finished")
        obj = self.watch.check()
        if obj.type != 'MESH':
            return self._write(obj, self.job)
        with object_mode(obj):
            return self._write(obj, self.job)


_EXECUTOR = []


def _worker_thread():
    """The one worker thread of the modal runs (created on first use): a job's step runs there while Blender
    keeps redrawing and handling events; it runs lacore only, never bpy."""
    if not _EXECUTOR:
        _EXECUTOR.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="lengths_angles"))
    return _EXECUTOR[0]


def wait_for_worker_thread():
    """Block until the step running in the worker thread (if any) has ended (tests, unregister)."""
    if _EXECUTOR:
        _EXECUTOR[0].submit(lambda: None).result()


def shutdown():
    """Stop the worker thread and kill lacore's worker processes (add-on unregister); a step being computed
    is dropped."""
    while _EXECUTOR:
        _EXECUTOR.pop().shutdown(wait=False, cancel_futures=True)
    close_workers()


class RunOperator:
    """Mixin of the long operators: :meth:`start_run` runs a :class:`Run` modally or synchronously."""

    interactive: BoolProperty(name="Interactive", default=False, options={'HIDDEN', 'SKIP_SAVE'},
                              description="Compute in a worker thread with a progress bar and Esc to cancel (set "
                                          "by the user interface; scripts, background mode and the redo panel "
                                          "run at once)")

    _timer = None
    _future = None
    _run = None

    def start_run(self, context, make_run):
        """Validate (``make_run(context) -> Run``; errors reported, nothing written) and run."""
        try:
            run = make_run(context)
        except Exception as exc:
            self.report({'ERROR'}, error_text(exc))
            return {'CANCELLED'}
        if self.interactive and not bpy.app.background and context.window is not None and not run.finished:
            self._begin_modal(context, run)
            context.window_manager.modal_handler_add(self)
            return {'RUNNING_MODAL'}
        wm = context.window_manager
        wm.progress_begin(0, PROGRESS_STEPS)
        try:
            run.run(lambda done, total, message="": wm.progress_update(_scaled(done, total)))
        except Exception as exc:
            run.cancel()
            self.report({'ERROR'}, error_text(exc))
            return {'CANCELLED'}
        finally:
            wm.progress_end()
        return self._finish_run(run)

    def _finish_run(self, run):
        try:
            message = run.finish()
        except Exception as exc:
            self.report({'ERROR'}, error_text(exc))
            return {'CANCELLED'}
        warning = run.warning()
        # what was done first, then what to look at (a real take's fit always has notes; its report still gives
        # the marker RMS and whether the calibration was reused)
        text = "; ".join(t.rstrip(" .;") for t in (message, warning) if t)
        self.report({'WARNING'} if warning else {'INFO'}, text)
        return {'FINISHED'}

    def _begin_modal(self, context, run):
        """Progress bar, status text and the timer whose events drive :meth:`modal`; a job that can compute
        everything in worker processes does (Blender's Python stays free for the UI)."""
        if hasattr(run.job, "all_in_workers"):
            run.job.all_in_workers = True
        wm = context.window_manager
        self._run = run
        self._future = None
        wm.progress_begin(0, PROGRESS_STEPS)
        self._timer = wm.event_timer_add(TIMER_SECONDS, window=context.window)
        self._status(context, run.status())

    @staticmethod
    def _status(context, text):
        if context.workspace is not None and context.window is not None:
            context.workspace.status_text_set(text)

    def _end_modal(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        self._status(context, None)

    def modal(self, context, event):
        """Timer events poll the step running in the worker thread, show the progress and start the next step;
        Esc / right-click cancels."""
        run = self._run
        if event.type in {'ESC', 'RIGHTMOUSE'} and event.value == 'PRESS':
            run.cancel()  # a step being computed ends in the worker thread and is dropped
            self._future = None
            self._end_modal(context)
            self.report({'WARNING'}, "Cancelled: nothing was changed")
            return {'CANCELLED'}
        if event.type != 'TIMER' or event.timer is not self._timer:
            return {'PASS_THROUGH'}
        if self._future is not None:
            if not self._future.done():
                self._show(context, run)
                return {'RUNNING_MODAL'}
            future, self._future = self._future, None
            try:
                future.result()
            except Exception as exc:
                run.cancel()
                self._end_modal(context)
                self.report({'ERROR'}, error_text(exc))
                return {'CANCELLED'}
        self._show(context, run)
        if run.finished:
            self._end_modal(context)
            self.interactive = False  # a redo-panel change re-runs synchronously (from the session cache)
            return self._finish_run(run)
        self._future = _worker_thread().submit(run.tick)
        return {'RUNNING_MODAL'}

    def _show(self, context, run):
        context.window_manager.progress_update(_scaled(run.done, run.total))
        self._status(context, run.status())

    def cancel(self, context):
        """Blender ends the modal operator (e.g. the window closes): stop the job, write nothing."""
        if self._run is not None:
            self._run.cancel()
        self._end_modal(context)


def _scaled(done, total):
    return int(PROGRESS_STEPS * min(max(done, 0), max(total, 1)) / max(total, 1))
