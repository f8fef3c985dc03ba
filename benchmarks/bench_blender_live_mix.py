#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: playback of live nonlinear mixing in Blender (bpy, headless): ``frame_set`` with three animated
shape-key values, the mesh update included.

Meshes (from :func:`bench_mixer.mesh_keys`):

* ``human13k``: the CC0 rigged body (13,380 vertices), keys left arm raised by 70 degrees, right knee bent by
  35 degrees, torso twisted;
* ``bar50k``: the box bar (210 x 52 segments, ~50k vertices), keys bent by 90 degrees, twisted by 90 degrees,
  and a third key bent and twisted by 45 degrees each.

Per mesh: ``lengths_angles.live_mix_enable`` (synchronous, ``enable_seconds``: mixer build + storing it), the
three key values keyframed over ``--frames`` frames (different values at frames 1, 34, 67, 100: every frame
mixes new weights), then ``--frames`` calls of ``scene.frame_set(f)`` followed by
``evaluated_depsgraph_get()`` (the evaluated mesh is up to date) -- timed, ``fps`` = frames / seconds.
``linear_fps``: the same loop before enabling (Blender's own linear mixing).  ``mix_ms``: the median time of
:meth:`ShapeMixer.mix` per frame (inside the handler); ``glue_ms``: the rest of a frame beyond the linear
playback (reading values, checking the keys, placing and writing the mix key, Blender's second evaluation).
``*_cpu_ms``: CPU time per frame (all threads; on a shared machine the wall time also holds waiting).
``max_error_of_diagonal``: the evaluated mesh at the last frame against lacore's mix of the same weights (cold start).

Prints one JSON object.  usage (bpy + SciPy in one Python, see ``make bench``):
python benchmarks/bench_blender_live_mix.py [human13k] [bar50k] [--frames 100] [--json FILE]
"""

import argparse
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

MESHES = ("human13k", "bar50k")


def bench_keys(name):
    """``(keys (4, V, 3), faces)``: the basis and three keys."""
    import numpy as np
    from bench_mixer import mesh_keys
    from bench_multires import twist

    from lacore.samples.simple_deform import simple_deform_bend

    keys, faces = mesh_keys(name)
    if len(keys) < 4:
        B = keys[0]
        keys = np.concatenate([keys, simple_deform_bend(twist(B, np.pi / 4, axis=0), np.pi / 4)[None]])
    return keys[:4], faces


def bench_mesh(bpy, pkg, name, n_frames):
    import numpy as np

    from lacore.geometry.rigid import rigid_align
    from lacore.shapes import ShapeMixer

    live_mix = pkg.addon.live_mix
    keys, faces = bench_keys(name)
    bpy.ops.wm.read_homefile(use_empty=True)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(keys[0].tolist(), [], faces.tolist())
    obj = bpy.data.objects.new(name, mesh)
    scene = bpy.context.scene
    scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.shape_key_add(name="Basis", from_mix=False)
    names = ["Key1", "Key2", "Key3"]
    for n, K in zip(names, keys[1:], strict=True):
        kb = obj.shape_key_add(name=n, from_mix=False)
        kb.data.foreach_set("co", K.astype(np.float32).ravel())
        kb.value = 0.0
    kbs = obj.data.shape_keys.key_blocks
    values = {"Key1": (0.0, 1.0, 0.3, 0.8), "Key2": (0.1, 0.4, 0.9, 0.2), "Key3": (0.5, 0.0, 0.6, 1.0)}
    for n, vals in values.items():
        for f, v in zip((1, 34, 67, 100), vals, strict=True):
            kbs[n].value = v
            kbs[n].keyframe_insert("value", frame=f)

    def playback():
        scene.frame_set(n_frames)
        bpy.context.evaluated_depsgraph_get()
        mix_times = []
        t, cpu = time.perf_counter(), time.process_time()
        for f in range(1, n_frames + 1):
            scene.frame_set(f)
            bpy.context.evaluated_depsgraph_get()
            s = live_mix.status(obj.data)
            if s is not None:
                mix_times.append(s["mix_seconds"])
        return time.perf_counter() - t, mix_times, time.process_time() - cpu

    linear_seconds, _, linear_cpu = playback()
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.live_mix_enable() == {"FINISHED"}
    enable_seconds = time.perf_counter() - t
    state = live_mix.status(obj.data)
    seconds, mix_times, cpu = playback()
    # the evaluated mesh at the last frame = lacore's mix of its weights, placed on the linear blend
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    w = np.array([kbs[n].value for n in names])
    K32 = keys.astype(np.float32).astype(np.float64)
    linear = K32[0] + np.tensordot(w, K32[1:] - K32[0], axes=1)
    mixer = live_mix._live(obj.data).mixer
    want = rigid_align(ShapeMixer.mix(mixer, w, warm_start=False).vertices, linear)
    diag = float(np.linalg.norm(np.ptp(keys[0], axis=0)))
    frame_ms = 1000 * seconds / n_frames
    linear_ms = 1000 * linear_seconds / n_frames
    mix_ms = 1000 * float(np.median(mix_times))
    return {"vertices": int(len(keys[0])), "faces": int(len(faces)), "keys": 3, "frames": n_frames,
            "enable_seconds": round(enable_seconds, 3),
            "build_seconds": {k: round(v, 3) for k, v in mixer.build_seconds.items()},
            "reduced_size": int(mixer.reduced_size), "fps": round(n_frames / seconds, 1),
            "frame_ms": round(frame_ms, 2), "frame_cpu_ms": round(1000 * cpu / n_frames, 2),
            "linear_fps": round(n_frames / linear_seconds, 1), "linear_cpu_ms": round(1000 * linear_cpu / n_frames, 2),
            "mix_ms": round(mix_ms, 2), "glue_ms": round(frame_ms - linear_ms - mix_ms, 2),
            "stale": state["stale"], "max_error_of_diagonal": float(np.abs(co.reshape(-1, 3) - want).max() / diag),
            "stored_megabytes": round(len(live_mix.stored_npz(obj.data[live_mix.MIXER_PROP])) / 1e6, 2)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="*", default=list(MESHES), help=f"of {', '.join(MESHES)}")
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--json", default=None, help="also write the result to this file")
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_bench_"))
    import bpy  # once per process, before the add-on
    from bench_common import emit, machine_info

    sys.path.insert(0, os.path.join(REPO, "scripts"))
    from addon_dev import load_addon

    pkg = load_addon()
    out = {"benchmark": "blender_live_mix", "blender": bpy.app.version_string,
           "machine": machine_info(threads={k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS",
                                                                           "OMP_NUM_THREADS")}),
           "meshes": {}}
    for name in args.meshes:
        out["meshes"][name] = bench_mesh(bpy, pkg, name, args.frames)
        print(f"[bench_blender_live_mix] {name}: {out['meshes'][name]}", file=sys.stderr, flush=True)
    emit(out, args.json)


if __name__ == "__main__":
    main()
