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
    """An orthographic camera over the scene and a text label for every object (placed per row when rendering)."""
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
        text.data.align_y = 'TOP'
        text.data.size = 0.7
        # in the saved scene: below the object as seen by the camera, and a bit towards it
        text.location = obj.location - 2.3 * up + 4.0 * toward
        text.rotation_euler = cam.rotation_euler
        text.color = (0.1, 0.1, 0.1, 1)
        labels[obj.name] = text
    return labels


GAP = 1.2          # scene units between two objects of a row, and between an object and its label
MARGIN = 0.8       # around the row's content


def _camera_extent(obj, cam):
    """``(xmin, xmax, ymin, ymax, zmax)`` of the evaluated object in the camera's frame (x right, y up)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    if ev.type == 'MESH':
        mesh = ev.data
        local = np.empty(3 * len(mesh.vertices), np.float64)
        mesh.vertices.foreach_get("co", local)
        local = local.reshape(-1, 3)
    else:  # text: its bounding box
        local = np.array([tuple(c) for c in ev.bound_box], np.float64)
    world = local @ np.array(obj.matrix_world.to_3x3()).T + np.array(obj.matrix_world.translation)
    rot = np.array(cam.matrix_world.to_3x3())
    P = (world - np.array(cam.matrix_world.translation)) @ rot
    return P[:, 0].min(), P[:, 0].max(), P[:, 1].min(), P[:, 1].max(), P[:, 2].max()


def layout_row(objects, labels, cam):
    """Place the visible objects of one row side by side in the camera's view, each with its label below it,
    none overlapping another or another's label.  Returns the row's ``(width, height)`` in scene units."""
    from mathutils import Vector

    rot = cam.matrix_world.to_3x3()
    right, up = rot.col[0].normalized(), rot.col[1].normalized()
    bpy.context.view_layer.update()
    blocks = []
    for obj in objects:
        if obj.hide_render:
            continue
        x0, x1, y0, y1, z1 = _camera_extent(obj, cam)
        lx0, lx1, ly0, ly1, _ = _camera_extent(labels[obj.name], cam)
        width = max(x1 - x0, lx1 - lx0)
        label_height = ly1 - ly0
        blocks.append((obj, x0, x1, y0, y1, z1, width, label_height))
    total = sum(b[6] for b in blocks) + GAP * (len(blocks) - 1)
    height = max((b[4] - b[3]) + GAP + b[7] for b in blocks)
    left = -0.5 * total
    cam_origin = cam.matrix_world.translation
    for obj, x0, x1, y0, y1, z1, width, label_height in blocks:
        centre = left + 0.5 * width
        left += width + GAP
        block_height = (y1 - y0) + GAP + label_height
        top = 0.5 * block_height                       # centre the object and its label vertically
        obj.location += Vector(right) * (centre - 0.5 * (x0 + x1)) + Vector(up) * (top - y1)
        label_top = top - (y1 - y0) - GAP
        labels[obj.name].location = cam_origin + rot @ Vector((centre, label_top, z1 + 1.0))
    return total, height


def render_contact_sheet(objects, labels, out_dir):
    """Render one row per shape-key index (each object showing its k-th key alone), stacked into one PNG.

    Every row is laid out in the camera's view (:func:`layout_row`): objects side by side with their labels
    below them, nothing overlapping; all rows share one scale."""
    scene = bpy.context.scene
    cam = scene.camera
    n_rows = max(len(o.data.shape_keys.key_blocks) for o in objects)
    home = {o.name: o.location.copy() for o in [*objects, *labels.values()]}

    def show_row(k):
        for obj in objects:
            blocks = obj.data.shape_keys.key_blocks
            obj.location = home[obj.name]
            obj.show_only_shape_key = True
            obj.active_shape_key_index = min(k, len(blocks) - 1)
            obj.hide_render = labels[obj.name].hide_render = k >= len(blocks)  # fewer keys: blank
            labels[obj.name].data.body = f"{obj.name}: {blocks[obj.active_shape_key_index].name}"
        return layout_row(objects, labels, cam)

    sizes = [show_row(k) for k in range(n_rows)]
    width = max(w for w, _ in sizes) + 2 * MARGIN
    height = max(h for _, h in sizes) + 2 * MARGIN
    cam.data.ortho_scale = width
    scene.render.resolution_x = 960
    scene.render.resolution_y = int(round(960 * height / width))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(n_rows):
            show_row(k)
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
    for name, location in home.items():
        bpy.data.objects[name].location = location
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
        json.dump({"blend": blend, "picture": picture, "saved_by": bpy.app.version_string, "objects": summary},
                  fh, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], render="--no-render" not in sys.argv[2:])
