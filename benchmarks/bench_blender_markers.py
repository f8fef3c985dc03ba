#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: importing a 5,000-frame, 50-marker C3D take in Blender (bpy, headless).

The seeded synthetic take of benchmarks/bench_markers.py (100 Hz, ~2.7 % occluded in gaps) is
written as C3D and imported with ``bpy.ops.lengths_angles.import_markers`` from the source tree
(scripts/addon_dev.py), best of ``--repeat`` runs in a fresh empty scene each.  Timed:

* ``operator_seconds``: the operator call as a user runs it (read, objects, F-curves, undo push);
* ``read_seconds``: ``lacore.markers.io.read_markers`` alone;
* ``create_seconds``: ``addon.operators_markers.import_take`` alone (objects and bulk F-curves).

Prints one JSON object.

usage: python benchmarks/bench_blender_markers.py [--frames 5000] [--markers 50] [--repeat 5]
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
    parser.add_argument("--frames", type=int, default=5000)
    parser.add_argument("--markers", type=int, default=50)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_bench_"))
    import bpy
    from bench_common import machine_info
    from bench_markers import synthetic_take

    sys.path.insert(0, os.path.join(REPO, "scripts"))
    from addon_dev import load_addon

    pkg = load_addon()
    mio, ops = pkg.lacore.markers.io, pkg.addon.operators_markers
    take = synthetic_take(args.frames, args.markers)
    tmp = tempfile.mkdtemp(prefix="lengths_angles_markers_")
    path = os.path.join(tmp, "take.c3d")
    mio.write_c3d(path, take)
    op_times, read_times, create_times = [], [], []
    for _ in range(args.repeat):
        bpy.ops.wm.read_homefile(use_empty=True)
        t = time.perf_counter()
        assert bpy.ops.lengths_angles.import_markers(filepath=path) == {"FINISHED"}
        op_times.append(time.perf_counter() - t)
        bpy.ops.wm.read_homefile(use_empty=True)
        t = time.perf_counter()
        back = mio.read_markers(path)
        read_times.append(time.perf_counter() - t)
        t = time.perf_counter()
        _, markers = ops.import_take(bpy.context, back, "take")
        create_times.append(time.perf_counter() - t)
    keys = sum(len(fc.keyframe_points) for obj in markers for fc in ops._fcurves_for(obj))
    os.remove(path)
    os.rmdir(tmp)
    result = {"frames": args.frames, "markers": args.markers, "keyframes": keys,
              "occluded_fraction": round(float((~take.visible).mean()), 4),
              "operator_seconds": round(min(op_times), 3), "operator_seconds_all": [round(x, 3) for x in op_times],
              "read_seconds": round(min(read_times), 4), "create_seconds": round(min(create_times), 3),
              "machine": machine_info(blender=bpy.app.version_string)}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
