#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: In-betweens by the live mixer in Blender (bpy, headless), the mixer's build included.

Mesh and keys as :mod:`bench_blender_live_mix` (``bar50k``: ~50k vertices, keys bent, twisted, both;
``human13k``: the CC0 body with three pose keys).  Per mesh, first without a live mixer:
``lengths_angles.interpolate`` of ``--count`` evenly spaced in-betweens from the basis to the first key with the
default method there (``path_method``: Path from 5,000 vertices), everything from the keys included
(``path_seconds``, ``path_cpu_seconds``); the session cache is then cleared so that the mixer starts cold.
Then ``lengths_angles.live_mix_enable``
(synchronous: build + storing the mixer, ``enable_seconds``; the build by stage ``build_seconds``), then
``lengths_angles.interpolate`` of ``--count`` evenly spaced in-betweens from the basis to the first key
with the default method (the mixer on a live mesh: ``method``), ``inbetweens_seconds``; ``total_seconds``
= both.  Every ``*_seconds`` has its ``*_cpu_seconds`` (CPU time of the process): on a machine shared
with other jobs the wall time is a multiple of it, and the CPU time is what the work costs.  Then the same in-betweens
with the Gauss-Newton method (``gauss_newton_seconds``) and the RMS vertex distance of every mixer
in-between to its Gauss-Newton one over the bounding-box diagonal (``rms_of_diagonal``, max and all; for the
Path in-betweens ``path_rms_of_diagonal``).

Prints one JSON object.  usage (bpy + SciPy in one Python, see ``make bench``):
python benchmarks/bench_blender_mixer_inbetweens.py [bar50k] [human13k] [--count 10] [--no-mixer] [--json FILE]
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

MESHES = ("bar50k", "human13k")


def key_coords(obj, names):
    import numpy as np

    out = []
    for n in names:
        kb = obj.data.shape_keys.key_blocks[n]
        c = np.empty(3 * len(kb.points), np.float32)
        kb.points.foreach_get("co", c)
        out.append(c.reshape(-1, 3).astype(np.float64))
    return np.array(out)


def bench_mesh(bpy, pkg, name, count, with_mixer=True):
    import numpy as np
    from bench_blender_live_mix import bench_keys

    ops_mod = pkg.addon.operators_interpolate
    naming = pkg.addon.naming
    keys, faces = bench_keys(name)
    bpy.ops.wm.read_homefile(use_empty=True)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(keys[0].tolist(), [], faces.tolist())
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.shape_key_add(name="Basis", from_mix=False)
    for i, K in enumerate(keys[1:], start=1):
        kb = obj.shape_key_add(name=f"Key{i}", from_mix=False)
        kb.data.foreach_set("co", K.astype(np.float32).ravel())
        kb.value = 0.0
    factors = [i / (count + 1) for i in range(1, count + 1)]
    names = [naming.inbetween_key_name("Basis", "Key1", t) for t in factors]
    ctx = bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj])
    with ctx:
        path_method = ops_mod.default_method(obj, ["Basis", "Key1"])
        t, c = time.perf_counter(), time.process_time()
        assert bpy.ops.lengths_angles.interpolate(key_from="Basis", key_to="Key1", count=count) == {"FINISHED"}
        path_seconds, path_cpu = time.perf_counter() - t, time.process_time() - c
        path = key_coords(obj, names)
        pkg.addon.session.clear()
        if with_mixer:
            t, c = time.perf_counter(), time.process_time()
            assert bpy.ops.lengths_angles.live_mix_enable() == {"FINISHED"}
            enable, enable_cpu = time.perf_counter() - t, time.process_time() - c
            method = ops_mod.default_method(obj, ["Basis", "Key1"])
            t, c = time.perf_counter(), time.process_time()
            assert bpy.ops.lengths_angles.interpolate(key_from="Basis", key_to="Key1", count=count) == {"FINISHED"}
            inb, inb_cpu = time.perf_counter() - t, time.process_time() - c
            mixed = key_coords(obj, names)
        t, c = time.perf_counter(), time.process_time()
        assert bpy.ops.lengths_angles.interpolate(key_from="Basis", key_to="Key1", count=count,
                                                  method='GAUSS_NEWTON') == {"FINISHED"}
        gn_seconds, gn_cpu = time.perf_counter() - t, time.process_time() - c
        gn = key_coords(obj, names)
    diag = float(np.linalg.norm(np.ptp(keys[0], axis=0)))
    path_rms = np.sqrt(np.mean(np.sum((path - gn) ** 2, axis=2), axis=1)) / diag
    out = {"vertices": int(len(keys[0])), "faces": int(len(faces)), "keys": int(len(keys)), "count": count,
           "gauss_newton_seconds": round(gn_seconds, 3), "gauss_newton_cpu_seconds": round(gn_cpu, 3),
           "path_method": path_method, "path_seconds": round(path_seconds, 3), "path_cpu_seconds": round(path_cpu, 3),
           "path_rms_of_diagonal_max": float(path_rms.max()), "path_rms_of_diagonal": [float(r) for r in path_rms]}
    if not with_mixer:
        return out
    rms = np.sqrt(np.mean(np.sum((mixed - gn) ** 2, axis=2), axis=1)) / diag
    mixer = pkg.addon.live_mix._live(obj.data).mixer
    return out | {"method": method, "reduced_size": int(mixer.reduced_size), "enable_seconds": round(enable, 3),
            "enable_cpu_seconds": round(enable_cpu, 3),
            "build_seconds": {k: round(v, 3) for k, v in mixer.build_seconds.items()},
            "build_cpu_seconds": {k: round(v, 3) for k, v in mixer.build_cpu_seconds.items()},
            "inbetweens_seconds": round(inb, 3), "inbetweens_cpu_seconds": round(inb_cpu, 3),
            "total_seconds": round(enable + inb, 3), "total_cpu_seconds": round(enable_cpu + inb_cpu, 3),
            "rms_of_diagonal_max": float(rms.max()),
            "rms_of_diagonal": [float(r) for r in rms]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="*", default=list(MESHES), help=f"of {', '.join(MESHES)}")
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--no-mixer", action="store_true", help="only the Path in-betweens and Gauss-Newton")
    parser.add_argument("--json", default=None, help="also write the result to this file")
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_bench_"))
    import bpy  # once per process, before the add-on
    from bench_common import emit, machine_info

    sys.path.insert(0, os.path.join(REPO, "scripts"))
    from addon_dev import load_addon

    pkg = load_addon()
    out = {"benchmark": "blender_mixer_inbetweens", "blender": bpy.app.version_string,
           "machine": machine_info(threads={k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS",
                                                                           "OMP_NUM_THREADS")}),
           "meshes": {}}
    for name in args.meshes:
        out["meshes"][name] = bench_mesh(bpy, pkg, name, args.count, not args.no_mixer)
        print(f"[bench_blender_mixer_inbetweens] {name}: {out['meshes'][name]}", file=sys.stderr, flush=True)
    emit(out, args.json)


if __name__ == "__main__":
    main()
