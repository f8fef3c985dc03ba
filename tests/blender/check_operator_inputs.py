"""Blender-side checks of how the operators of the INSTALLED extension name bad input and refuse what Blender would
not keep (run in a SUBPROCESS by tests/test_blender_operator_inputs.py; bpy can be imported once per process):

* faces of no area on a quad mesh, named by mesh, shape key and Blender face number by every operator that checks
  them (Encode, In-betweens, Bake, Build Model, Live Mixing);
* a character linked into a shot from a library (its object linked, or a library override with its mesh linked or
  an override too): what Blender keeps of the add-on's records on reopening, and the operators writing records that
  would be lost refused in one line;
* Import Markers with a negative Start Frame;
* Bake's and Build Model's typed key lists naming keys that hold commas.

usage: BLENDER_USER_RESOURCES=<tmp> python check_operator_inputs.py --zip EXT.zip --workdir DIR --result OUT.json
"""

import importlib
import json
import os

# harness first: it checks the environment and imports bpy
from harness import ARGS, MODULE, REPO, bpy, fake_operator, plain, reset, run_cases, select_only
import numpy as np
import blender_samples as samples
import libraries

MOCAP = os.path.join(os.environ.get("LACORE_SHARED_DATA") or os.path.join(os.path.dirname(REPO), "shared", "data"),
                     "mocap")


def ext(name):
    return importlib.import_module(f"{MODULE}.{name}")


def snapshot(obj):
    """What an operator could change on ``obj``: ID properties of the object and the mesh, keys and coordinates,
    modifiers, and the file's objects, texts and actions."""
    mesh = obj.data
    keys = []
    if mesh.shape_keys is not None:
        for kb in mesh.shape_keys.key_blocks:
            co = np.empty(3 * len(kb.points), np.float32)
            kb.points.foreach_get("co", co)
            keys.append((kb.name, kb.value, co.tolist()))
    return json.dumps({"mesh_props": {k: repr(plain(mesh[k])) for k in mesh.keys()},
                       "object_props": {k: repr(plain(obj[k])) for k in obj.keys()},
                       "keys": keys, "modifiers": [m.name for m in obj.modifiers],
                       "objects": sorted(o.name for o in bpy.data.objects),
                       "texts": sorted(t.name for t in bpy.data.texts),
                       "actions": sorted(a.name for a in bpy.data.actions)}, sort_keys=True)


def attempt(obj, op, selected=(), **kwargs):
    """Run ``op`` with ``obj`` active (and ``selected`` selected too): ``{"result", "message", "one_line",
    "unchanged"}``."""
    before = snapshot(obj)
    try:
        with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[*selected, obj]):
            result, message = sorted(op(**kwargs)), ""
    except RuntimeError as exc:
        result, message = ["ERROR"], str(exc).replace("Error: ", "").strip()
    return {"result": result, "message": message, "one_line": "\n" not in message and "Traceback" not in message,
            "unchanged": snapshot(obj) == before}


# ----------------------------------------------------------------------------- cases
def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    assert MODULE in bpy.context.preferences.addons


GRID_N = 4        # 4 x 4 quads: polygon p is triangles 2p and 2p + 1 of the fan triangulation
COLLAPSED = (12, 13)  # vertex 13 moved onto vertex 12 in the key 'Flat'


def degenerate_faces():
    """A 4 x 4 quad grid whose key 'Flat' has the edge (12, 13) collapsed: the two quads sharing it have a triangle of
    no area.  Every operator that checks for such faces names the mesh, the key and the quads' Blender numbers (not
    the triangles' numbers 2p or 2p + 1)."""
    reset()
    obj = samples.make_wave_grid("Grid", n=GRID_N)
    verts = samples.basis_coords(obj)
    flat = verts.copy()
    flat[COLLAPSED[1]] = flat[COLLAPSED[0]]
    samples.add_shape_key(obj, "Flat", flat)
    polys = [p.index for p in obj.data.polygons if set(COLLAPSED) <= set(p.vertices)]
    triangles = ext("addon.mesh_access").triangulate(obj.data)
    tris = [int(t) for t in np.flatnonzero([set(COLLAPSED) <= set(f) for f in triangles.faces.tolist()])]
    ops = bpy.ops.lengths_angles
    out = {"polygons": polys, "triangles": tris}
    for name, op, kwargs in (("encode", ops.encode, {}),
                             ("inbetweens", ops.interpolate, {"key_from": "Basis", "key_to": "Flat", "factors": "0.5"}),
                             ("bake", ops.bake_keyframes, {"keys": "Basis, Flat", "frames": "1 5"}),
                             ("build_model", ops.build_model, {"keys": "Wave, Roll, Flat"}),
                             ("live_mix", ops.live_mix_enable, {})):
        select_only(obj)
        out[name] = attempt(obj, op, **kwargs)
    return out


def _character(library):
    """'Body' (a cube with keys, its shape model and a pin) saved in the library ``library``."""
    reset()
    obj = samples.make_cube("Body")
    select_only(obj)
    assert bpy.ops.lengths_angles.build_model() == {"FINISHED"}
    obj[ext("addon.operators_pins").PINS_PROP] = {"LFHD": 0}
    libraries.save_character(library, [obj])


