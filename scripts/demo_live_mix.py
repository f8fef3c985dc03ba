# SPDX-License-Identifier: GPL-3.0-or-later
"""Demo, live mixing part (run by scripts/demo.py in its own process: bpy can be imported once).

The CC0 body (13,380 vertices) with three pose keys (:func:`lacore.samples.human.pose_keys`: left arm raised by 70
degrees, right knee bent by 35, torso twisted) as a mesh object ``Body``; the add-on's Enable Live Mixing makes
Blender's own sliders show the lengths-and-angles mix.  At ``ArmRaised`` = 0.5 the evaluated mesh is compared with
Blender's linear mix of the same values and with the body skinned with the arm raised by 35 degrees (half the key's
angle): the arm's length, shoulder to fingertip, and the RMS distance (after the best rigid motion) over the bounding
box diagonal.  The sliders are then keyframed (frames 1-48), played once with ``frame_set`` (frames per second of
this machine, mesh update included), and the scene is saved to ``OUTPUT_DIR/human_live_mix.blend`` (press Play: the
mesh follows the keyframed sliders live) with ``human_live_mix.json``; ``human_live_mix.png`` shows the three shapes
side by side (rendering is skipped with a message where it cannot run).

usage: python scripts/demo_live_mix.py OUTPUT_DIR INPUTS.npz [--no-render]

``INPUTS.npz``: ``faces`` (F, 3), ``keys`` (K, V, 3) decimetres (y up), ``names`` (K,), ``half`` (V, 3) the
skinned pose at half the first key's angle, ``shoulder`` and ``fingertip`` (vertex indices).
"""

import importlib
import json
import os
import sys
import time

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from addon_dev import load_addon
from demo_blender import MARGIN, layout_row, setup_camera_and_labels
from demo_mocap_blender import evaluated_vertices, make_body, select_only

#: Frames of the keyframed sliders: (frame, ArmRaised, KneeBent, TorsoTwisted).
KEYFRAMES = ((1, 0.0, 0.0, 0.0), (16, 1.0, 0.0, 0.5), (32, 0.5, 1.0, 1.0), (48, 0.0, 0.0, 0.0))


def shape_numbers(pkg, X, reference, shoulder, fingertip, diagonal):
    """The arm's length (cm) and the RMS / largest distance to ``reference`` after the best rigid motion."""
    rigid = importlib.import_module(pkg.__name__ + ".lacore.geometry.rigid")
    Y = rigid.rigid_align(np.asarray(X, np.float64), reference)
    d = np.linalg.norm(Y - reference, axis=1)
    return {"arm_length_cm": 10.0 * float(np.linalg.norm(X[fingertip] - X[shoulder])),
            "rms_per_diagonal": float(np.sqrt(np.mean(d ** 2)) / diagonal), "max_distance_cm": 10.0 * float(d.max())}


def render_picture(bpy_objects, texts, path):
    """The three shapes side by side with their labels (Workbench, one PNG)."""
    labels = setup_camera_and_labels(bpy_objects)
    for obj, text in zip(bpy_objects, texts, strict=True):
        labels[obj.name].data.body = text
        labels[obj.name].data.size = 0.9
    cam = bpy.context.scene.camera
    width, height = layout_row(bpy_objects, labels, cam)
    scene = bpy.context.scene
    cam.data.ortho_scale = width + 2 * MARGIN
    scene.render.resolution_x = 1200
    scene.render.resolution_y = int(round(1200 * (height + 2 * MARGIN) / (width + 2 * MARGIN)))
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    return path


def main(out_dir, inputs_path, render=True):
    pkg = load_addon()
    inputs = dict(np.load(inputs_path))
    names = [str(n) for n in inputs["names"]]
    keys, faces, half = inputs["keys"], inputs["faces"], inputs["half"]
    shoulder, fingertip = int(inputs["shoulder"]), int(inputs["fingertip"])
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups next to the outputs
    scene = bpy.context.scene
    obj = make_body(faces, keys[0], keys[1:], names=names[1:])
    obj.rotation_euler = (np.pi / 2, 0.0, 0.0)  # the body's y up -> Blender's z up
    select_only(obj)
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.live_mix_enable() == {"FINISHED"}
    enable_seconds = time.perf_counter() - t
    blocks = obj.data.shape_keys.key_blocks
    blocks[names[1]].value = 0.5
    live = evaluated_vertices(obj).astype(np.float64)
    linear = keys[0] + 0.5 * (keys[1] - keys[0])
    diagonal = float(np.linalg.norm(np.ptp(keys[0], axis=0)))
    numbers = {name: shape_numbers(pkg, X, half, shoulder, fingertip, diagonal)
               for name, X in (("blender_linear", linear), ("live_mix", live), ("skinned_half_angle", half))}
    numbers["rest"] = {"arm_length_cm": 10.0 * float(np.linalg.norm(keys[0][fingertip] - keys[0][shoulder]))}
    status = pkg.addon.live_mix.status(obj.data)
    for frame, *values in KEYFRAMES:
        for name, value in zip(names[1:], values, strict=True):
            blocks[name].value = value
            blocks[name].keyframe_insert("value", frame=frame)
    scene.frame_start, scene.frame_end = KEYFRAMES[0][0], KEYFRAMES[-1][0]
    frames = range(scene.frame_start, scene.frame_end + 1)
    t = time.perf_counter()
    for f in frames:
        scene.frame_set(f)
        obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    fps = len(frames) / (time.perf_counter() - t)
    scene.frame_set(1)
    blend = os.path.join(out_dir, "human_live_mix.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend, compress=True)
    picture = None
    if render:
        try:
            shapes = []
            for name, X in (("Linear", linear), ("LiveMix", live), ("Skinned35", half)):
                mesh = bpy.data.meshes.new(name)
                mesh.from_pydata(X.tolist(), [], faces.tolist())
                shape = bpy.data.objects.new(name, mesh)
                scene.collection.objects.link(shape)
                shape.rotation_euler = obj.rotation_euler
                shapes.append(shape)
            obj.hide_render = True
            n = {k: numbers[k] for k in ("blender_linear", "live_mix", "skinned_half_angle")}
            texts = [f"Blender's linear mix, ArmRaised 0.5\narm {n['blender_linear']['arm_length_cm']:.1f} cm, "
                     f"{100 * n['blender_linear']['rms_per_diagonal']:.2f} % off",
                     f"Live mix (Lengths & Angles)\narm {n['live_mix']['arm_length_cm']:.1f} cm, "
                     f"{100 * n['live_mix']['rms_per_diagonal']:.2f} % off",
                     f"Skinned, arm raised 35\u00b0\narm {n['skinned_half_angle']['arm_length_cm']:.1f} cm"]
            picture = render_picture(shapes, texts, os.path.join(out_dir, "human_live_mix.png"))
        except Exception as exc:  # rendering is a bonus: no GPU/EGL must not break the demo
            print(f"demo_live_mix: rendering skipped ({type(exc).__name__}: {exc})", file=sys.stderr)
    result = {"vertices": len(obj.data.vertices), "keys": names, "enable_seconds": round(enable_seconds, 3),
              "reduced_size": status["space_size"], "stale": status["stale"], "in_range": status["in_range"],
              "mix_ms": round(1e3 * status["mix_seconds"], 3), "at_half_arm": numbers,
              "playback_fps": round(fps, 1), "frames": len(frames), "blend": blend, "picture": picture,
              "saved_by": bpy.app.version_string}
    with open(os.path.join(out_dir, "human_live_mix.json"), "w") as fh:
        json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], render="--no-render" not in sys.argv[3:])
