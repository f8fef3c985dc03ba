"""Shared harness of the Blender-side check scripts (tests/blender/check_*.py).

Each check script runs in its own SUBPROCESS (bpy can be imported once per process,
and BLENDER_USER_RESOURCES must be set before ``import bpy``)::

    BLENDER_USER_RESOURCES=<tmp> python check_xxx.py --zip EXT.zip --workdir DIR --result OUT.json

Importing this module parses those arguments, checks the environment and imports
bpy.  :func:`run_cases` runs the script's cases in order and writes
``{"ok": ..., "cases": {...}}`` to OUT.json; a failed check records the traceback and
exits non-zero.  pytest asserts on the JSON (tests/conftest.py: ``run_blender_check``).
"""

import argparse
import importlib
import json
import os
import sys
import time
import traceback
from types import SimpleNamespace

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
MODULE = "bl_ext.user_default.lengths_angles"


def _parse_args():
    parser = argparse.ArgumentParser()
    parser.add_argument("--zip", required=True)
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--result", required=True)
    return parser.parse_args()


ARGS = _parse_args()
if not os.environ.get("BLENDER_USER_RESOURCES"):
    sys.exit("BLENDER_USER_RESOURCES must be set (to a throw-away directory) before bpy is imported")

import bpy  # noqa: E402

sys.path.insert(0, os.path.join(REPO, "scripts"))  # sample builders (blender_samples, blend_sample_cases)

RESULTS = {}


def case(fn):
    """Run one check, record its duration and the details it returns."""
    t = time.perf_counter()
    details = fn()
    RESULTS[fn.__name__] = {"seconds": round(time.perf_counter() - t, 3), **(details or {})}
    script = os.path.splitext(os.path.basename(sys.argv[0]))[0]
    print(f"[{script}] {fn.__name__}: ok ({RESULTS[fn.__name__]['seconds']} s)", flush=True)


def reset():
    """Empty scene for the next case."""
    bpy.ops.wm.read_homefile(use_empty=True)


def plain(value):
    """An ID property as plain Python data (for snapshots)."""
    return value.to_dict() if hasattr(value, "to_dict") else (value.to_list() if hasattr(value, "to_list") else value)


def draw_panel(panel, context):
    """Draw ``panel`` into a layout that records every call (there is no GUI in background mode).

    Returns the list of ``(method name, args, kwargs)`` the panel called on its layouts.
    """
    from types import SimpleNamespace

    calls = []

    class Layout:
        def __getattr__(self, name):
            def record(*args, **kwargs):
                calls.append((name, args, kwargs))
                return Layout()
            return record

    panel.draw(SimpleNamespace(layout=Layout()), context)
    return calls


def run_cases(cases):
    """Run ``cases`` (functions) in order and write the JSON result; exit 1 on the first failure."""
    t0 = time.perf_counter()
    os.makedirs(ARGS.workdir, exist_ok=True)
    try:
        for fn in cases:
            case(fn)
    except Exception:
        traceback.print_exc()
        with open(ARGS.result, "w") as fh:
            json.dump({"ok": False, "cases": RESULTS, "error": traceback.format_exc()}, fh, indent=1)
        sys.exit(1)
    with open(ARGS.result, "w") as fh:
        json.dump({"ok": True, "cases": RESULTS, "seconds": round(time.perf_counter() - t0, 3),
                   "blender": bpy.app.version_string}, fh, indent=1)


def evaluated(obj):
    """(V', 3) float32 positions of the evaluated object (shape keys, then modifiers)."""
    import numpy as np
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)


def select_only(*objs):
    """Select exactly ``objs`` and make the first the active object."""
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]


# ----------------------------------------------------------------------------- modal runs driven by a test
class FakeOperator:
    """A long operator's run logic (the ``addon.runs.RunOperator`` mixin) on a plain object: modal() driven by
    the test (headless Blender has no window to send events)."""

    def __init__(self):
        self.reports = []
        self.interactive = True

    def report(self, kind, text):
        self.reports.append((sorted(kind)[0], text))


def fake_operator():
    """A :class:`FakeOperator` with the installed extension's ``RunOperator`` mixed in."""
    runs = importlib.import_module(f"{MODULE}.addon.runs")
    return type("Fake", (FakeOperator, runs.RunOperator), {})()


def timer(op):
    """The timer event that polls ``op``'s worker thread."""
    return SimpleNamespace(type='TIMER', value='NOTHING', timer=op._timer)


def esc():
    """An Esc key press."""
    return SimpleNamespace(type='ESC', value='PRESS', timer=None)


def drive(op, run, until=None, timeout=300.0):
    """Timer events to the operator's modal() every 5 ms until it returns something other than RUNNING_MODAL
    or ``until(run)``; returns (state, [(done, total) seen while running])."""
    seen, end = [], time.perf_counter() + timeout
    while time.perf_counter() < end:
        state = op.modal(bpy.context, timer(op))
        seen.append((run.done, run.total))
        if state != {'RUNNING_MODAL'} or (until is not None and until(run)):
            return state, seen
        time.sleep(0.005)
    raise AssertionError(f"the modal run did not progress ({run.done} of {run.total})")
