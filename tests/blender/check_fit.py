"""Blender-side checks of Build Shape Model / Bind Markers / Fit to Markers of the INSTALLED extension
(run in a SUBPROCESS by tests/test_blender_fit.py, which prepares the inputs with the repo's lacore:
``<work>/inputs.npz`` (faces, basis, training poses, true take, bind pose) and ``<work>/take.c3d``).

usage: BLENDER_USER_RESOURCES=<tmp> python check_fit.py --zip EXT.zip --workdir DIR --result OUT.json

The check writes what Blender produced (model, binding, evaluated Mesh Cache poses) to
``<workdir>/blender_fit.npz``; pytest compares it with lacore's own fit of the same data.
"""

import base64
import importlib
import os
import time

from harness import (ARGS, MODULE, bpy, draw_panel, drive, esc, evaluated, fake_operator, reset, run_cases,
                     select_only)
import libraries
import numpy as np

WORK = os.path.dirname(ARGS.workdir)
INPUTS = dict(np.load(os.path.join(WORK, "inputs.npz")))
C3D = os.path.join(WORK, "take.c3d")
OUT = {}


def ext(name):
    return importlib.import_module(f"{MODULE}.{name}")


def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    return {"operators": [bpy.ops.lengths_angles.build_model.idname(), bpy.ops.lengths_angles.bind_markers.idname(),
                          bpy.ops.lengths_angles.fit_markers.idname()]}


def make_body():
    """Mesh object 'Body' with Basis + training shape keys (and the bind pose key, value 0)."""
    faces = INPUTS["faces"]
    mesh = bpy.data.meshes.new("Body")
    mesh.from_pydata(INPUTS["basis"].tolist(), [], faces.tolist())
    obj = bpy.data.objects.new("Body", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    for k, X in enumerate(INPUTS["training"]):
        kb = obj.shape_key_add(name=f"train{k:02d}", from_mix=False)
        kb.data.foreach_set("co", X.astype(np.float32).ravel())
        kb.value = 0.0  # (new keys are at 1 in Blender 5)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def state(obj):
    """A snapshot of everything a failed operator must leave alone."""
    mesh = obj.data
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    return {"keys": [kb.name for kb in mesh.shape_keys.key_blocks] if mesh.shape_keys else [],
            "modifiers": [m.name for m in obj.modifiers], "props": sorted(obj.keys()),
            "mesh_props": sorted(mesh.keys()), "co": co.tobytes(),
            "files": sorted(os.listdir(ARGS.workdir)) if os.path.isdir(ARGS.workdir) else []}


def whole_path():
    reset()
    os.makedirs(ARGS.workdir, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = make_body()
    n_keys = len(INPUTS["training"])
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.build_model() == {"FINISHED"}
    t_model = time.perf_counter() - t
    meta = obj.data[ext("addon.operators_fit").MODEL_PROP].to_dict()
    OUT["model_npz"] = np.frombuffer(ext("addon.storage").load_payload(meta, ext("addon.operators_fit").MODEL_HEADER),
                                     np.uint8)
    # the mode sliders as a shape key: mode 1 at +1 std
    obj.lengths_angles_mode_weights[0] = 1.0
    fit = ext("addon.operators_fit")
    pending = sorted(fit._PENDING_PREVIEWS)  # the slider's update asked for a preview
    t = time.perf_counter()
    fit.update_previews()  # the timer's callback (timers do not run in background mode)
    t_preview = time.perf_counter() - t
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY].data.foreach_get("co", co)
    OUT["preview"] = co.reshape(-1, 3)
    preview_value = obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY].value
    obj.shape_key_remove(obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY])
    assert bpy.ops.lengths_angles.model_pose_to_shape_key(name="mode1") == {"FINISHED"}
    pose_key = obj.data.shape_keys.key_blocks["mode1"]
    pose_key_setup = [pose_key.value, pose_key.relative_key.name]
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks["mode1"].data.foreach_get("co", co)
    OUT["mode1"] = co.reshape(-1, 3)
    obj.shape_key_remove(obj.data.shape_keys.key_blocks["mode1"])
    # a slider far out: the preview shows a pose that fails its checks, and the panel says so until it is moved back
    problems = []
    for value in (3.0, 1.0):
        obj.lengths_angles_mode_weights[0] = value
        fit.update_previews()
        problems.append(fit.PREVIEW_PROBLEMS.get(obj.name))
    obj.lengths_angles_mode_weights[0] = 3.0
    fit.update_previews()
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY].data.foreach_get("co", co)
    OUT["far_preview"] = co.reshape(-1, 3)
    assert bpy.ops.lengths_angles.model_pose_to_shape_key(name="far") == {"FINISHED"}  # written, with a warning
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks["far"].data.foreach_get("co", co)
    OUT["far"] = co.reshape(-1, 3)
    # the slider moved back to 1 in Edit Mode: the preview waits for Object Mode (leaving Edit Mode writes back the
    # keys as they were on entering it)
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='EDIT')
    obj.lengths_angles_mode_weights[0] = 1.0
    fit.update_previews()
    edit_pending = sorted(fit._PENDING_PREVIEWS)
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='OBJECT')
    fit.update_previews()
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY].data.foreach_get("co", co)
    OUT["edit_mode_preview"] = co.reshape(-1, 3)
    obj.shape_key_remove(obj.data.shape_keys.key_blocks["far"])
    obj.shape_key_remove(obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY])
    obj.lengths_angles_mode_weights[0] = 1.0
    fit._PENDING_PREVIEWS.clear()
    # markers
    assert bpy.ops.lengths_angles.import_markers(filepath=C3D, scale=10.0) == {"FINISHED"}
    take = bpy.data.objects["take"]
    scene = bpy.context.scene
    # pose the mesh like the first frame of the take (a shape key at 1) and bind there
    kb = obj.shape_key_add(name="bind pose", from_mix=False)
    kb.data.foreach_set("co", INPUTS["bind_pose"].astype(np.float32).ravel())
    kb.value = 1.0
    scene.frame_set(1)
    select_only(obj, take)
    fit = ext("addon.operators_fit")
    OUT["bind_mesh"] = fit._mesh_vertices(obj)
    OUT["bind_markers"] = ext("addon.operators_markers").read_take(take, frames=[1]).positions[0]
    assert bpy.ops.lengths_angles.bind_markers() == {"FINISHED"}
    obj.shape_key_remove(kb)
    binding = obj[ext("addon.operators_fit").BINDING_PROP]
    OUT["bind_faces"] = np.array(binding["faces"])
    OUT["bind_barycentric"] = np.array(binding["barycentric"]).reshape(-1, 3)
    OUT["bind_offsets"] = np.array(binding["offsets"])
    OUT["bind_vertices"] = np.array(binding["vertices"])
    from types import SimpleNamespace
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_mocap, SimpleNamespace(object=obj))
    places = [kw.get("text", "") for name, _a, kw in calls if name == "label"
              and kw.get("text", "").startswith(("vertex ", "triangle "))]
    bind_regions = list(binding["regions"])
    # fit the scene range (synchronous in background mode), PC2 output
    T = INPUTS["true"].shape[0]
    scene.frame_start, scene.frame_end = 1, T
    before = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.vertices.foreach_get("co", before)
    keys_before = [k.name for k in obj.data.shape_keys.key_blocks]
    t = time.perf_counter()
    assert bpy.ops.lengths_angles.fit_markers() == {"FINISHED"}
    t_fit = time.perf_counter() - t
    mod = obj.modifiers["LA Fit"]
    pc2 = bpy.path.abspath(mod.filepath)
    quality = rms_curve(obj)
    after = np.empty_like(before)
    obj.data.vertices.foreach_get("co", after)
    # evaluated mesh per frame (the Mesh Cache modifier playing the PC2)
    frames = np.arange(1, T + 1)
    poses = []
    for f in frames:
        scene.frame_set(int(f))
        poses.append(evaluated(obj))
    OUT["evaluated"] = np.array(poses)
    modifier = {"type": mod.type, "cache_format": mod.cache_format, "filepath": mod.filepath,
                "frame_start": mod.frame_start, "frame_scale": mod.frame_scale, "time_mode": mod.time_mode}
    n_vertices = len(obj.data.vertices)
    keys_unchanged = keys_before == [k.name for k in obj.data.shape_keys.key_blocks]
    OUT["frames"] = frames
    # save and reload: model, binding and modifier survive
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    model = ext("addon.operators_fit").read_model(obj)
    np.savez(os.path.join(ARGS.workdir, "blender_fit.npz"), **OUT)
    return {"preview": {"pending": pending, "value": preview_value, "seconds": round(t_preview, 3),
                        "problems": problems, "pose_key": pose_key_setup, "edit_pending": edit_pending},
            "n_keys": n_keys, "n_modes": int(meta["n_modes"]), "model_keys": list(meta["keys"]),
            "model_seconds": round(t_model, 3), "fit_seconds": round(t_fit, 3), "frames": int(T),
            "fit_seconds_per_frame": t_fit / T,
            "modifier": modifier, "pc2_bytes": os.path.getsize(pc2), "n_vertices": n_vertices,
            "mesh_untouched": bool(np.array_equal(before, after)), "keys_unchanged": keys_unchanged,
            "quality": quality, "bind_places": places, "bind_regions": bind_regions,
            "reloaded": {"n_modes": int(model.n_modes), "binding": "lengths_angles_binding" in obj,
                         "modifier": "LA Fit" in obj.modifiers}}


def rms_curve(obj):
    """The fit's quality stored on ``obj``: the keyed per-frame marker RMS (mm) and the summary."""
    quality = ext("addon.fit_quality")
    fcurves = ext("addon.compat").id_fcurves(obj)
    fc = fcurves.find(f'["{quality.RMS_PROP}"]')
    co = np.empty(2 * len(fc.keyframe_points), np.float32)
    fc.keyframe_points.foreach_get("co", co)
    bpy.context.scene.frame_set(3)
    from types import SimpleNamespace
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_mocap, SimpleNamespace(object=obj))
    texts = [kw.get("text", "") for name, _args, kw in calls if name == "label"]
    return {"frames": co[0::2].tolist(), "values": co[1::2].tolist(), "value_at_3": float(obj[quality.RMS_PROP]),
            "summary": obj[quality.FIT_PROP].to_dict(), "panel": [t for t in texts if t.startswith("Fit of")]}