def _take():
    """A small take (3 markers, 5 samples) imported into the open file; returns its take empty."""
    mio = importlib.import_module(f"{MODULE}.lacore.markers.io")
    positions = np.random.default_rng(0).normal(size=(5, 3, 3))
    take = mio.MarkerTake(labels=["LFHD", "RFHD", "C7"], positions=positions, rate=100.0, source="generated")
    take_obj, _markers = ext("addon.operators_markers").import_take(bpy.context, take, "take")
    return take_obj


def _shot_object(kind, library):
    """The open file made a shot holding 'Body' of ``library`` as ``kind``: "linked" (the object linked),
    "override" (a library override, its mesh linked) or "override_mesh" (the mesh an override too)."""
    reset()
    if kind == "linked":
        return libraries.link_objects(library, ["Body"])[0]
    libraries.override_character(library, editable=True)
    obj = next(o for o in bpy.data.objects if o.name == "Body" and o.library is None)
    if kind == "override_mesh":
        obj.data.override_create(remap_local_usages=True)
    return obj


def _reopened(path):
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    return next(o for o in bpy.data.objects if o.name == "Body" and (o.library is None or o.override_library is None))


def library_data():
    """'Body' of a library in a shot, as a linked object, a library override with its mesh linked, and with its mesh
    an override too.  What Blender keeps of custom properties set in the shot when it is saved and opened again
    (the add-on's records are such properties), then each operator storing records on the object or the mesh."""
    library = os.path.join(ARGS.workdir, "body_library.blend")
    shot = os.path.join(ARGS.workdir, "body_shot.blend")
    _character(library)
    ops = bpy.ops.lengths_angles
    pins_prop = ext("addon.operators_pins").PINS_PROP
    out = {}
    for kind in ("linked", "override", "override_mesh"):
        got = {}
        obj = _shot_object(kind, library)
        got["datablocks"] = [obj.library is not None, obj.override_library is not None,
                             obj.data.library is not None, obj.data.override_library is not None]
        # what Blender keeps: a custom property set on the object and on the mesh in the shot, and the library's pin
        # changed in the shot
        obj["test_object_prop"] = 1
        obj.data["test_mesh_prop"] = 1
        obj[pins_prop] = {"LFHD": 3}
        # the add-on's object settings (registered properties): Placement and the first mode slider
        settings = None
        if obj.library is None:
            obj.lengths_angles_placement = 'PLACED'
            obj.lengths_angles_mode_weights[0] = 1.5
        obj = _reopened(shot)
        if obj.library is None:
            settings = [obj.lengths_angles_placement, round(obj.lengths_angles_mode_weights[0], 3)]
        got["kept_after_reopen"] = {"object_prop": "test_object_prop" in obj,
                                    "mesh_prop": "test_mesh_prop" in obj.data,
                                    "pin_changed": obj.get(pins_prop, {}).to_dict() == {"LFHD": 3},
                                    "settings": settings}
        obj = _shot_object(kind, library)
        take = _take()
        bpy.ops.wm.save_as_mainfile(filepath=shot)  # Calibrate & Fit writes its point cache next to it
        select_only(obj)
        got["encode"] = attempt(obj, ops.encode)
        got["pin_marker"] = attempt(obj, ops.pin_marker, label="RFHD", vertex=1)
        got["remove_pin"] = attempt(obj, ops.remove_pin, label="LFHD")
        got["bind_markers"] = attempt(obj, ops.bind_markers, selected=[take])
        got["calibrate_fit"] = attempt(obj, ops.calibrate_fit, selected=[take])
        out[kind] = got
    # the same operators on the character made local in the shot: their records are kept
    obj = _shot_object("override", library)
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.make_local(type='SELECT_OBDATA')
    obj = next(o for o in bpy.data.objects if o.name == "Body")
    _take()
    select_only(obj)
    local = {"datablocks": [obj.library is not None, obj.override_library is not None,
                            obj.data.library is not None, obj.data.override_library is not None],
             "encode": attempt(obj, ops.encode), "pin_marker": attempt(obj, ops.pin_marker, label="RFHD", vertex=1)}
    obj = _reopened(shot)
    local["kept_after_reopen"] = {"encoding": ext("addon.storage").PROP in obj.data,
                                  "pins": obj.get(pins_prop, {}).to_dict()}
    out["made_local"] = local
    return out


