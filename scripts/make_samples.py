#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""`make samples`: write reproducible sample data generated with Blender (bpy).

* ``<out>/shape_keys.blend``: a cube, a bar and a grid with quads and shape keys, not yet
  encoded (open it and press Encode in Object Data > Shape Keys > Lengths & Angles);
* ``<out>/<Object>/<Key>.ply``: every shape key as a triangle mesh (the add-on's fixed
  fan triangulation), in dense correspondence per object, usable with ``lacore encode``.

usage: python scripts/make_samples.py [--output blend_samples]
"""

import argparse
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", default=os.path.join(REPO, "blend_samples"))
    args = parser.parse_args(argv)
    out = os.path.abspath(args.output)
    os.makedirs(out, exist_ok=True)
    # isolate from the user's Blender configuration (must be set before importing bpy)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_samples_"))
    import bpy

    sys.path.insert(0, HERE)
    import blender_samples
    from addon_dev import load_addon

    pkg = load_addon(register=False)
    mesh_access = pkg.addon.mesh_access
    import importlib

    save_mesh = importlib.import_module(pkg.__name__ + ".lacore.mesh_io").save_mesh

    bpy.ops.wm.read_homefile(use_empty=True)
    objects = blender_samples.build_demo_scene()
    for obj in objects:
        tri = mesh_access.triangulate(obj.data)
        names, coords = mesh_access.read_shape_keys(obj.data)
        os.makedirs(os.path.join(out, obj.name), exist_ok=True)
        for name, X in zip(names, coords, strict=True):
            path = os.path.join(out, obj.name, f"{name}.ply")
            save_mesh(path, X, tri.faces)
            print("wrote", path)
    blend = os.path.join(out, "shape_keys.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    print("wrote", blend)
    return 0


if __name__ == "__main__":
    sys.exit(main())