def bind_units_and_occlusion():
    """Bind at a frame where some markers are occluded binds the visible ones (the report names the others);
    the warning distance is in metres (the take was imported with Scale 10: a unit is 0.1 m)."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    fit = ext("addon.operators_fit")
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    obj.modifiers.remove(obj.modifiers["LA Fit"])
    kb = obj.shape_key_add(name="pose 3", from_mix=False)
    kb.data.foreach_set("co", INPUTS["true"][2].astype(np.float32).ravel())
    kb.value = 1.0
    scene = bpy.context.scene
    scene.frame_set(3)  # markers 3, 10, 20 are occluded at frames 3..5
    out = {}
    for label, warn in (("default", None), ("strict", 0.004)):
        run = fit.bind_run(bpy.context, obj, take, **({} if warn is None else {"warn_distance": warn}))
        run.run()
        op = fake_operator()
        result = op._finish_run(run)
        binding = obj[fit.BINDING_PROP].to_dict()
        out[label] = {"result": sorted(result), "reports": op.reports, "n_bound": len(binding["labels"]),
                      "not_bound": list(binding["not_bound"]), "metres_per_unit": binding["metres_per_unit"],
                      "not_bound_reasons": list(binding["not_bound_reasons"]),
                      "offsets_mm": [1000 * abs(o) * binding["metres_per_unit"] for o in binding["offsets"]]}
    labels = [lb for lb, _ in ext("addon.operators_markers").marker_objects(take)]
    out["occluded_labels"] = [labels[i] for i in (3, 10, 20)]
    out["n_markers"] = len(labels)
    scene.unit_settings.scale_length = 0.1
    out["scene_unit"] = fit.metres_per_unit(obj, None, scene)
    out["take_unit_after_scene_change"] = fit.metres_per_unit(obj, take, scene)
    return out


def shape_key_output():
    """Short clip as shape keys: one key per frame, showing exactly at its frame; the PC2 fit's modifier goes, and
    fitting again replaces the keys instead of adding to them."""
    obj = bpy.data.objects["Body"]
    scene = bpy.context.scene
    select_only(obj)
    had_modifier = "LA Fit" in obj.modifiers
    n_before = len(obj.data.shape_keys.key_blocks)
    assert bpy.ops.lengths_angles.fit_markers(output='SHAPE_KEYS', use_scene_range=False, frame_start=2,
                                              frame_end=4) == {"FINISHED"}
    names = [k.name for k in obj.data.shape_keys.key_blocks][n_before:]
    scene.frame_set(3)
    values = {k.name: k.value for k in obj.data.shape_keys.key_blocks[n_before:]}
    first = evaluated(obj).astype(np.float64)
    key3 = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks["LA fit 3"].data.foreach_get("co", key3)
    assert bpy.ops.lengths_angles.fit_markers(output='SHAPE_KEYS', use_scene_range=False, frame_start=2,
                                              frame_end=4) == {"FINISHED"}
    scene.frame_set(2)
    scene.frame_set(3)
    again = {"names": [k.name for k in obj.data.shape_keys.key_blocks][n_before:], "evaluated_change":
             float(np.abs(evaluated(obj).astype(np.float64) - first).max()),
             "shows_key": float(np.abs(first - key3.reshape(-1, 3)).max()),
             "size": float(np.ptp(first, axis=0).max()), "modifier": "LA Fit" in obj.modifiers,
             "had_modifier": had_modifier}
    # fitting frames 3..5 again from Edit Mode: the keys of frames 2..4 go and stay gone on leaving it, the other keys
    # keep their coordinates
    def key_bytes():
        out = {}
        for kb in obj.data.shape_keys.key_blocks:
            co = np.empty(3 * len(kb.data), np.float32)
            kb.data.foreach_get("co", co)
            out[kb.name] = co.tobytes()
        return out
    before_edit = key_bytes()
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='EDIT')
    result = sorted(bpy.ops.lengths_angles.fit_markers(output='SHAPE_KEYS', use_scene_range=False, frame_start=3,
                                                       frame_end=5))
    mode = obj.mode
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='OBJECT')
    after_edit = key_bytes()
    again["edit_mode"] = {"result": result, "mode": mode, "names": list(after_edit)[n_before:],
                          "others_kept": all(after_edit[n] == before_edit[n] for n in list(before_edit)[:n_before])}
    assert bpy.ops.lengths_angles.fit_markers(output='SHAPE_KEYS', use_scene_range=False, frame_start=2,
                                              frame_end=4) == {"FINISHED"}
    scene.frame_set(2)
    scene.frame_set(3)
    # a training key left on adds to the fitted keys: the fit's report says so (keys_on_note)
    fit_ops = ext("addon.operators_fit")
    again["note_off"] = fit_ops.keys_on_note(obj)
    kb = obj.data.shape_keys.key_blocks["train01"]
    kb.value = 0.4
    again["on_shown_vs_key"] = float(np.abs(evaluated(obj).astype(np.float64) - key3.reshape(-1, 3)).max())
    again["note_on"] = fit_ops.keys_on_note(obj)
    kb.mute = True
    again["note_muted"] = fit_ops.keys_on_note(obj)
    kb.mute, kb.value = False, 0.0
    # a clip too long for shape keys
    scene.frame_start, scene.frame_end = 1, 200
    before = state(obj)
    try:
        res = bpy.ops.lengths_angles.fit_markers(output='SHAPE_KEYS')
    except RuntimeError:  # bpy.ops raise on ERROR reports
        res = {"CANCELLED"}
    return {"names": names, "values_at_3": values, "too_long": sorted(res), "too_long_unchanged": state(obj) == before,
            "again": again}


def bad_input():
    """No model, not bound, take too short, empties deleted, mesh edited: ERROR, nothing changed."""
    out = {}
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    scene = bpy.context.scene
    obj = bpy.data.objects["Body"]
    take = bpy.data.objects["take"]
    T = INPUTS["true"].shape[0]

    def attempt(name, op, **kw):
        before = state(obj)
        try:
            res = op(**kw)
            msg = ""
        except RuntimeError as exc:  # bpy.ops raise on ERROR reports
            res, msg = {"CANCELLED"}, str(exc)
        out[name] = {"result": sorted(res), "message": msg, "unchanged": state(obj) == before}

    select_only(obj)
    scene.frame_start, scene.frame_end = 1, T + 5
    attempt("take_too_short", bpy.ops.lengths_angles.fit_markers)
    attempt("range_reversed", bpy.ops.lengths_angles.fit_markers, use_scene_range=False, frame_start=10, frame_end=5)
    scene.frame_end = T
    t0 = time.perf_counter()
    attempt("unwritable_cache", bpy.ops.lengths_angles.fit_markers, filepath="/proc/fit.pc2")
    out["unwritable_cache"]["seconds"] = time.perf_counter() - t0
    dup = obj.shape_key_add(name="dup", from_mix=False)                 # a copy of train01
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.shape_keys.key_blocks["train01"].data.foreach_get("co", co)
    dup.data.foreach_set("co", co)
    attempt("build_identical_keys", bpy.ops.lengths_angles.build_model, keys="train00, train01, dup")
    obj.shape_key_remove(dup)
    # a key with two vertices collapsed onto one: the faces holding both have no area
    flat = obj.shape_key_add(name="flat", from_mix=False)
    faces = np.asarray(INPUTS["faces"])
    a, b = (int(v) for v in faces[7][:2])
    obj.data.shape_keys.key_blocks["train01"].data.foreach_get("co", co)
    co = co.reshape(-1, 3)
    co[b] = co[a]
    flat.data.foreach_set("co", co.ravel())
    attempt("build_degenerate_key", bpy.ops.lengths_angles.build_model, keys="train00, flat, train02")
    out["build_degenerate_key"]["faces"] = np.flatnonzero((faces == a).any(1) & (faces == b).any(1)).tolist()
    obj.shape_key_remove(flat)
    meta = obj.data["lengths_angles_model"].to_dict()
    del obj.data["lengths_angles_model"]
    attempt("no_model", bpy.ops.lengths_angles.fit_markers)
    select_only(obj, take)
    attempt("bind_without_model", bpy.ops.lengths_angles.bind_markers)
    obj.data["lengths_angles_model"] = meta
    scene.frame_set(3)  # markers 3, 10, 20 are occluded at frames 3..5: with only those selected none is visible
    labels = [lb for lb, _ in ext("addon.operators_markers").marker_objects(take)]
    hidden = [c for c in take.children if c.get("lengths_angles_marker") in [labels[i] for i in (3, 10, 20)]]
    select_only(obj, *hidden)
    attempt("bind_occluded", bpy.ops.lengths_angles.bind_markers)
    select_only(obj, take)
    scene.frame_set(1)
    binding = obj["lengths_angles_binding"].to_dict()
    del obj["lengths_angles_binding"]
    select_only(obj)
    attempt("not_bound", bpy.ops.lengths_angles.fit_markers)
    obj["lengths_angles_binding"] = binding
    # a bound marker's empty renamed (the label stays): the fit runs; the take renamed: it is not found
    next(c for c in take.children if c.get("lengths_angles_marker") == binding["labels"][5]).name = "renamed"
    out["empty_renamed"] = sorted(bpy.ops.lengths_angles.fit_markers())
    take.name = "take renamed"
    attempt("take_renamed", bpy.ops.lengths_angles.fit_markers)
    take.name = "take"
    victim = next(c for c in take.children if c.get("lengths_angles_marker") == binding["labels"][3])
    bpy.data.objects.remove(victim)
    attempt("empty_deleted", bpy.ops.lengths_angles.fit_markers)
    # mesh edited: one vertex deleted
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    import bmesh
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    bmesh.ops.delete(bm, geom=[bm.verts[0]], context='VERTS')
    bm.to_mesh(obj.data)
    bm.free()
    select_only(obj)
    attempt("mesh_edited", bpy.ops.lengths_angles.fit_markers)
    # a vertex deleted in Edit Mode, Model Pose to Shape Key there
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    select_only(obj)
    keys = [kb.name for kb in obj.data.shape_keys.key_blocks]
    bpy.ops.object.mode_set(mode='EDIT')
    bm = bmesh.from_edit_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    bmesh.ops.delete(bm, geom=[bm.verts[0]], context='VERTS')
    bmesh.update_edit_mesh(obj.data)
    try:
        res, msg = sorted(bpy.ops.lengths_angles.model_pose_to_shape_key(name="pose")), ""
    except RuntimeError as exc:
        res, msg = ["CANCELLED"], str(exc)
    mode = obj.mode
    bpy.ops.object.mode_set(mode='OBJECT')
    out["pose_key_edit_mode_edited"] = {"result": res, "message": msg, "mode": mode,
                                        "unchanged": [kb.name for kb in obj.data.shape_keys.key_blocks] == keys}
    return out


def model_storage():
    """The model's .npz is a payload text, not in the mesh record: it survives undo, a duplicate shares it until
    either is removed, two objects have one each; a record of earlier versions (.npz inside) is read and
    migrated to a text on the next save."""
    fit, storage = ext("addon.operators_fit"), ext("addon.storage")
    path = os.path.join(ARGS.workdir, "fit.blend")
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Body"]
    meta = obj.data[fit.MODEL_PROP].to_dict()
    text = bpy.data.texts[meta["text"]]
    n_modes = fit.read_model(obj).n_modes
    out = {"record": sorted(meta), "record_chars": len(repr(meta)), "text_chars": len(text.as_string()),
           "text": text.name, "fake_user": text.use_fake_user}
    # undo brings a removed model back
    bpy.ops.ed.undo_push(message="model")
    fit.remove_model(obj)
    out["removed_text_gone"] = meta["text"] not in bpy.data.texts
    bpy.ops.ed.undo_push(message="model removed")
    bpy.ops.ed.undo()
    obj = bpy.data.objects["Body"]
    out["undo_n_modes"] = int(fit.read_model(obj).n_modes) if fit.MODEL_PROP in obj.data else None
    # a duplicate (Shift+D copies the mesh) shares the text; removing one model keeps the other's
    select_only(obj)
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.duplicate()
    copy = bpy.context.view_layer.objects.active
    out["copy_mesh_differs"] = copy.data != obj.data
    out["copy_n_modes"] = int(fit.read_model(copy).n_modes)
    fit.remove_model(copy)
    out["text_kept_for_original"] = meta["text"] in bpy.data.texts and fit.read_model(obj).n_modes == n_modes
    # two objects with a model each: two texts
    fit.store_model(copy.data, fit.read_model(obj), meta["keys"])
    out["two_texts"] = sorted(t.name for t in bpy.data.texts)
    fit.remove_model(obj)
    out["after_removing_original"] = sorted(t.name for t in bpy.data.texts)
    out["copy_still_reads"] = int(fit.read_model(copy).n_modes)
    # a record of earlier versions: the .npz base64-encoded inside it
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Body"]
    meta = obj.data[fit.MODEL_PROP].to_dict()
    data = storage.load_payload(meta, fit.MODEL_HEADER)
    bpy.data.texts.remove(bpy.data.texts[meta["text"]])
    obj.data[fit.MODEL_PROP] = {"npz_base64": base64.b64encode(data).decode("ascii"), "keys": meta["keys"],
                                "n_vertices": meta["n_vertices"], "n_modes": meta["n_modes"]}
    out["legacy_n_modes"] = int(fit.read_model(obj).n_modes)
    legacy = os.path.join(ARGS.workdir, "legacy_model.blend")
    bpy.ops.wm.save_as_mainfile(filepath=legacy)
    bpy.ops.wm.open_mainfile(filepath=legacy)
    obj = bpy.data.objects["Body"]
    migrated = obj.data[fit.MODEL_PROP].to_dict()
    out["migrated_record"] = sorted(migrated)
    out["migrated_n_modes"] = int(fit.read_model(obj).n_modes)
    out["migrated_same_bytes"] = storage.load_payload(migrated, fit.MODEL_HEADER) == data
    out["n_modes"] = int(n_modes)
    return out


def make_runs(context, obj, take):
    """Build model (all keys), Bind (with ICP: one progress unit per iteration) and Fit (one per frame) runs."""
    fit = ext("addon.operators_fit")
    T = INPUTS["true"].shape[0]
    return {"build_model": lambda: fit.model_run(obj),
            "bind_markers": lambda: fit.bind_run(context, obj, take, align=True),
            "fit_markers": lambda: fit.fit_run(context, obj, 1, T)}


def hold_after_first_progress(run):
    """Make the run's worker wait after its first progress report until the returned event is set, so that Esc
    arrives while the step computes however fast the machine is (the job's own progress callback still decides
    whether lacore stops)."""
    import threading

    job, report, released = run.job, run.job._progress, threading.Event()

    def progress(done, total, message=""):
        report(done, total, message)
        if job.done > 0:
            released.wait(120)
        return job.cancelled
    job._progress = progress
    return released


def runs_progress_and_cancel():
    """Each long operator of the model/marker panel through the one run mechanism: modal steps in the worker
    thread with progress; Esc while a step computes cancels it (lacore raises Cancelled inside the step) and
    changes nothing; a full modal run writes what the synchronous operator writes."""
    runs = ext("addon.runs")
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    select_only(obj)
    obj.modifiers.remove(obj.modifiers["LA Fit"])
    scene = bpy.context.scene
    scene.frame_set(1)
    out = {}
    for name, make in make_runs(bpy.context, obj, take).items():
        before = state(obj)
        op, run = fake_operator(), make()
        released = hold_after_first_progress(run)
        op._begin_modal(bpy.context, run)
        # Esc once the job has reported progress (or its step has ended)
        state_, seen = drive(op, run, until=lambda r, op=op: r.done > 0 or (op._future is not None
                                                                              and op._future.done()))
        future = op._future
        cancelled = op.modal(bpy.context, esc())
        released.set()
        runs.wait_for_worker_thread()
        try:
            future.result()
            raised = None
        except Exception as exc:  # the cancelled step's exception type is what is checked
            raised = type(exc).__name__
        out[name] = {"running": sorted(state_), "cancel": sorted(cancelled), "reports": op.reports,
                     "step_raised": raised, "seen_before_cancel": seen[-1], "unchanged": state(obj) == before,
                     "total": run.total}
    # full modal runs (bind without ICP, as its default): FINISHED, written, progress seen along the way
    for name, make in (("build_model", lambda: ext("addon.operators_fit").model_run(obj)),
                       ("bind_markers", lambda: ext("addon.operators_fit").bind_run(bpy.context, obj, take)),
                       ("fit_markers", make_runs(bpy.context, obj, take)["fit_markers"])):
        op, run = fake_operator(), make()
        op._begin_modal(bpy.context, run)
        final, seen = drive(op, run)
        out[name]["full"] = {"state": sorted(final), "reports": [r[0] for r in op.reports], "seen": seen,
                             "interactive_after": op.interactive}
    out["fit_markers"]["full"]["modifier"] = "LA Fit" in obj.modifiers
    return out


def runs_object_changed():
    """What a run read changes before it writes: the run writes nothing and names the change (each of
    Build / Bind / Fit; the run is computed synchronously, the scene changed, then finished)."""
    import bmesh

    fit = ext("addon.operators_fit")
    out = {}

    def attempt(label, make, change):
        bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
        obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
        select_only(obj)
        bpy.context.scene.frame_set(1)
        run = make(bpy.context, obj, take)
        run.run()
        change(obj, take)
        obj = bpy.data.objects.get("Body")
        changed = state(obj) if obj is not None else None
        op = fake_operator()
        result = op._finish_run(run)
        out[label] = {"result": sorted(result), "message": op.reports[-1][1],
                      "unchanged": (state(obj) if obj is not None else None) == changed}

    def edit_key(obj, take):
        kb = obj.data.shape_keys.key_blocks["train03"]
        kb.data[0].co.x += 0.1

    def edit_mode(obj, take):
        with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
            bpy.ops.object.mode_set(mode='EDIT')

    def delete_vertex(obj, take):
        bm = bmesh.new()
        bm.from_mesh(obj.data)
        bm.verts.ensure_lookup_table()
        bmesh.ops.delete(bm, geom=[bm.verts[0]], context='VERTS')
        bm.to_mesh(obj.data)
        bm.free()

    def flip_face(obj, take):            # the same counts, other connectivity
        bm = bmesh.new()
        bm.from_mesh(obj.data)
        bm.faces.ensure_lookup_table()
        bmesh.ops.reverse_faces(bm, faces=[bm.faces[0]])
        bm.to_mesh(obj.data)
        bm.free()

    def other_frame(obj, take):
        bpy.context.scene.frame_set(2)

    def delete_marker(obj, take):
        bpy.data.objects.remove(next(c for c in take.children if "lengths_angles_marker" in c))

    def rebuild_model(obj, take):
        with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
            assert bpy.ops.lengths_angles.build_model(n_modes=2) == {'FINISHED'}

    def delete_object(obj, take):
        bpy.data.objects.remove(obj)

    # small runs (4 training keys, 2 frames): the check is about what happens after them
    build = lambda context, obj, take: fit.model_run(obj, [f"train{k:02d}" for k in range(4)])  # noqa: E731
    bind = lambda context, obj, take: fit.bind_run(context, obj, take)  # noqa: E731
    fit_ = lambda context, obj, take: fit.fit_run(context, obj, 1, 2)  # noqa: E731
    attempt("build_key_edited", build, edit_key)
    attempt("build_edit_mode", build, edit_mode)
    attempt("bind_other_frame", bind, other_frame)
    attempt("bind_marker_deleted", bind, delete_marker)
    attempt("fit_mesh_edited", fit_, delete_vertex)
    attempt("fit_face_flipped", fit_, flip_face)
    attempt("fit_model_rebuilt", fit_, rebuild_model)
    attempt("fit_marker_deleted", fit_, delete_marker)
    attempt("fit_object_deleted", fit_, delete_object)
    return out


def script_defaults_and_paths():
    """Fit's Cache File takes '//' paths (no warning, written next to the .blend with the permissions of any
    new file); an unsaved .blend and a missing folder are named; Remove Data removes the model and binding."""
    import stat
    import warnings

    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    select_only(obj)
    os.makedirs(os.path.join(ARGS.workdir, "caches"), exist_ok=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = bpy.ops.lengths_angles.fit_markers(filepath="//caches/custom.pc2")
    path = os.path.join(ARGS.workdir, "caches", "custom.pc2")
    umask = os.umask(0)
    os.umask(umask)
    mode = stat.S_IMODE(os.stat(path).st_mode)
    out = {"result": sorted(result), "warnings": [str(w.message) for w in caught], "exists": os.path.isfile(path),
           "modifier_path": obj.modifiers["LA Fit"].filepath, "mode": oct(mode), "expected_mode": oct(0o666 & ~umask)}
    messages = {}
    for label, filepath in (("missing_folder", "//no/such/folder/x.pc2"),):
        before = state(obj)
        try:
            bpy.ops.lengths_angles.fit_markers(filepath=filepath)
        except RuntimeError as exc:
            messages[label] = {"message": str(exc), "unchanged": state(obj) == before}
    # Remove Data: encoding, model (and its preview key, sliders) and binding
    obj.lengths_angles_mode_weights[0] = 0.5
    ext("addon.operators_fit").update_previews()
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        assert bpy.ops.lengths_angles.remove_data() == {'FINISHED'}
    out["after_remove_data"] = {"mesh_props": sorted(obj.data.keys()), "object_props": sorted(obj.keys()),
                                "preview_key": "LA model preview" in obj.data.shape_keys.key_blocks,
                                "sliders": max(abs(v) for v in obj.lengths_angles_mode_weights)}
    # an unsaved .blend (the objects appended into a new file): '//' paths have nothing to be relative to
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(os.path.join(ARGS.workdir, "fit.blend"), link=False) as (src, dst):
        dst.objects = list(src.objects)
    for o in dst.objects:
        bpy.context.scene.collection.objects.link(o)
    obj = bpy.data.objects["Body"]
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, INPUTS["true"].shape[0]
    select_only(obj)
    assert bpy.data.filepath == ""
    for label, filepath in (("unsaved_relative", "//x.pc2"), ("unsaved_default", "")):
        before = state(obj)
        try:
            bpy.ops.lengths_angles.fit_markers(filepath=filepath)
        except RuntimeError as exc:
            messages[label] = {"message": str(exc), "unchanged": state(obj) == before}
    out["messages"] = messages
    return out


def operator_defaults(idname):
    """The fit settings' defaults of the registered operator ``idname`` (its RNA)."""
    props = getattr(bpy.ops.lengths_angles, idname).get_rna_type().properties
    return {"use_observed_radius": props["use_observed_radius"].default,
            "observed_radius": list(props["observed_radius"].default_array),
            "penetration_weight": props["penetration_weight"].default,
            "coefficient_weight": props["coefficient_weight"].default,
            "names": [props[k].name for k in ("use_observed_radius", "penetration_weight", "coefficient_weight")]}


