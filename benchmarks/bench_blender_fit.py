#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: Fit to Markers inside Blender (bpy, headless) against lacore's own fit of the same data.

The coarse CC0 human (``lacore.samples.human``, coarse body), ``--train`` skinned training poses as
shape keys, Build Shape Model, a held-out ``--frames``-frame take (41 markers, 8 mm off the skin, 0.5 mm
noise, ~10 % occluded) written as C3D and imported, Bind Markers at frame 1, then:

* ``blender_seconds``: ``bpy.ops.lengths_angles.fit_markers()`` as a user runs it (background mode:
  synchronous), i.e. reading the take from the F-curves, the fit, writing the PC2 and the modifier;
* ``lacore_seconds``: ``lacore.markers.fitting.fit_markers`` on the same model, binding and marker
  positions, in the same process (best of ``--repeat`` each, interleaved);
* ``setup_seconds`` / ``finish_seconds``: the operator's own work around that call (reading the take
  from the F-curves; writing the PC2 and the modifier), best of 5: the operator's time is lacore's plus
  these (``overhead_over_lacore``), a figure the machine's load does not blur.

Prints one JSON object.

usage: python benchmarks/bench_blender_fit.py [--train 30] [--frames 60] [--repeat 2]
"""

import argparse
import json
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
sys.path.insert(0, HERE)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train", type=int, default=30)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_bench_"))
    import bpy
    import numpy as np
    from bench_common import machine_info

    sys.path.insert(0, os.path.join(REPO, "scripts"))
    from addon_dev import load_addon

    pkg = load_addon()
    fit_markers = pkg.lacore.markers.fitting.fit_markers  # the add-on's own copy of lacore
    from lacore.markers.io import MarkerTake, write_c3d
    from lacore.samples.human import load_human
    from lacore.samples.markers import observe_markers, place_markers

    fit_ops = pkg.addon.operators_fit
    body = load_human(coarse=True)
    training, _ = body.random_poses(args.train, seed=1)
    true = body.take(args.frames, seed=7)[0]
    names, binding = place_markers(body)
    x = observe_markers(true, body.faces, binding, noise=0.005, occlusion=0.1, seed=3)
    x[0] = observe_markers(true[:1], body.faces, binding, noise=0.005, occlusion=0.0, seed=3)[0]  # bind frame
    tmp = tempfile.mkdtemp(prefix="lengths_angles_fit_")
    c3d_path = os.path.join(tmp, "take.c3d")
    write_c3d(c3d_path, MarkerTake(labels=tuple(names), positions=x / 10.0, rate=100.0, units="m"), units="mm")

    bpy.ops.wm.read_homefile(use_empty=True)
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
    bpy.context.view_layer.objects.active = obj
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.build_model() == {"FINISHED"}
    model_seconds = time.perf_counter() - t
    assert bpy.ops.lengths_angles.import_markers(filepath=c3d_path, scale=10.0) == {"FINISHED"}
    take = bpy.data.objects["take"]
    kb = obj.shape_key_add(name="bind pose", from_mix=False)
    kb.data.foreach_set("co", true[0].astype(np.float32).ravel())
    kb.value = 1.0
    scene.frame_set(1)
    for o in bpy.context.view_layer.objects:
        o.select_set(o in (obj, take))
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.lengths_angles.bind_markers(warn_distance=0.2) == {"FINISHED"}
    obj.shape_key_remove(kb)
    scene.frame_start, scene.frame_end = 1, args.frames

    blender_times, lacore_times = [], []
    inputs = fit_ops.fit_inputs(bpy.context, obj, 1, args.frames)
    for _ in range(args.repeat):
        t = time.perf_counter()
        assert bpy.ops.lengths_angles.fit_markers() == {"FINISHED"}
        blender_times.append(time.perf_counter() - t)
        t = time.perf_counter()
        res = fit_markers(inputs["model"], inputs["markers"], inputs["binding"])
        lacore_times.append(time.perf_counter() - t)
    # the operator's own work around lacore's fit: reading the take (F-curves) and writing PC2 + modifier
    setup_times, finish_times = [], []
    for _ in range(5):
        t = time.perf_counter()
        run = fit_ops.fit_run(bpy.context, obj, 1, args.frames)  # validation + reading the take (F-curves)
        setup_times.append(time.perf_counter() - t)
        run.job.result, run.job.finished = res, True  # the fit computed above
        t = time.perf_counter()
        run.finish()  # the checks before writing, the PC2 and the modifier
        finish_times.append(time.perf_counter() - t)
    overhead = min(setup_times) + min(finish_times)
    err = np.linalg.norm(res.vertices - true, axis=2).mean()
    T = args.frames
    result = {"vertices": int(len(body.vertices)), "training_poses": args.train, "modes": int(inputs["model"].n_modes),
              "frames": T, "markers": len(names), "occluded_fraction": round(float(np.isnan(x[..., 0]).mean()), 3),
              "model_seconds": round(model_seconds, 3),
              "blender_seconds": round(min(blender_times), 3), "lacore_seconds": round(min(lacore_times), 3),
              "blender_seconds_per_frame": round(min(blender_times) / T, 4),
              "lacore_seconds_per_frame": round(min(lacore_times) / T, 4),
              "blender_over_lacore": round(min(blender_times) / min(lacore_times), 3),
              "setup_seconds": round(min(setup_times), 4), "finish_seconds": round(min(finish_times), 4),
              "overhead_over_lacore": round(overhead / min(lacore_times), 4),
              "all_blender_seconds": [round(v, 3) for v in blender_times],
              "all_lacore_seconds": [round(v, 3) for v in lacore_times],
              "mean_error_mm": round(100 * float(err), 2),
              "pc2_bytes": os.path.getsize(bpy.path.abspath(obj.modifiers["LA Fit"].filepath)),
              "machine": machine_info(blender=bpy.app.version_string)}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
