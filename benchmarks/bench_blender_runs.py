#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: Build Shape Model, Bind Markers (with ICP) and Fit to Markers through the add-on's run mechanism
(addon/runs.py) inside Blender (bpy, headless), as the modal operators run them.

The CC0 human (coarse body by default, ``--full`` for the full one), ``--train`` skinned training poses as
shape keys, a ``--frames``-frame take (41 markers) imported from C3D.  For each operator the run is driven
the way Blender drives the modal operator: a timer event every 5 ms calls its ``modal()``, the job's step
runs in the worker thread.  Per operator:

* ``seconds``: wall time from the first timer event to FINISHED (written);
* ``progress_updates``: distinct progress values the bar showed (model stages, ICP iterations, frames);
* ``main_thread_longest_interval_seconds``: the longest time from one timer event to the next one handled
  (5 ms asked for; more while the step holds Python's lock: how long Blender's Python-drawn UI can stall);
* ``cancel_seconds``: from Esc (after the first progress unit) to the end of the cancelled step in the
  worker thread (how long a cancelled computation goes on in the background).

Prints one JSON object.

usage: python benchmarks/bench_blender_runs.py [--full] [--train 20] [--frames 20] [--only ...] [--json FILE]
"""

import argparse
import json
import os
import sys
import tempfile
import time
from types import SimpleNamespace

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
sys.path.insert(0, HERE)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="the full human instead of the coarse one")
    parser.add_argument("--train", type=int, default=20)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--only", nargs="+", choices=["build_model", "bind_markers_icp", "fit_markers"],
                        help="these operators only (Bind and Fit need the model: Build runs first anyway)")
    parser.add_argument("--json", default=None, help="also write the result to this file (Blender prints its "
                                                     "own report lines on stdout)")
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_bench_"))
    import bpy
    import numpy as np
    from bench_common import machine_info

    sys.path.insert(0, os.path.join(REPO, "scripts"))
    from addon_dev import load_addon

    pkg = load_addon()
    from lacore.markers.io import MarkerTake, write_c3d
    from lacore.samples.human import load_human
    from lacore.samples.markers import observe_markers, place_markers

    fit_ops, runs = pkg.addon.operators_fit, pkg.addon.runs
    body = load_human(coarse=not args.full)
    training, _ = body.random_poses(args.train, seed=1)
    true = body.take(args.frames, seed=7)[0]
    names, binding = place_markers(body)
    x = observe_markers(true, body.faces, binding, noise=0.005, occlusion=0.0, seed=3)
    tmp = tempfile.mkdtemp(prefix="lengths_angles_runs_")
    c3d_path = os.path.join(tmp, "take.c3d")
    write_c3d(c3d_path, MarkerTake(labels=tuple(names), positions=x / 10.0, rate=100.0, units="m"), units="mm")

    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(tmp, "bench.blend"))
    mesh = bpy.data.meshes.new("Body")
    mesh.from_pydata(body.vertices.tolist(), [], body.faces.tolist())
    obj = bpy.data.objects.new("Body", mesh)
    scene = bpy.context.scene
    scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    for k, X in enumerate(training):
        kb = obj.shape_key_add(name=f"train{k:02d}", from_mix=False)
        kb.data.foreach_set("co", X.astype(np.float32).ravel())
        kb.value = 0.0
    kb = obj.shape_key_add(name="LA bind pose", from_mix=False)  # an add-on-like name: not a training key
    kb.data.foreach_set("co", true[0].astype(np.float32).ravel())
    kb.value = 1.0
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.lengths_angles.import_markers(filepath=c3d_path, scale=10.0) == {"FINISHED"}
    take = bpy.data.objects["take"]
    scene.frame_set(1)
    scene.frame_start, scene.frame_end = 1, args.frames
    bpy.context.view_layer.objects.active = obj

    class Operator(runs.RunOperator):
        def __init__(self):
            self.reports, self.interactive = [], True

        def report(self, kind, text):
            self.reports.append((sorted(kind)[0], text))

    def drive(make, cancel=False):
        op, run = Operator(), make()
        op._begin_modal(bpy.context, run)
        seen, longest = set(), 0.0
        t0 = last = time.perf_counter()
        while True:
            state = op.modal(bpy.context, SimpleNamespace(type='TIMER', value='NOTHING', timer=op._timer))
            now = time.perf_counter()
            longest = max(longest, now - last)  # the 5 ms sleep + waiting for Python's lock + modal()
            seen.add(run.done)
            if cancel and run.done > 0:
                future, t = op._future, time.perf_counter()
                op.modal(bpy.context, SimpleNamespace(type='ESC', value='PRESS', timer=None))
                runs.wait_for_worker_thread()
                return {"cancel_seconds": round(time.perf_counter() - t, 3),
                        "cancelled_in_step": future is not None and future.exception() is not None}
            if state != {'RUNNING_MODAL'}:
                return {"state": sorted(state), "seconds": round(now - t0, 3), "progress_updates": len(seen),
                        "total": run.total, "main_thread_longest_interval_seconds": round(longest, 3),
                        "reports": [r[0] for r in op.reports]}
            time.sleep(0.005)
            last = time.perf_counter()

    makes = {"build_model": lambda: fit_ops.model_run(obj),
             "bind_markers_icp": lambda: fit_ops.bind_run(bpy.context, obj, take, align=True),
             "fit_markers": lambda: fit_ops.fit_run(bpy.context, obj, 1, args.frames)}
    result = {"vertices": len(body.vertices), "training_poses": args.train, "frames": args.frames,
              "markers": len(names), "machine": machine_info(), "operators": {}}
    # what a skipped operator leaves for the next ones: a model, a binding (without ICP: quick)
    prerequisite = {"build_model": makes["build_model"],
                    "bind_markers_icp": lambda: fit_ops.bind_run(bpy.context, obj, take)}
    for name, make in makes.items():
        if args.only and name not in args.only:
            if name in prerequisite:
                drive(prerequisite[name])
            continue
        entry = drive(make, cancel=True)
        entry.update(drive(make))
        result["operators"][name] = entry
    text = json.dumps(result, indent=1)
    if args.json:
        with open(args.json, "w") as fh:
            fh.write(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