def draw_operator(cls, **props):
    """``cls.draw`` into a layout recording ``(property, index, active)`` of every ``prop`` call (no GUI here)."""
    from types import SimpleNamespace
    drawn = []

    class Layout:
        def __init__(self, active=True):
            self.active = active

        def __getattr__(self, name):
            def record(*args, **kwargs):
                if name == "prop":
                    drawn.append((args[1], kwargs.get("index", -1), bool(self.active)))
                return Layout(self.active)
            return record

    cls.draw(SimpleNamespace(layout=Layout(), **props), bpy.context)
    return drawn


def fit_settings():
    """Modes Near Markers Only, Non-Penetration Weight and Training Range Weight of Fit to Markers: defaults from
    lacore's FitOptions, drawn with the prior and temporal weights, handed to lacore by the operator and by
    fit_run (the fit of frames 1-3 with the modes everywhere and no non-penetration term: its vertices and the
    markers as read are written for pytest to fit again with lacore), stored with the fit's quality and shown in
    the panel; bad values: one line, CANCELLED, nothing changed."""
    import doctest
    from types import SimpleNamespace

    fit, quality = ext("addon.operators_fit"), ext("addon.fit_quality")
    lacore_defaults = importlib.import_module(f"{MODULE}.lacore.markers.fitting").FIT_DEFAULTS
    out = {"operator_defaults": {name: operator_defaults(name) for name in ("fit_markers", "calibrate_fit")},
           "lacore_defaults": {"observed_radius": list(lacore_defaults.observed_radius),
                               "penetration_weight": lacore_defaults.penetration_weight,
                               "coefficient_weight": lacore_defaults.coefficient_weight}}
    runner = doctest.DocTestRunner()
    for f in (fit.fit_settings, fit.typed, quality.settings_text, ext("addon.operators_markers").unkeyed_note,
              ext("addon.motion").expression_names):
        for test in doctest.DocTestFinder().find(f):
            runner.run(test)
    out["doctests"] = [runner.failures, runner.tries]
    ops = {"fit_markers": fit.LENGTHS_ANGLES_OT_fit_markers,
           "calibrate_fit": ext("addon.operators_calibrate").LENGTHS_ANGLES_OT_calibrate_fit}
    out["drawn"] = {f"{name}_{on}": draw_operator(cls, use_scene_range=True, output='PC2', auto_prior=False,
                                                   use_observed_radius=on)
                    for name, cls in ops.items() for on in (True, False)}
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    select_only(obj)
    obj.modifiers.remove(obj.modifiers["LA Fit"])
    # the operator: its properties reach the run and the record
    before = state(obj)
    result = bpy.ops.lengths_angles.fit_markers(use_scene_range=False, frame_start=1, frame_end=3,
                                                use_observed_radius=False, penetration_weight=0.0,
                                                coefficient_weight=0.5, filepath="//settings.pc2")
    q = obj[quality.FIT_PROP].to_dict()
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_mocap, SimpleNamespace(object=obj))
    out["operator"] = {"result": sorted(result), "changed": state(obj) != before, "settings": q["settings"],
                       "panel": [kw["text"] for name, _a, kw in calls
                                 if name == "label" and kw.get("text", "").startswith("Temporal")]}
    # fit_run: lacore's result with these settings and with the defaults, on the markers as the add-on read them
    arrays = {}
    for label, settings in (("settings", {"observed_radius": 0, "penetration_weight": 0.0}), ("defaults", {})):
        run = fit.fit_run(bpy.context, obj, 1, 3, filepath="//settings.pc2", **settings)
        run.run()
        op = fake_operator()
        finished = op._finish_run(run)
        res = run.job.result
        arrays[f"{label}_vertices"] = res.vertices
        arrays["markers"] = run.job.inputs["markers"]
        out[label] = {"result": sorted(finished), "settings": obj[quality.FIT_PROP]["settings"].to_dict(),
                      "penetration_off": res.frame_self_intersections is None}
    arrays["rate"] = np.array(bpy.context.scene.render.fps / bpy.context.scene.render.fps_base)
    np.savez(os.path.join(ARGS.workdir, "fit_settings.npz"), **arrays)
    # bad values: one line, CANCELLED, nothing changed (negative weights from scripts: the properties stop at 0)
    bad = {}
    for label, kw in (("radii_reversed", {"observed_radius": (0.3, 0.1)}),
                      ("radii_equal", {"observed_radius": (0.2, 0.2)})):
        before = state(obj)
        try:
            res, msg = bpy.ops.lengths_angles.fit_markers(use_scene_range=False, frame_start=1, frame_end=3, **kw), ""
        except RuntimeError as exc:  # bpy.ops raise on ERROR reports
            res, msg = {"CANCELLED"}, str(exc).strip()
        bad[label] = {"result": sorted(res), "message": msg, "lines": len(msg.splitlines()),
                      "unchanged": state(obj) == before}
    for label, kw in (("penetration_negative", {"penetration_weight": -1.0}),
                      ("coefficient_negative", {"coefficient_weight": -0.5}),
                      ("radius_negative", {"observed_radius": (-0.1, 0.2)})):
        before = state(obj)
        op = fake_operator()
        op.interactive = False
        res = op.start_run(bpy.context, lambda context, kw=kw: fit.fit_run(context, obj, 1, 3, **kw))
        msg = op.reports[-1][1] if op.reports else ""
        bad[label] = {"result": sorted(res), "message": msg, "lines": len(msg.splitlines()),
                      "kind": op.reports[-1][0] if op.reports else "", "unchanged": state(obj) == before}
    out["bad"] = bad
    return out