def fit_on_override():
    """'Body' with its model, a take and the binding saved in a library, made a library override in a shot: Fit to
    Markers writes its point cache (kept) and its report says that the fit's quality is not (Blender drops the custom
    properties set on an override); on the object linked without an override it is refused in one line."""
    library = os.path.join(ARGS.workdir, "fit_library.blend")
    shot = os.path.join(ARGS.workdir, "fit_shot.blend")
    reset()
    obj = samples.make_cube("Body")
    select_only(obj)
    assert bpy.ops.lengths_angles.build_model() == {"FINISHED"}
    take = _take()
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[take, obj]):
        assert bpy.ops.lengths_angles.bind_markers() == {"FINISHED"}
    libraries.save_character(library, [obj, take, *take.children_recursive])
    fit = ext("addon.operators_fit")
    quality = ext("addon.fit_quality")
    out = {}
    obj = _shot_object("override", library)
    bpy.ops.wm.save_as_mainfile(filepath=shot)
    op = fake_operator()
    op.interactive = False
    out["override_result"] = sorted(op.start_run(bpy.context, lambda context: fit.fit_run(context, obj, 1, 5)))
    out["override_reports"] = op.reports
    out["quality_before_reopen"] = quality.FIT_PROP in obj
    obj = _reopened(shot)
    out["reopened"] = {"modifier": fit.FIT_MODIFIER in obj.modifiers, "quality": quality.FIT_PROP in obj,
                       "rms_property": quality.RMS_PROP in obj}
    obj = _shot_object("linked", library)
    bpy.ops.wm.save_as_mainfile(filepath=shot)
    out["linked"] = attempt(obj, bpy.ops.lengths_angles.fit_markers, use_scene_range=False, frame_start=1,
                            frame_end=5)
    return out


def negative_start_frame():
    """Import Markers with Start Frame -5: with Set Frame Range (a scene's range starts at 0 at the earliest) refused
    in one line, nothing created and the scene's range kept; without it the take is keyed from frame -5."""
    reset()
    path = os.path.join(MOCAP, "Eb015pr.c3d")
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 3, 40
    out = {}
    before = (len(bpy.data.objects), len(bpy.data.actions), scene.frame_start, scene.frame_end)
    try:
        out["set_range"] = sorted(bpy.ops.lengths_angles.import_markers(filepath=path, frame_start=-5))
    except RuntimeError as exc:
        out["set_range"] = str(exc).replace("Error: ", "").strip()
    out["set_range_unchanged"] = before == (len(bpy.data.objects), len(bpy.data.actions), scene.frame_start,
                                            scene.frame_end)
    out["no_range"] = sorted(bpy.ops.lengths_angles.import_markers(filepath=path, frame_start=-5,
                                                                   set_frame_range=False))
    take = next(o for o in bpy.data.objects if ext("addon.operators_markers").TAKE_PROP in o)
    meta = take[ext("addon.operators_markers").TAKE_PROP]
    firsts = [ext("addon.operators_markers").keyed_location(m)[0].keyframe_points[0].co[0] for m in take.children]
    out["take_frame_start"] = float(meta["frame_start"])
    out["first_key"] = float(min(firsts))
    out["scene_range"] = [scene.frame_start, scene.frame_end]
    out["read_at_minus_5"] = bool(np.isfinite(ext("addon.operators_markers").read_take(take, frames=[-5]).positions)
                                  .any())
    out["zero_with_range"] = sorted(bpy.ops.lengths_angles.import_markers(filepath=path, frame_start=0))
    out["zero_scene_start"] = scene.frame_start
    return out


def comma_key_names():
    """Keys 'Arm, left' and 'Arm' next to 'Basis' and 'Bend': Bake's typed Keys and Build Model's name them quoted
    or as they are (the longest key name the typed commas spell)."""
    reset()
    obj = samples.make_bar("Bar", segments=6)
    names = [kb.name for kb in obj.data.shape_keys.key_blocks]
    verts = samples.basis_coords(obj)
    samples.add_shape_key(obj, "Arm, left", samples.bend(verts, np.pi / 3, 6.0))
    samples.add_shape_key(obj, "Arm", samples.twist(verts, np.pi / 3, 6.0))
    out = {"keys": names + ["Arm, left", "Arm"]}
    bake_op = bpy.ops.lengths_angles.bake_keyframes
    select_only(obj)
    out["bake_quoted"] = attempt(obj, bake_op, keys='Basis, "Arm, left"', frames="1 3", method='PREVIEW')
    out["bake_quoted_keys"] = list(plain(obj.data[ext("addon.bake").BAKE_PROP])["source"]["keys"])
    out["bake_plain"] = attempt(obj, bake_op, keys="Arm, left, Basis", frames="1 3", method='PREVIEW')
    out["bake_plain_keys"] = list(plain(obj.data[ext("addon.bake").BAKE_PROP])["source"]["keys"])
    out["bake_two"] = attempt(obj, bake_op, keys='"Arm", Basis', frames="1 3", method='PREVIEW')
    out["bake_two_keys"] = list(plain(obj.data[ext("addon.bake").BAKE_PROP])["source"]["keys"])
    out["bake_unclosed"] = attempt(obj, bake_op, keys='Basis, "Arm, left', frames="1 3")
    out["bake_missing"] = attempt(obj, bake_op, keys="Basis, Leg, right", frames="1 3 5")
    out["model"] = attempt(obj, bpy.ops.lengths_angles.build_model, keys='Bend, "Arm, left", Twist')
    meta = obj.data.get(ext("addon.operators_fit").MODEL_PROP)
    out["model_keys"] = None if meta is None else list(plain(meta)["keys"])
    return out


def main():
    run_cases((install_and_enable, degenerate_faces, library_data, fit_on_override, negative_start_frame,
               comma_key_names))


if __name__ == "__main__":
    main()
