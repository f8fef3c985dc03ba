#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The README figure: Blender's linear shape-key blend vs the lengths-and-angles in-between.

A box bar 8 x 1 x 1 (quads, 1058 vertices) gets a shape key ``Bend180`` from Blender's
Simple Deform modifier (BEND, 180 degrees about z, applied as a shape key).  At t = 0.5

* Blender's linear blend ``0.5 Basis + 0.5 Bend180`` (what the shape-key slider at 0.5 shows),
* the lengths-and-angles in-between (operator ``lengths_angles.interpolate``, method FAST),

are compared with Blender's own 90-degree Simple Deform bend (the reference; each result is
rigidly fitted to it with Kabsch before measuring).  Prints the numbers as JSON and renders
the three side by side (Workbench, headless, no GPU needed), the reference in light grey
underneath both blends, to ``docs/images/bar_blend_comparison.png``.

usage: python scripts/render_comparison.py [--output PNG] [--blend FILE.blend] [--json FILE.json]
                                           [--method FAST|GAUSS_NEWTON] [--no-render] [--bake]

With ``--blend`` the scene is saved too: the bar with its keys (Basis, Bend180, SimpleDeform90
and the in-betweens "LA Basis>Bend180 0.250/0.500/0.750"; with ``--bake`` also the baked
motion, press Play) below the three compared objects.
"""

import argparse
import json
import math
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", default=os.path.join(REPO, "docs", "images", "bar_blend_comparison.png"))
    parser.add_argument("--blend", default=None, help="also save the scene (bar with its keys + the 3 objects)")
    parser.add_argument("--json", default=None, help="also write the numbers to this file")
    parser.add_argument("--method", default="FAST", choices=["FAST", "GAUSS_NEWTON"])
    parser.add_argument("--no-render", action="store_true")
    parser.add_argument("--bake", action="store_true",
                        help="also bake a straight > bent > straight motion (frames 1-24-48) on the bar, for --blend")
    return parser.parse_args(argv)


def compare(bpy, cases, method="FAST"):
    """Build the bar, run the operator, return ``(bar, coordinates dict, numbers dict)``."""
    bar = cases.bent_bar("Bar", 180.0, segments=(64, 4, 4), reference_deg=90.0)
    t = time.perf_counter()
    with bpy.context.temp_override(active_object=bar, object=bar, selected_objects=[bar]):
        result = bpy.ops.lengths_angles.interpolate(key_from="Basis", key_to="Bend180", factors="0.25 0.5 0.75",
                                                    method=method)
    seconds = time.perf_counter() - t
    assert result == {'FINISHED'}, result
    A, B = cases.key_coords(bar, "Basis"), cases.key_coords(bar, "Bend180")
    R = cases.key_coords(bar, "SimpleDeform90")
    la = cases.key_coords(bar, "LA Basis>Bend180 0.500")
    lin = 0.5 * A + 0.5 * B
    edges = cases.mesh_edges(bar)
    numbers = {
        "mesh": {"vertices": len(bar.data.vertices), "quads": len(bar.data.polygons), "edges": len(edges),
                 "size": "8 x 1 x 1", "bend": "Simple Deform BEND 180 deg about z (applied as shape key)"},
        "t": 0.5,
        "method": method,
        "operator_seconds_for_3_inbetweens": round(seconds, 3),
        "reference": "Simple Deform BEND 90 deg",
        "bounding_box_diagonal_of_reference": float(math.dist(R.max(0), R.min(0))),
        "linear_blend": cases.blend_metrics(lin, R, A, edges),
        "lengths_and_angles": cases.blend_metrics(la, R, A, edges),
        "simple_deform_90": cases.blend_metrics(R, R, A, edges),
    }
    return bar, {"linear": lin, "lengths_angles": la, "reference": R}, numbers


def _look_at(obj, target):
    from mathutils import Vector

    obj.rotation_euler = (Vector(target) - obj.location).to_track_quat("-Z", "Y").to_euler()


def build_picture_scene(bpy, cases, bar, coords, numbers):
    """Three objects side by side (linear, lengths and angles, reference), labels, camera, light."""
    import numpy as np

    scene = bpy.context.scene
    polys = [list(p.vertices) for p in bar.data.polygons]
    R = coords["reference"]
    spacing = 10.0
    lin, la, ref = numbers["linear_blend"], numbers["lengths_and_angles"], numbers["simple_deform_90"]
    columns = [
        ("linear", "Linear shape-key blend (Blender)", (0.85, 0.45, 0.35, 1.0),
         f"RMS error {100 * lin['rms_error_per_diagonal']:.2f} % of the diagonal\n"
         f"edge lengths off by up to {100 * lin['max_edge_error_vs_reference']:.0f} %"),
        ("lengths_angles", "Lengths & Angles in-between", (0.35, 0.6, 0.9, 1.0),
         f"RMS error {100 * la['rms_error_per_diagonal']:.2f} % of the diagonal\n"
         f"edge lengths off by up to {100 * la['max_edge_error_vs_reference']:.3f} %"),
        ("reference", "Simple Deform 90\u00b0 (reference)", (0.5, 0.78, 0.45, 1.0),
         f"Blender's own 90\u00b0 bend; its edge lengths\n"
         f"differ from the straight bar's by up to {100 * ref['max_edge_change_vs_straight']:.0f} %"),
    ]
    center = R.mean(0)
    objects = []
    for i, (key, title, color, detail) in enumerate(columns):
        offset = np.array([(i - 1) * spacing, 0.0, 0.0])
        X = cases.rigid_align(coords[key], R) - center + offset
        obj = cases.make_object(f"Cmp_{key}", X, polys)
        obj.color = color
        objects.append(obj)
        if key != "reference":  # the reference in light grey just below: visible where the blend misses it
            ghost = cases.make_object(f"Cmp_{key}_reference", R - center + offset - [0, 0, 0.05], polys)
            ghost.color = (0.82, 0.82, 0.82, 1.0)
        for j, (text, size, dy) in enumerate(((title, 0.55, -2.3), (detail, 0.42, -3.1))):
            curve = bpy.data.curves.new(f"Label_{key}_{j}", 'FONT')
            curve.body = text
            curve.size = size
            curve.align_x = 'CENTER'
            label = bpy.data.objects.new(f"Label_{key}_{j}", curve)
            scene.collection.objects.link(label)
            label.location = (offset[0], dy, 0.6)
            label.color = (0.05, 0.05, 0.05, 1.0)
    curve = bpy.data.curves.new("Title", 'FONT')
    curve.body = ("t = 0.5 between a straight bar and its 180\u00b0 Simple Deform bend "
                  "(light grey underneath: the 90\u00b0 reference)")
    curve.size = 0.5
    curve.align_x = 'CENTER'
    title = bpy.data.objects.new("Title", curve)
    scene.collection.objects.link(title)
    title.location = (0.0, 3.4, 0.6)
    title.color = (0.05, 0.05, 0.05, 1.0)

    cam = bpy.data.objects.new("ComparisonCamera", bpy.data.cameras.new("ComparisonCamera"))
    scene.collection.objects.link(cam)
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 30.5
    cam.location = (0.0, -5.0, 20.0)
    _look_at(cam, (0.0, 0.3, 0.0))
    scene.camera = cam
    scene.render.engine = 'BLENDER_WORKBENCH'
    shading = scene.display.shading
    shading.light = 'STUDIO'
    shading.color_type = 'OBJECT'
    shading.show_shadows = True
    shading.show_cavity = True
    shading.cavity_type = 'WORLD'
    scene.display.light_direction = (0.4, -0.4, 0.8)
    scene.render.film_transparent = False
    scene.world = scene.world or bpy.data.worlds.new("World")
    scene.world.color = (0.93, 0.93, 0.93)
    scene.render.resolution_x, scene.render.resolution_y = 1500, 520
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = 'PNG'
    scene.render.image_settings.color_mode = 'RGB'
    scene.view_settings.view_transform = 'Standard'
    return objects


def main(argv=None):
    args = parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_render_"))
    import bpy

    sys.path.insert(0, HERE)
    import blend_sample_cases as cases
    from addon_dev import load_addon

    load_addon()
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups next to the outputs
    bar, coords, numbers = compare(bpy, cases, args.method)
    bar.hide_render = True  # in the saved .blend the bar stays visible in the viewport, below the comparison
    bar.location = (0.0, -9.0, 0.0)
    build_picture_scene(bpy, cases, bar, coords, numbers)
    if args.bake:
        t = time.perf_counter()
        with bpy.context.temp_override(active_object=bar, object=bar, selected_objects=[bar]):
            result = bpy.ops.lengths_angles.bake_keyframes(keys="Basis, Bend180, Basis", frames="1, 24, 48",
                                                           smooth=True, method=args.method)
        assert result == {'FINISHED'}, result
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = 1, 48
        scene.frame_set(1)
        numbers["bake"] = {"keys": "Basis, Bend180, Basis", "frames": [1, 24, 48], "smooth": True,
                           "baked_keys": len([k for k in bar.data.shape_keys.key_blocks
                                              if k.name.startswith("LA bake ")]),
                           "seconds": round(time.perf_counter() - t, 3)}
    if not args.no_render:
        os.makedirs(os.path.dirname(os.path.abspath(args.output)), exist_ok=True)
        bpy.context.scene.render.filepath = os.path.abspath(args.output)
        bpy.ops.render.render(write_still=True)
        numbers["picture"] = os.path.abspath(args.output)
    if args.blend:
        os.makedirs(os.path.dirname(os.path.abspath(args.blend)), exist_ok=True)
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend), compress=True)
        numbers["blend"] = os.path.abspath(args.blend)
        numbers["saved_by"] = bpy.app.version_string  # Blender opens a .blend saved by its version or an older one
    text = json.dumps(numbers, indent=1)
    if args.json:
        with open(args.json, "w") as fh:
            fh.write(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