def finish(run):
    """Compute ``run`` synchronously and finish it as the operator does: ``(result, reports)``."""
    run.run()
    op = fake_operator()
    return sorted(op._finish_run(run)), op.reports


def one_line_attempt(out, name, obj, operator, **kw):
    """``operator(**kw)`` recorded in ``out[name]``: result, message, its line count, whether ``obj`` is unchanged."""
    before = state(obj)
    try:
        res, msg = operator(**kw), ""
    except RuntimeError as exc:  # bpy.ops raise on ERROR reports
        res, msg = {"CANCELLED"}, str(exc).strip()
    out[name] = {"result": sorted(res), "message": msg, "lines": len(msg.splitlines()),
                 "unchanged": state(obj) == before}


def still_verdict(take, obj):
    """``require_still(take, obj)``'s verdict: None, or the message it refuses with."""
    try:
        ext("addon.operators_fit").require_still(take, obj)
    except ext("lacore.errors").InputError as exc:
        return str(exc)
    return None


def seconds_per_still_check(take, obj, repeat=100):
    """Mean seconds of one ``require_still(take, obj)``, refusing or not."""
    t = time.perf_counter()
    for _ in range(repeat):
        still_verdict(take, obj)
    return (time.perf_counter() - t) / repeat


def cleared_marker():
    """A bound marker's empty with its animation cleared (Clear Keyframes): Fit to Markers fits the others (the
    marker never visible, said in one line) -- the markers and the fit are written for pytest to fit again with
    lacore; Bind Markers leaves it out, says so and lists it as not bound with why (the panel too); with every
    bound marker cleared the fit is refused."""
    fit, quality = ext("addon.operators_fit"), ext("addon.fit_quality")
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    select_only(obj)
    labels = list(obj[fit.BINDING_PROP]["labels"])
    label = labels[4]
    empties = {c["lengths_angles_marker"]: c for c in take.children if "lengths_angles_marker" in c}
    empties[label].animation_data_clear()
    run = fit.fit_run(bpy.context, obj, 1, 3)
    result, reports = finish(run)
    arrays = {"markers": run.job.inputs["markers"], "vertices": run.job.result.vertices}
    q = obj[quality.FIT_PROP].to_dict()
    out = {"label": label, "index": labels.index(label), "fit": {"result": result, "reports": reports,
                                                                  "marker_rms_mm": q["marker_rms_mm"],
                                                                  "flagged_markers": list(q["flagged_markers"])}}
    obj.modifiers.remove(obj.modifiers["LA Fit"])
    kb = obj.shape_key_add(name="bind pose", from_mix=False)
    kb.data.foreach_set("co", INPUTS["bind_pose"].astype(np.float32).ravel())
    kb.value = 1.0
    bpy.context.scene.frame_set(1)
    result, reports = finish(fit.bind_run(bpy.context, obj, take))
    binding = obj[fit.BINDING_PROP].to_dict()
    from types import SimpleNamespace
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_mocap, SimpleNamespace(object=obj))
    texts = [kw.get("text", "") for name, _args, kw in calls if name == "label"]
    out["bind"] = {"result": result, "reports": reports, "labels": list(binding["labels"]),
                   "not_bound": list(binding["not_bound"]), "not_bound_reasons": list(binding["not_bound_reasons"]),
                   "not_bound_texts": [t for t in texts if "not bound (" in t], "n_markers": len(empties)}
    obj.shape_key_remove(kb)
    for c in empties.values():
        c.animation_data_clear()
    select_only(obj)
    one_line_attempt(out, "all_cleared", obj, bpy.ops.lengths_angles.fit_markers)
    np.savez(os.path.join(ARGS.workdir, "cleared.npz"), **arrays)
    return out


