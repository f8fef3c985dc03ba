# SPDX-License-Identifier: GPL-3.0-or-later
"""Demo, Blender part (run by scripts/demo.py in its own process: bpy can be imported once).

Builds the sample scene (cube, bar, grid with shape keys), runs the
``lengths_angles.encode`` operator on every object, saves the .blend and writes
what was stored (JSON summary + .npz arrays), then renders a contact sheet
``demo_scene_keys.png`` (one row per shape-key index, Workbench engine) unless
``--no-render``.

usage: python scripts/demo_blender.py OUTPUT_DIR [--no-render]
"""

import json
import os
import sys
import tempfile
import time

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import blender_samples
from addon_dev import load_addon


def _look_at(obj, target):
    from mathutils import Vector

    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def setup_camera_and_labels(objects):
    """An orthographic camera over the scene and a text label under every object."""
    scene = bpy.context.scene
    cam = bpy.data.objects.new("DemoCamera", bpy.data.cameras.new("DemoCamera"))
    scene.collection.objects.link(cam)
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 17.0
    cam.location = (-4.0, -20.0, 10.0)
    _look_at(cam, (0.5, 0.0, 0.0))
    scene.camera = cam
    scene.render.engine = 'BLENDER_WORKBENCH'
    scene.display.shading.light = 'STUDIO'
    scene.display.shading.color_type = 'OBJECT'
    scene.render.resolution_x, scene.render.resolution_y = 960, 380
    scene.render.image_settings.file_format = 'PNG'
    bpy.context.view_layer.update()
    rot = cam.matrix_world.to_3x3()
    up, toward = rot.col[1].normalized(), rot.col[2].normalized()
    labels = {}
    for obj, color in zip(objects, ((0.9, 0.55, 0.3, 1), (0.35, 0.6, 0.9, 1), (0.45, 0.8, 0.45, 1)), strict=False):
        obj.color = color
        text = bpy.data.objects.new(f"{obj.name}Label", bpy.data.curves.new(f"{obj.name}Label", 'FONT'))
        scene.collection.objects.link(text)
        text.data.align_x = 'CENTER'
        text.data.size = 0.7
        # below the object as seen by the camera, and a bit towards it (not hidden by the object)
        text.location = obj.location - 2.3 * up + 4.0 * toward
        text.rotation_euler = cam.rotation_euler
        text.color = (0.1, 0.1, 0.1, 1)
        labels[obj.name] = text
    return labels


def render_contact_sheet(objects, labels, out_dir):
    """Render one row per shape-key index (each object showing its k-th key alone), stacked into one PNG."""
    scene = bpy.context.scene
    n_rows = max(len(o.data.shape_keys.key_blocks) for o in objects)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(n_rows):
            for obj in objects:
                blocks = obj.data.shape_keys.key_blocks
                obj.show_only_shape_key = True
                obj.active_shape_key_index = min(k, len(blocks) - 1)
                obj.hide_render = labels[obj.name].hide_render = k >= len(blocks)  # fewer keys: blank
                labels[obj.name].data.body = f"{obj.name}: {blocks[obj.active_shape_key_index].name}"
            scene.render.filepath = os.path.join(tmp, f"row{k}.png")
            bpy.ops.render.render(write_still=True)
            img = bpy.data.images.load(scene.render.filepath)
            px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
            img.pixels.foreach_get(px)
            rows.append(px.reshape(img.size[1], img.size[0], 4)[::-1])  # top row first
            bpy.data.images.remove(img)
    for obj in objects:
        obj.show_only_shape_key = False
        obj.active_shape_key_index = 0
        obj.hide_render = labels[obj.name].hide_render = False
        labels[obj.name].data.body = obj.name
    sheet = np.concatenate(rows, axis=0)[::-1]  # Blender images are stored bottom-up
    img = bpy.data.images.new("contact_sheet", sheet.shape[1], sheet.shape[0], alpha=True)
    img.pixels.foreach_set(np.ascontiguousarray(sheet).ravel())
    path = os.path.join(out_dir, "demo_scene_keys.png")
    img.filepath_raw = path
    img.file_format = 'PNG'
    img.save()
    bpy.data.images.remove(img)
    return path


def main(out_dir, render=True):
    os.makedirs(out_dir, exist_ok=True)
    pkg = load_addon()
    storage = pkg.addon.storage
    bpy.ops.wm.read_homefile(use_empty=True)
    objects = blender_samples.build_demo_scene()
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups next to the outputs
    summary, arrays = {}, {}
    for obj in objects:
        t = time.perf_counter()
        with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
            bpy.ops.lengths_angles.encode()
        seconds = time.perf_counter() - t
        enc = storage.read_encoding(obj.data)
        E = len(enc["edges"])
        arrays[f"{obj.name}/faces"] = enc["faces"]
        arrays[f"{obj.name}/edges"] = enc["edges"]
        keys = {}
        for name, item in enc["keys"].items():
            z = item["z"]
            arrays[f"{obj.name}/{name}/lengths"] = z[:E]
            arrays[f"{obj.name}/{name}/angles"] = z[E:]
            keys[name] = {
                "min_length": float(z[:E].min()), "max_length": float(z[:E].max()),
                "max_abs_angle_deg": float(np.degrees(np.abs(z[E:]).max())),
                "max_integrability_violation": item["max_integrability_violation"],
            }
        summary[obj.name] = {
            "vertices": len(obj.data.vertices), "polygons": len(obj.data.polygons),
            "triangles": len(enc["faces"]), "edges": E, "blender_edges": enc["n_mesh_edges"],
            "seconds": seconds, "keys": keys,
        }
    labels = setup_camera_and_labels(objects)
    for obj in objects:
        labels[obj.name].data.body = obj.name
    blend = os.path.join(os.path.abspath(out_dir), "demo_scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    np.savez(os.path.join(out_dir, "demo_scene.npz"), **arrays)
    picture = None
    if render:
        try:
            picture = render_contact_sheet(objects, labels, out_dir)
        except Exception as exc:  # rendering is a bonus: no GPU/EGL must not break the demo
            print(f"demo_blender: rendering skipped ({type(exc).__name__}: {exc})", file=sys.stderr)
    with open(os.path.join(out_dir, "demo_scene.json"), "w") as fh:
        json.dump({"blend": blend, "picture": picture, "blender": bpy.app.version_string, "objects": summary},
                  fh, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], render="--no-render" not in sys.argv[2:])
