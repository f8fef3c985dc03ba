# SPDX-License-Identifier: GPL-3.0-or-later
"""Demo, Blender motion-capture part (run by scripts/demo.py in its own process: bpy can be imported once).

Builds the coarse human as a mesh with its training poses as shape keys, then runs the add-on's
Build Shape Model, Import Markers (C3D, scale 10: metres -> decimetres, the body's unit), Bind
Markers (at frame 1, the mesh posed like the take's first frame by a temporary shape key) and
Fit to Markers (PC2 point cache played by a Mesh Cache modifier) operators, saves
``OUTPUT_DIR/human_mocap_fit.blend`` and writes ``human_mocap_fit.json`` with the timings and the
mean per-vertex error of the evaluated (Mesh Cache) mesh vs the true poses.

usage: python scripts/demo_mocap_blender.py OUTPUT_DIR INPUTS.npz TAKE.c3d

``INPUTS.npz``: ``faces`` (F, 3), ``basis`` (V, 3), ``training`` (K, V, 3), ``true`` (T, V, 3) in decimetres.
"""

import json
import os
import sys
import time

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from addon_dev import load_addon


def make_body(faces, basis, training, names=None):
    """Mesh object 'Body' with Basis + one shape key (value 0) per training pose (named ``names``, default
    ``train00``, ``train01`` ...)."""
    mesh = bpy.data.meshes.new("Body")
    mesh.from_pydata(basis.tolist(), [], faces.tolist())
    obj = bpy.data.objects.new("Body", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    for k, X in enumerate(training):
        kb = obj.shape_key_add(name=f"train{k:02d}" if names is None else names[k], from_mix=False)
        kb.data.foreach_set("co", X.astype(np.float32).ravel())
        kb.value = 0.0  # (new keys are at 1 in Blender 5)
    return obj


def select_only(*objs):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]


def evaluated_vertices(obj):
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)


def main(out_dir, inputs_path, c3d_path):
    load_addon()
    inputs = dict(np.load(inputs_path))
    true = inputs["true"]
    T = len(true)
    bpy.ops.wm.read_homefile(use_empty=True)
    blend = os.path.join(out_dir, "human_mocap_fit.blend")
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups next to the outputs
    bpy.ops.wm.save_as_mainfile(filepath=blend)  # the point cache is written next to the .blend
    scene = bpy.context.scene
    obj = make_body(inputs["faces"], inputs["basis"], inputs["training"])
    select_only(obj)
    timings = {}
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.build_model(n_modes=5) == {"FINISHED"}
    timings["build_model"] = time.perf_counter() - t
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.import_markers(filepath=c3d_path, scale=10.0) == {"FINISHED"}
    timings["import_markers"] = time.perf_counter() - t
    take = bpy.data.objects[os.path.splitext(os.path.basename(c3d_path))[0]]
    kb = obj.shape_key_add(name="bind pose", from_mix=False)
    kb.data.foreach_set("co", true[0].astype(np.float32).ravel())
    kb.value = 1.0
    scene.frame_set(1)
    select_only(obj, take)
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.bind_markers(warn_distance=0.2) == {"FINISHED"}
    timings["bind_markers"] = time.perf_counter() - t
    obj.shape_key_remove(kb)
    scene.frame_start, scene.frame_end = 1, T
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.fit_markers() == {"FINISHED"}
    timings["fit_markers"] = time.perf_counter() - t
    mod = obj.modifiers["LA Fit"]
    evaluated = []
    for f in range(1, T + 1):
        scene.frame_set(f)
        evaluated.append(evaluated_vertices(obj))
    err_mm = np.linalg.norm(np.array(evaluated, float) - true, axis=2) * 100.0  # decimetres -> mm
    scene.frame_set(1)
    bpy.ops.wm.save_mainfile()
    result = {"frames": T, "vertices": len(obj.data.vertices), "markers": len(take.children),
              "modifier": {"type": mod.type, "cache_format": mod.cache_format, "filepath": mod.filepath},
              "pc2": os.path.basename(bpy.path.abspath(mod.filepath)), "saved_by": bpy.app.version_string,
              "mean_vertex_error_mm": float(err_mm.mean()), "max_vertex_error_mm": float(err_mm.max()),
              "seconds": {k: round(v, 3) for k, v in timings.items()}}
    with open(os.path.join(out_dir, "human_mocap_fit.json"), "w") as fh:
        json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main(*sys.argv[1:4])