def moving_setups():
    """What makes the take empty or the character move besides keys of its action: a driver on a transform channel,
    a constraint, an NLA strip (on a parent): Fit to Markers refuses in one line naming it, nothing changed; muted,
    disabled, influence 0, invalid, a muted or non-solo track: still.  require_still reads data only (timed)."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    select_only(obj)
    out, still = {}, {}

    def check(name):
        still[name] = still_verdict(take, obj)

    def attempt(name):
        one_line_attempt(out, name, obj, bpy.ops.lengths_angles.fit_markers, use_scene_range=False, frame_start=1,
                         frame_end=2)

    check("plain")
    fc = take.driver_add("location", 2)            # the take empty's Z driven
    fc.driver.expression = "frame / 100"
    attempt("take_driver")
    fc.mute = True
    check("muted_driver")
    take.driver_remove("location", 2)
    mover = bpy.data.objects.new("Mover", None)    # the character follows an object that moves
    bpy.context.scene.collection.objects.link(mover)
    mover.keyframe_insert("location", frame=1)
    mover.location.z = 1.0
    mover.keyframe_insert("location", frame=8)
    con = obj.constraints.new('COPY_LOCATION')
    con.name = "Follow Take"
    con.target = mover
    attempt("character_constraint")
    con.enabled = False
    check("disabled_constraint")
    con.enabled, con.influence = True, 0.0
    check("constraint_no_influence")
    con.influence, con.target = 1.0, None          # no target: invalid, Blender does not evaluate it
    check("invalid_constraint")
    obj.constraints.remove(con)
    rig = bpy.data.objects.new("Rig", None)        # a parent played by an NLA strip
    bpy.context.scene.collection.objects.link(rig)
    obj.parent = rig
    rig.keyframe_insert("location", frame=1)
    rig.location.x = 1.0
    rig.keyframe_insert("location", frame=8)
    rig.location.x = 0.0
    action = rig.animation_data.action
    track = rig.animation_data.nla_tracks.new()
    track.name = "Walk Track"
    track.strips.new("Walk", 1, action)
    rig.animation_data.action = None
    bpy.context.view_layer.update()
    attempt("parent_nla")
    t = time.perf_counter()
    for _ in range(100):
        check("nla_timed")
    out["seconds_per_check"] = (time.perf_counter() - t) / 100
    track.mute = True
    check("muted_track")
    track.mute = False
    solo = rig.animation_data.nla_tracks.new()
    solo.is_solo = True
    check("other_track_solo")
    out["still"] = still
    return out


def evaluated_motion(ob, frames=(1, 8)):
    """How far ``ob``'s origin moves between ``frames`` (frame_set; the scene is reopened after each case)."""
    scene, where = bpy.context.scene, []
    for f in frames:
        scene.frame_set(f)
        where.append(np.array(ob.matrix_world.translation))
    scene.frame_set(1)
    return float(np.linalg.norm(where[-1] - where[0]))


def constant_setups():
    """Drivers and constraints whose effect cannot change over time (a constant expression, variables reading a
    property or a transform that nothing animates, a constraint following an object that stands still) are no
    reason to refuse; the same setups made to change (the property keyed, the target keyed, the influence keyed, a
    'frame' in the expression) and constraint types that read time or geometry are refused.  Each verdict is
    compared with the take's or the character's evaluated motion over the take (frame_set); checks timed."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    select_only(obj)
    out, verdict, motion, timing = {}, {}, {}, {}

    def check(name, ob, timed=False):
        verdict[name] = still_verdict(take, obj)
        motion[name] = evaluated_motion(ob)
        if timed:
            timing[name] = seconds_per_still_check(take, obj)

    def link(ob):
        bpy.context.scene.collection.objects.link(ob)
        return ob

    z = take.location.z
    fc = take.driver_add("location", 2)            # the take empty's Z driven by a constant expression
    fc.driver.expression = f"{z} + 0 * pi"
    check("constant_expression", take, timed=True)
    control = link(bpy.data.objects.new("Control", None))
    control["height"] = z
    var = fc.driver.variables.new()                # a variable reading a property nothing animates
    var.name, var.targets[0].id, var.targets[0].data_path = "h", control, '["height"]'
    fc.driver.expression = "h"
    check("constant_property", take, timed=True)
    control.keyframe_insert('["height"]', frame=1)  # the property keyed changing: the take moves
    control["height"] = z + 1.0
    control.keyframe_insert('["height"]', frame=8)
    check("keyed_property", take)
    control.animation_data_clear()
    control["height"] = z
    var.type = 'TRANSFORMS'                        # the Z of an object standing still
    var.targets[0].id, var.targets[0].transform_type = control, 'LOC_Z'
    control.location.z = z
    check("still_transform", take, timed=True)
    fc.driver.expression = "h + frame / 100"       # the frame in the expression
    check("frame_expression", take)
    take.driver_remove("location", 2)
    take.location.z = z
    anchor = link(bpy.data.objects.new("Anchor", None))
    anchor.location = obj.matrix_world.translation
    con = obj.constraints.new('COPY_LOCATION')     # the character follows an object standing still
    con.name = "Follow Anchor"
    con.target = anchor
    check("constraint_still_target", obj, timed=True)
    anchor.keyframe_insert("location", frame=1)     # the target keyed moving
    anchor.location.x += 1.0
    anchor.keyframe_insert("location", frame=8)
    check("constraint_moving_target", obj)
    anchor.animation_data_clear()
    anchor.location = obj.matrix_world.translation
    curve = link(bpy.data.objects.new("Path", bpy.data.curves.new("Path", 'CURVE')))
    path = obj.constraints.new('FOLLOW_PATH')      # a type that reads time: refused whatever it does
    path.name, path.target = "On Path", curve
    check("follow_path", obj)
    obj.constraints.remove(path)
    obj.keyframe_insert('constraints["Follow Anchor"].influence', frame=1)  # its influence keyed changing
    con.influence = 0.0
    obj.keyframe_insert('constraints["Follow Anchor"].influence', frame=8)
    anchor.location.x += 1.0
    check("keyed_influence", obj)
    select_only(obj)
    return {"verdict": verdict, "motion": motion, "timing": timing, **out}


def add_rig():
    """An armature 'Rig' with bones Arm > Hand > Finger and Other (Edit Mode in background Blender)."""
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    select_only(rig)
    bpy.ops.object.mode_set(mode='EDIT')
    bones = rig.data.edit_bones
    parent = None
    for name, head, tail in (("Arm", (0, 0, 0), (0, 0, 1)), ("Hand", (0, 0, 1), (0, 0, 2)),
                             ("Finger", (0, 0, 2), (0, 0, 2.5))):
        b = bones.new(name)
        b.head, b.tail, b.parent = head, tail, parent
        parent = b
    other = bones.new("Other")
    other.head, other.tail = (1, 0, 0), (1, 0, 1)
    bpy.ops.object.mode_set(mode='OBJECT')
    return rig


def parent_links():
    """The take empty parented to a bone (parent type Bone) of an animated armature, or to vertices of a deformed
    mesh: Fit to Markers refuses in one line naming the bone or the mesh and what to do, nothing changed (before:
    read as still, the markers placed wrongly); a bone whose pose does not change (keys on another bone, Rest
    Position) and a mesh that is not deformed (a Subdivision Surface) are still.  Each verdict is compared with the
    take empty's evaluated motion (frame_set); the check stays data only (timed)."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    rig = add_rig()
    take.parent, take.parent_type, take.parent_bone = rig, 'BONE', "Hand"
    select_only(obj)
    out, verdict, motion = {}, {}, {}

    def check(name):
        verdict[name] = still_verdict(take, obj)
        motion[name] = evaluated_motion(take)

    def attempt(name):
        one_line_attempt(out, name, obj, bpy.ops.lengths_angles.fit_markers, use_scene_range=False, frame_start=1,
                         frame_end=2)

    def key_bone(bone, path="rotation_euler", value=(0.5, 0.0, 0.0)):
        pb = rig.pose.bones[bone]
        pb.rotation_mode = 'XYZ'
        pb.keyframe_insert(path, frame=1)
        setattr(pb, path, value)
        pb.keyframe_insert(path, frame=8)
        setattr(pb, path, (0.0, 0.0, 0.0))

    check("bone_still")
    key_bone("Other")                              # another bone keyed: the take's bone does not move
    check("other_bone_keyed")
    key_bone("Hand")
    attempt("bone_keyed")
    check("bone_keyed")
    out["seconds_per_check"] = seconds_per_still_check(take, obj)
    rig.data.pose_position = 'REST'                # the armature in Rest Position: no pose is played
    check("rest_position")
    rig.data.pose_position = 'POSE'
    rig.animation_data_clear()
    key_bone("Arm", "location", (0.0, 0.3, 0.0))   # an ancestor bone keyed
    attempt("ancestor_keyed")
    check("ancestor_keyed")
    rig.animation_data_clear()
    target = bpy.data.objects.new("Target", None)
    bpy.context.scene.collection.objects.link(target)
    target.location = (0.0, 2.0, 2.0)
    ik = rig.pose.bones["Finger"].constraints.new('IK')  # an IK chain from a child bone through the take's bone
    ik.name, ik.target, ik.chain_count = "Reach", target, 2
    target.keyframe_insert("location", frame=1)
    target.location = (0.0, -2.0, 1.0)
    target.keyframe_insert("location", frame=8)
    check("ik_from_child")
    rig.pose.bones["Finger"].constraints.remove(ik)
    take.parent_bone = ""
    blob = bpy.data.objects.new("Blob", bpy.data.meshes.new("Blob"))
    blob.data.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)], [], [(0, 1, 3, 2)])
    bpy.context.scene.collection.objects.link(blob)
    take.parent, take.parent_type = blob, 'VERTEX'
    take.parent_vertices[0] = 3
    check("vertex_still")
    blob.modifiers.new("Subdivision", 'SUBSURF')   # static: the same at every frame
    check("vertex_subdivided")
    blob.shape_key_add(name="Basis")
    up = blob.shape_key_add(name="Up")
    for v in up.data:
        v.co.z += 1.0
    up.value = 0.0                                 # (a new key's value is not 0 in every Blender)
    up.keyframe_insert("value", frame=1)           # the shape key keyed: the vertices move
    up.value = 1.0
    up.keyframe_insert("value", frame=8)
    up.value = 0.0
    attempt("shape_keyed")
    check("shape_keyed")
    blob.shape_key_clear()
    arm = blob.modifiers.new("Armature", 'ARMATURE')  # deformed by an armature whose pose is keyed
    arm.object = rig
    group = blob.vertex_groups.new(name="Hand")
    group.add([0, 1, 2, 3], 1.0, 'REPLACE')
    blob.modifiers.move(1, 0)
    key_bone("Hand")
    check("armature_deformed")
    return {"verdict": verdict, "motion": motion, **out}


def take_rate():
    """The scene's frame rate changed after import (the take at 10 Hz, one sample per frame): Fit to Markers hands
    lacore the take's rate, and fits the same as at the scene's original rate."""
    fit = ext("addon.operators_fit")
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    select_only(obj)
    render = bpy.context.scene.render
    original, rates, vertices = fit.fit_markers, [], []

    def spy(*args, **kwargs):
        rates.append(kwargs["rate"])
        return original(*args, **kwargs)
    fit.fit_markers = spy
    try:
        for fps, base in ((render.fps, render.fps_base), (24, 1.0), (30, 1.001)):
            render.fps, render.fps_base = fps, base
            run = fit.fit_run(bpy.context, obj, 1, 3)
            assert finish(run)[0] == ["FINISHED"]
            vertices.append(run.job.result.vertices)
    finally:
        fit.fit_markers = original
    return {"rates": rates, "max_difference": float(max(np.abs(v - vertices[0]).max() for v in vertices[1:]))}


def posed_for_binding(placement=None, keep_fit=False):
    """whole_path's scene reopened, 'Body' posed like the take's first frame (a shape key 'bind pose' at 1) at frame
    1, placed at ``placement`` (location, rotation, scale) if given, its fit's modifier removed unless ``keep_fit``;
    'Body' and the take selected.  Returns (body, take, the pose key)."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    if not keep_fit:
        obj.modifiers.remove(obj.modifiers["LA Fit"])
    if placement is not None:
        obj.location, obj.rotation_euler, obj.scale = placement
    kb = obj.shape_key_add(name="bind pose", from_mix=False)
    kb.data.foreach_set("co", INPUTS["bind_pose"].astype(np.float32).ravel())
    kb.value = 1.0
    bpy.context.scene.frame_set(1)
    select_only(obj, take)
    return obj, take, kb


def bind_record(obj, take):
    """Bind Markers' run on ``obj`` and ``take`` finished as the operator does: its result and reports and the binding
    stored (labels, faces, barycentric coordinates, offsets), or the refusal's message."""
    fit = ext("addon.operators_fit")
    try:
        result, reports = finish(fit.bind_run(bpy.context, obj, take))
    except ext("lacore.errors").InputError as exc:
        return {"result": ["CANCELLED"], "message": str(exc)}
    b = obj[fit.BINDING_PROP].to_dict()
    return {"result": result, "reports": reports, "labels": list(b["labels"]), "faces": list(b["faces"]),
            "barycentric": list(b["barycentric"]), "offsets": list(b["offsets"])}


def bind_failing(obj, take):
    """Bind Markers on ``obj`` failing while it evaluates the mesh (a simulated error): ``"<type>: <message>"`` of
    the error it raised, "" if none."""
    fit = ext("addon.operators_fit")
    original = fit._evaluated_co

    def failing(*args):
        raise RuntimeError("simulated failure while evaluating")
    fit._evaluated_co = failing
    try:
        fit.bind_run(bpy.context, obj, take)
        return ""
    except Exception as exc:  # the simulated failure, not another one
        return f"{type(exc).__name__}: {exc}"
    finally:
        fit._evaluated_co = original


def bind_with_modifiers():
    """Subdivision Surface and Mirror on the character (the vertex count changed): Bind Markers binds the mesh of
    its shape keys and leading deformers -- the same binding as without them; the modifiers' viewport switches
    are back as they were (also after an error); a deformer at the top of the stack counts."""
    obj, take, _ = posed_for_binding()
    out = {"plain": bind_record(obj, take)}
    sub = obj.modifiers.new("Subdivision", 'SUBSURF')
    sub.levels = 1
    obj.modifiers.new("Mirror", 'MIRROR')
    hidden = obj.modifiers.new("Displace", 'DISPLACE')
    hidden.show_viewport = False                   # off before: stays off
    out["evaluated_before"] = len(evaluated(obj))
    out["subdivided"] = bind_record(obj, take)
    out["shown_after"] = [m.show_viewport for m in obj.modifiers]
    out["evaluated_after"] = len(evaluated(obj))
    out["n_vertices"] = len(obj.data.vertices)
    out["error"] = bind_failing(obj, take)
    out["shown_after_error"] = [m.show_viewport for m in obj.modifiers]
    top = obj.modifiers.new("Inflate", 'DISPLACE')  # a deformer at the top: the bound mesh is inflated
    top.strength = 0.1
    obj.modifiers.move(len(obj.modifiers) - 1, 0)
    out["deformed"] = bind_record(obj, take)
    out["modifiers"] = [m.name for m in obj.modifiers]
    return out


def bind_with_preview_key():
    """Bind Markers with the mode sliders' preview key on (mode 1 at +1 std: the key 'LA model preview' at 1, which
    adds the model's pose to the character's): the binding is of the character as posed without it, the same as
    with no preview key; the key is muted while the mesh is read and as it was after, also after an error.  Records
    how far the preview moves the mesh and the mesh the binding saw."""
    fit = ext("addon.operators_fit")
    obj, take, _ = posed_for_binding()
    pose = fit._mesh_vertices(obj)
    out = {"plain": bind_record(obj, take)}
    obj.lengths_angles_mode_weights[0] = 1.0
    fit.update_previews()                          # the slider's timer callback
    preview = obj.data.shape_keys.key_blocks[fit.PREVIEW_KEY]
    out["preview"] = {"value": preview.value, "mute": preview.mute}
    out["preview_moves"] = float(np.linalg.norm(evaluated(obj) - pose, axis=1).max())
    out["seen_minus_pose"] = float(np.linalg.norm(fit._mesh_vertices(obj) - pose, axis=1).max())
    out["previewed"] = bind_record(obj, take)
    out["after"] = {"value": preview.value, "mute": preview.mute}
    out["error"] = bind_failing(obj, take)
    out["after_error"] = {"value": preview.value, "mute": preview.mute}
    return out


def skin_body(obj):
    """An armature 'Skin' standing in the body (bones Lower and Upper along its longest axis) placed off the origin,
    and the body's vertex groups Lower and Upper (below / above the middle, weight 1); Upper's rotation keyed from 0
    at frame 1 (the rest pose: the binding's mesh) to 0.4 rad at frame 8.  Returns the armature."""
    X = INPUTS["basis"]
    axis = int(np.argmax(np.ptp(X, axis=0)))
    lo, hi = X[:, axis].min(), X[:, axis].max()
    mid = 0.5 * (lo + hi)
    centre = X.mean(0)
    rig = bpy.data.objects.new("Skin", bpy.data.armatures.new("Skin"))
    bpy.context.scene.collection.objects.link(rig)
    rig.location, rig.rotation_euler = (0.3, -0.2, 0.1), (0.0, 0.0, 0.3)
    bpy.context.view_layer.update()
    select_only(rig)
    bpy.ops.object.mode_set(mode='EDIT')
    inv = np.linalg.inv(np.array(rig.matrix_world))

    def at(v):                                     # a point of the body's (object = world) space in the rig's
        p = centre.copy()
        p[axis] = v
        return tuple(inv[:3, :3] @ p + inv[:3, 3])
    lower = rig.data.edit_bones.new("Lower")
    lower.head, lower.tail = at(lo), at(mid)
    upper = rig.data.edit_bones.new("Upper")
    upper.head, upper.tail, upper.parent = at(mid), at(hi), lower
    bpy.ops.object.mode_set(mode='OBJECT')
    above = X[:, axis] > mid
    obj.vertex_groups.new(name="Lower").add(np.flatnonzero(~above).tolist(), 1.0, 'REPLACE')
    obj.vertex_groups.new(name="Upper").add(np.flatnonzero(above).tolist(), 1.0, 'REPLACE')
    pb = rig.pose.bones["Upper"]
    pb.rotation_mode = 'XYZ'
    pb.keyframe_insert("rotation_euler", frame=1)
    pb.rotation_euler = (0.4, 0.0, 0.0)
    pb.keyframe_insert("rotation_euler", frame=8)
    pb.rotation_euler = (0.0, 0.0, 0.0)
    return rig


def world(obj, X):
    """Object-space positions ``X`` of ``obj`` in world space (its evaluated placement at the current frame)."""
    M = np.array(obj.matrix_world, np.float64)
    return np.asarray(X, np.float64) @ M[:3, :3].T + M[:3, 3]


SHOWN_FRAMES = (1, 3, 5, 8)


def shown_minus_fit(obj, fitted, frames=SHOWN_FRAMES, first=1):
    """Per frame of ``frames``: the largest world-space distance between the evaluated mesh (depsgraph) and the
    fitted frame ``fitted[f - first]`` (object space) mapped to world."""
    out = []
    for f in frames:
        bpy.context.scene.frame_set(f)
        out.append(float(np.linalg.norm(world(obj, evaluated(obj)) - world(obj, fitted[f - first]), axis=1).max()))
    bpy.context.scene.frame_set(1)
    return out


def deformer_motion(obj, frames=(1, 8)):
    """How far the deformers move the mesh between ``frames`` with the fit's modifier off: the largest vertex
    displacement in world space (the motion the fit's point cache replaces)."""
    mod = obj.modifiers.get("LA Fit")
    if mod is not None:
        mod.show_viewport = False
    shown = []
    for f in frames:
        bpy.context.scene.frame_set(f)
        shown.append(world(obj, evaluated(obj)))
    if mod is not None:
        mod.show_viewport = True
    bpy.context.scene.frame_set(1)
    return float(np.linalg.norm(shown[-1] - shown[0], axis=1).max())


def keys_shown(obj, frames=SHOWN_FRAMES):
    """The fitted frames as written in the shape keys 'LA fit <f>' (object space), ``{frame: (V, 3)}``."""
    out = {}
    for f in frames:
        co = np.empty(3 * len(obj.data.vertices), np.float32)
        obj.data.shape_keys.key_blocks[f"LA fit {f}"].data.foreach_get("co", co)
        out[f] = co.reshape(-1, 3).astype(np.float64)
    return out


def armature_character():
    """The body skinned to an armature whose pose is keyed over the take: Fit to Markers (point cache) with an
    Armature modifier (added after an earlier fit's modifier: the new fit goes after it), with the armature object
    itself keyed moving (the character stays: the fit replaces the motion), and parented with parent type Armature
    (the deforming parent Blender evaluates before the stack): the evaluated mesh at frames 1, 3, 5, 8 is the fit,
    in world space.  The shape-key output with either (the armature would deform the keys again) is refused in one
    line, nothing changed, and so is it under a lattice parent (parent type Lattice); the armature object keyed moving
    the parented character: refused.  Records what was
    shown when an output was written, and how far the armature moves the mesh by itself."""
    fit = ext("addon.operators_fit")
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    rig = skin_body(obj)
    out = {"size": float(np.linalg.norm(np.ptp(INPUTS["basis"], axis=0)))}

    def pc2(name):
        select_only(obj)
        run = fit.fit_run(bpy.context, obj, 1, 8)
        result, reports = finish(run)
        out[name] = {"result": result, "modifiers": [m.name for m in obj.modifiers],
                     "shown_minus_fit": shown_minus_fit(obj, run.job.result.vertices),
                     "deformer_motion": deformer_motion(obj)}

    def shape_keys(name):
        select_only(obj)
        one_line_attempt(out, name, obj, bpy.ops.lengths_angles.fit_markers, output='SHAPE_KEYS',
                         use_scene_range=False, frame_start=1, frame_end=8)
        if out[name]["result"] == ["FINISHED"]:   # what a written shape-key fit shows
            keys = keys_shown(obj)
            shown = []
            for f in SHOWN_FRAMES:
                bpy.context.scene.frame_set(f)
                shown.append(float(np.linalg.norm(world(obj, evaluated(obj)) - world(obj, keys[f]), axis=1).max()))
            out[name]["shown_minus_keys"] = shown
            bpy.context.scene.frame_set(1)
            fit.remove_fit_keys(obj)

    mod = obj.modifiers.new("Armature", 'ARMATURE')   # added after whole_path's fit modifier
    mod.object = rig
    out["modifiers_before"] = [m.name for m in obj.modifiers]
    pc2("modifier")
    shape_keys("modifier_shape_keys")
    out["modifier_still"] = still_verdict(take, obj)
    home = rig.location.x
    rig.keyframe_insert("location", frame=1)          # the armature object keyed moving (the modifier's armature):
    rig.location.x += 2.0                             # the character object stays
    rig.keyframe_insert("location", frame=8)
    out["moving_rig_still"] = still_verdict(take, obj)
    out["moving_rig_character_motion"] = evaluated_motion(obj)
    out["moving_rig_motion"] = evaluated_motion(rig)
    pc2("modifier_moving_rig")
    for f in (1, 8):
        rig.keyframe_delete("location", frame=f)
    rig.location.x = home
    obj.modifiers.remove(obj.modifiers["Armature"])
    obj.parent, obj.parent_type = rig, 'ARMATURE'     # Ctrl+P > With Empty Groups: the placement kept
    obj.matrix_parent_inverse = rig.matrix_world.inverted()
    bpy.context.view_layer.update()
    out["parent_type"] = obj.parent_type
    out["parent_still"] = still_verdict(take, obj)
    pc2("parent")
    shape_keys("parent_shape_keys")
    rig.keyframe_insert("location", frame=1)          # the armature object keyed moving: so does the character
    rig.location.x += 2.0
    rig.keyframe_insert("location", frame=8)
    rig.location.x = home
    out["parent_moving_still"] = still_verdict(take, obj)
    out["parent_moving_character_motion"] = evaluated_motion(obj)
    one_line_attempt(out, "parent_moving", obj, bpy.ops.lengths_angles.fit_markers, use_scene_range=False,
                     frame_start=1, frame_end=8)
    cage = bpy.data.objects.new("Cage", bpy.data.lattices.new("Cage"))  # a lattice parent (parent type Lattice)
    bpy.context.scene.collection.objects.link(cage)
    obj.parent, obj.parent_type = cage, 'LATTICE'
    obj.matrix_parent_inverse = cage.matrix_world.inverted()
    bpy.context.view_layer.update()
    out["lattice_parent_type"] = obj.parent_type
    shape_keys("lattice_shape_keys")
    return out


#: The noisy take's rigid misplacement relative to the character (the take empty's rotation, radians, and location,
#: decimetres): 5.3 degrees about the origin at the body's feet and 4 cm, which puts the markers 63 mm (RMS) off.
MISPLACEMENT = ((0.05, -0.03, 0.07), (0.25, -0.3, 0.1))


def bind_align():
    """Bind Markers with Align on a noisy take (``take_noisy.c3d``: 3 mm noise) whose take empty is rigidly misplaced
    (:data:`MISPLACEMENT`): the operator's Align reaches lacore's ICP, which stops early; the binding is stored.  The
    markers as read (object space), the rotation and translation ICP found and the binding are written to
    ``align.npz`` for pytest; the same bind without Align for comparison; the report says how many ICP
    iterations ran."""
    fit = ext("addon.operators_fit")
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj = bpy.data.objects["Body"]
    obj.modifiers.remove(obj.modifiers["LA Fit"])
    assert bpy.ops.lengths_angles.import_markers(filepath=os.path.join(WORK, "take_noisy.c3d"),
                                                 scale=10.0) == {"FINISHED"}
    take = bpy.data.objects["take_noisy"]
    take.rotation_euler, take.location = MISPLACEMENT
    kb = obj.shape_key_add(name="bind pose", from_mix=False)
    kb.data.foreach_set("co", INPUTS["bind_pose"].astype(np.float32).ravel())
    kb.value = 1.0
    bpy.context.scene.frame_set(1)
    original, calls = fit.bind_markers, []

    def spy(*args, **kwargs):
        found = original(*args, **kwargs)
        calls.append({"align": kwargs["align"], "cap": kwargs["iterations"], "info": found[1]})
        return found
    fit.bind_markers = spy
    try:
        select_only(obj, take)
        t = time.perf_counter()
        result = sorted(bpy.ops.lengths_angles.bind_markers(align=True))
        seconds = time.perf_counter() - t
        binding = obj[fit.BINDING_PROP].to_dict()
        again, reports = finish(fit.bind_run(bpy.context, obj, take, align=True))
        plain = finish(fit.bind_run(bpy.context, obj, take))[0]
        unaligned = obj[fit.BINDING_PROP].to_dict()
    finally:
        fit.bind_markers = original
    inv = ext("addon.mesh_access").world_to_object(obj)
    seen = ext("addon.operators_markers").read_take(take, frames=[1]).positions[0]
    info = calls[0]["info"]
    np.savez(os.path.join(ARGS.workdir, "align.npz"), markers=seen @ inv[:3, :3].T + inv[:3, 3],
             rotation=info["rotation"], translation=info["translation"], faces=np.array(binding["faces"]),
             barycentric=np.array(binding["barycentric"]).reshape(-1, 3), offsets=np.array(binding["offsets"]),
             plain_faces=np.array(unaligned["faces"]),
             plain_barycentric=np.array(unaligned["barycentric"]).reshape(-1, 3),
             plain_offsets=np.array(unaligned["offsets"]), take_matrix=np.array(take.matrix_world))
    return {"result": result, "seconds": round(seconds, 3), "align": [c["align"] for c in calls],
            "caps": [c["cap"] for c in calls], "iterations": [int(c["info"]["iterations"]) for c in calls],
            "labels": list(binding["labels"]), "n_markers": len(list(take.children)), "again": again,
            "reports": reports, "plain": plain, "take": binding["take"]}


#: The frame Bind Markers runs at again (the take's last: every marker visible; the first binding was at frame 1).
REBIND_FRAME = 8


def fit_output(obj):
    """The fit's output on ``obj``: its modifiers, the fitted frames' keys and their F-curves' data paths."""
    keys = [k.name for k in obj.data.shape_keys.key_blocks if k.name.startswith("LA fit ")]
    fcurves = ext("addon.compat").animation_channels(obj.data.shape_keys)
    paths = [fc.data_path for fc in fcurves.fcurves] if fcurves is not None else []
    return {"modifiers": [m.name for m in obj.modifiers], "fit_keys": keys,
            "fit_key_curves": sorted(p for p in paths if "LA fit " in p)}


def rebind_after_fit():
    """Bind Markers and Fit to Markers again on a character with an earlier fit, for each output: the earlier fit
    (whole_path's binding at frame 1, fitted over frames 1-8 as a point cache or as shape keys) is there, the
    character is posed like frame 8 (a shape key at 1) and bound at frame 8, the pose key removed, and frames 1-8
    fitted again in the same output.  The same on a fresh copy without the earlier fit.  Records the mesh the
    binding saw, the bindings, the fits and what is shown (``rebind.npz``), and the fit's modifiers and keys left."""
    fit = ext("addon.operators_fit")
    out, arrays = {}, {}
    for output in ('PC2', 'SHAPE_KEYS'):
        for earlier in (True, False):
            name = f"{output.lower()}_{'again' if earlier else 'fresh'}"
            bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
            obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
            scene = bpy.context.scene
            obj.modifiers.remove(obj.modifiers["LA Fit"])
            select_only(obj, take)
            if earlier:
                assert finish(fit.fit_run(bpy.context, obj, 1, 8, output=output))[0] == ["FINISHED"]
            kb = obj.shape_key_add(name="pose 8", from_mix=False)
            kb.data.foreach_set("co", INPUTS["true"][REBIND_FRAME - 1].astype(np.float32).ravel())
            kb.value = 1.0
            scene.frame_set(REBIND_FRAME)
            before_bind = {"modifiers": [m.name for m in obj.modifiers],
                           "fit_keys": [k.name for k in obj.data.shape_keys.key_blocks if k.name.startswith("LA fit ")]}
            arrays[f"{name}_seen"] = fit._mesh_vertices(obj)
            bound = sorted(bpy.ops.lengths_angles.bind_markers())
            after_bind = {"muted": [k.name for k in obj.data.shape_keys.key_blocks if k.mute],
                          "shown": [m.name for m in obj.modifiers if m.show_viewport]}
            obj.shape_key_remove(kb)
            binding = obj[fit.BINDING_PROP].to_dict()
            run = fit.fit_run(bpy.context, obj, 1, 8, output=output)
            result = finish(run)[0]
            X = run.job.result.vertices
            arrays.update({f"{name}_faces": np.array(binding["faces"]), f"{name}_offsets": np.array(binding["offsets"]),
                           f"{name}_barycentric": np.array(binding["barycentric"]).reshape(-1, 3),
                           f"{name}_fit": X})
            out[name] = {"bind": bound, "before_bind": before_bind, "after_bind": after_bind, "fit": result,
                         "frame": binding["frame"], "labels": list(binding["labels"]), **fit_output(obj),
                         "shown_minus_fit": shown_minus_fit(obj, X)}
    np.savez(os.path.join(ARGS.workdir, "rebind.npz"), **arrays)
    return out


#: The character's placement after its fit (location in decimetres, rotation in radians, scale): 5 mm, 3 degrees and
#: 2 % from where it was bound and fitted.
PLACEMENT = ((0.03, -0.04, 0.02), (0.02, -0.03, 0.035), (1.02, 1.02, 1.02))
#: The frames the cases after rebind_after_fit fit (short: the fit of one frame takes about a second).
SHORT_FRAMES = (1, 2, 3)


def rebind_after_moving():
    """Bind Markers (at frame 1, posed like it) and Fit to Markers (frames 1-3, point cache) again after the character
    was moved, turned and scaled (:data:`PLACEMENT`) following a fit (whole_path's point cache); the same on a fresh
    copy placed the same way without the fit.  Records the bindings, the fits (``moved.npz``) and what is shown."""
    fit = ext("addon.operators_fit")
    out, arrays = {}, {}
    for name, keep_fit in (("again", True), ("fresh", False)):
        obj, _, kb = posed_for_binding(PLACEMENT, keep_fit=keep_fit)
        before = [m.name for m in obj.modifiers]
        bound = sorted(bpy.ops.lengths_angles.bind_markers())
        obj.shape_key_remove(kb)
        binding = obj[fit.BINDING_PROP].to_dict()
        run = fit.fit_run(bpy.context, obj, SHORT_FRAMES[0], SHORT_FRAMES[-1])
        result = finish(run)[0]
        X = run.job.result.vertices
        arrays.update({f"{name}_faces": np.array(binding["faces"]), f"{name}_offsets": np.array(binding["offsets"]),
                       f"{name}_barycentric": np.array(binding["barycentric"]).reshape(-1, 3), f"{name}_fit": X,
                       f"{name}_matrix": np.array(obj.matrix_world)})
        out[name] = {"bind": bound, "fit": result, "modifiers_before": before, **fit_output(obj),
                     "shown_minus_fit": shown_minus_fit(obj, X, SHORT_FRAMES)}
    np.savez(os.path.join(ARGS.workdir, "moved.npz"), **arrays)
    return out


def fit_output_switch():
    """Fit to Markers (frames 1-3) as Shape Keys after a fit as a point cache, and as a point cache after one as shape
    keys, on whole_path's binding: records the output left (modifiers, keys, F-curves), the fits and the mesh shown
    at each frame after each fit (``switch.npz``); each order's first fit is the other's second on a fresh copy."""
    fit = ext("addon.operators_fit")
    out, arrays = {}, {}
    for order in (('PC2', 'SHAPE_KEYS'), ('SHAPE_KEYS', 'PC2')):
        name = "_then_".join(o.lower() for o in order)
        bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
        obj = bpy.data.objects["Body"]
        obj.modifiers.remove(obj.modifiers["LA Fit"])
        select_only(obj)
        out[name] = {}
        for step, output in zip(("first", "second"), order, strict=True):
            run = fit.fit_run(bpy.context, obj, SHORT_FRAMES[0], SHORT_FRAMES[-1], output=output)
            out[name][step] = {"fit": finish(run)[0], **fit_output(obj)}
            shown = []
            for f in SHORT_FRAMES:
                bpy.context.scene.frame_set(f)
                shown.append(evaluated(obj))
            arrays[f"{name}_{step}_fit"] = run.job.result.vertices
            arrays[f"{name}_{step}_shown"] = np.array(shown)
        bpy.context.scene.frame_set(1)
    np.savez(os.path.join(ARGS.workdir, "switch.npz"), **arrays)
    return out


def library_meshes():
    """'Body' with its model, binding and take saved in a library and linked into a shot as a library override, its
    mesh left linked or made an override too: Fit with the Shape Keys output and Model Pose to Shape Key, whose keys
    Blender would not keep, are refused in one line and change nothing; the Point Cache output (a modifier of the
    override object and a file) fits and shows the same shape after the shot is saved and opened again."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ARGS.workdir, "fit.blend"))
    obj, take = bpy.data.objects["Body"], bpy.data.objects["take"]
    obj.modifiers.remove(obj.modifiers["LA Fit"])
    library = os.path.join(ARGS.workdir, "body_library.blend")
    libraries.save_character(library, [obj, take, *take.children_recursive])
    shot = os.path.join(ARGS.workdir, "body_shot.blend")
    out = {}
    for mesh_kind in ("linked", "override"):
        reset()
        libraries.override_character(library, editable=True)
        obj = next(o for o in bpy.data.objects if o.name == "Body" and o.library is None)
        if mesh_kind == "override":
            obj.data.override_create(remap_local_usages=True)
        bpy.ops.wm.save_as_mainfile(filepath=shot)
        select_only(obj)
        got = {"mesh": [obj.data.library is not None, obj.data.override_library is not None]}
        for name, op, kw in (("shape_keys", bpy.ops.lengths_angles.fit_markers,
                              {"output": 'SHAPE_KEYS', "use_scene_range": False, "frame_start": 2, "frame_end": 4}),
                             ("pose_key", bpy.ops.lengths_angles.model_pose_to_shape_key, {"name": "pose"}),
                             ("build_model", bpy.ops.lengths_angles.build_model, {})):
            before = state(obj)
            try:
                got[name] = sorted(op(**kw))
            except RuntimeError as exc:
                got[name] = str(exc).replace("Error: ", "").strip()
            got[f"{name}_unchanged"] = state(obj) == before
        got["keys"] = [kb.name for kb in obj.data.shape_keys.key_blocks]
        bpy.ops.wm.save_as_mainfile(filepath=shot)
        bpy.ops.wm.open_mainfile(filepath=shot)
        obj = next(o for o in bpy.data.objects if o.name == "Body" and o.library is None)
        got["reopened_keys"] = [kb.name for kb in obj.data.shape_keys.key_blocks]
        select_only(obj)
        got["pc2"] = sorted(bpy.ops.lengths_angles.fit_markers(use_scene_range=False, frame_start=2, frame_end=4))
        bpy.context.scene.frame_set(3)
        shown = evaluated(obj)
        got["pc2_rms_to_true"] = float(np.sqrt(((shown - INPUTS["true"][2]) ** 2).sum(1).mean()))  # frame 3
        bpy.ops.wm.save_as_mainfile(filepath=shot)
        bpy.ops.wm.open_mainfile(filepath=shot)
        obj = next(o for o in bpy.data.objects if o.name == "Body" and o.library is None)
        bpy.context.scene.frame_set(3)
        got["pc2_reopened"] = ["LA Fit" in obj.modifiers, float(np.abs(evaluated(obj) - shown).max()),
                               float(np.ptp(shown, axis=0).max())]
        out[mesh_kind] = got
    return out


if __name__ == "__main__":
    run_cases([install_and_enable, whole_path, model_storage, shape_key_output, library_meshes, bad_input,
               runs_progress_and_cancel,
               runs_object_changed, script_defaults_and_paths, bind_units_and_occlusion, fit_settings, cleared_marker,
               moving_setups, constant_setups, parent_links, take_rate, bind_with_modifiers, armature_character,
               bind_align, rebind_after_fit, bind_with_preview_key, rebind_after_moving, fit_output_switch])
