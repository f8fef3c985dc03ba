"""Blender-side checks of the Import Motion Capture Markers operator of the INSTALLED extension
(run in a SUBPROCESS by tests/test_blender_markers.py; bpy can be imported once per process).

usage: BLENDER_USER_RESOURCES=<tmp> python check_markers.py --zip EXT.zip --workdir DIR --result OUT.json

Every imported file is compared with lacore.markers.io's own reading of the same file (tested on
its own against the files' headers in tests/test_marker_io.py).  Every case returns the numbers
it measured; pytest asserts on them.
"""

import glob
import importlib
import math
import os
import time

# harness first: it checks the environment and imports bpy
from harness import ARGS, MODULE, REPO, bpy, reset, run_cases
import numpy as np

MOCAP = os.path.join(os.environ.get("LACORE_SHARED_DATA") or os.path.join(os.path.dirname(REPO), "shared", "data"),
                     "mocap")


def ext(name):
    return importlib.import_module(f"{MODULE}.{name}")


def import_markers(path, **kwargs):
    with bpy.context.temp_override(scene=bpy.context.scene):
        return bpy.ops.lengths_angles.import_markers(filepath=path, **kwargs)


def fcurves(obj):
    return ext("addon.operators_markers")._fcurves_for(obj)


def keys(fc):
    n = len(fc.keyframe_points)
    co = np.empty(2 * n, np.float32)
    fc.keyframe_points.foreach_get("co", co)
    return co[0::2].astype(np.float64), co[1::2].astype(np.float64)


def interpolations(fc):
    return sorted({k.interpolation for k in fc.keyframe_points})


def scene_fps():
    r = bpy.context.scene.render
    return r.fps / r.fps_base


def counts():
    return len(bpy.data.objects), len(bpy.data.actions)


def check_take(path, take, frame_start=1.0, step=1.0, matrix=None, verify_depsgraph=True, file_take=None):
    """Compare the imported objects with ``take`` (a lacore MarkerTake; ``file_take`` the file's own
    take if ``take`` was resampled); returns measured figures."""
    matrix = np.eye(3) if matrix is None else matrix
    file_take = take if file_take is None else file_take
    name = os.path.splitext(os.path.basename(path))[0]
    take_obj = bpy.data.objects[name]
    meta = take_obj["lengths_angles_take"]
    assert math.isclose(meta["rate"], file_take.rate) and meta["units"] == take.units, meta.to_dict()
    assert meta["frame_count"] == file_take.n_frames and meta["first_frame"] == take.first_frame
    assert math.isclose(meta["keyed_rate"], take.rate) and meta["keyed_samples"] == take.n_frames
    assert list(meta["labels"]) == list(take.labels) and meta["source"] == take.source
    children = sorted(take_obj.children, key=lambda o: list(take.labels).index(o["lengths_angles_marker"]))
    assert [c["lengths_angles_marker"] for c in children] == list(take.labels)
    assert all(c.type == 'EMPTY' and c.parent == take_obj for c in children)
    frames = frame_start + np.arange(take.n_frames) * step
    pos = take.positions @ matrix.T
    max_err, occluded_keys, vis_mismatch, location_keys, occluded = 0.0, 0, 0, 0, 0
    for m, obj in enumerate(children):
        curves = fcurves(obj)
        seen = take.visible[:, m]
        occluded += int((~seen).sum())
        for axis in range(3):
            fc = curves.find("location", index=axis)
            if not seen.any():
                assert fc is None or len(fc.keyframe_points) == 0
                continue
            kf, kv = keys(fc)
            assert interpolations(fc) == ["LINEAR"]
            location_keys += len(kf)
            # keys exactly on the visible samples, none on occluded ones
            assert len(kf) == int(seen.sum()), (obj.name, len(kf), int(seen.sum()))
            assert np.allclose(kf, frames[seen], atol=1e-4), obj.name
            occluded_keys += int(np.isin(np.round(kf, 4), np.round(frames[~seen], 4)).sum())
            max_err = max(max_err, float(np.abs(kv - pos[seen, m, axis]).max()))
        ui = obj.id_properties_ui("visible").as_dict()
        assert (ui["min"], ui["max"]) == (0.0, 1.0), ui
        vis = curves.find('["visible"]')
        assert interpolations(vis) == ["CONSTANT"]
        evaluated = np.array([vis.evaluate(f) for f in frames])
        vis_mismatch += int((evaluated != seen.astype(float)).sum())
    result = {"markers": len(children), "frames": take.n_frames, "location_keys": location_keys,
              "occluded_samples": occluded, "keys_on_occluded_samples": occluded_keys,
              "visible_mismatches": vis_mismatch, "max_abs_key_error": max_err,
              "scene_fps": scene_fps(), "frame_range": [bpy.context.scene.frame_start, bpy.context.scene.frame_end]}
    if verify_depsgraph:  # world positions as Blender evaluates them, at a few frames where a marker is seen
        dg_err = 0.0
        for t in (0, take.n_frames // 2, take.n_frames - 1):
            if step != 1.0:
                break
            bpy.context.scene.frame_set(int(frames[t]))
            for m, obj in enumerate(children):
                if take.visible[t, m]:
                    world = np.array(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).matrix_world.translation)
                    dg_err = max(dg_err, float(np.abs(world - pos[t, m]).max()))
        result["max_abs_world_error"] = dg_err
    return result


def read_back(path, take, space='LOCAL'):
    """read_take (bulk F-curve reading) against the take that was imported."""
    take_obj = bpy.data.objects[os.path.splitext(os.path.basename(path))[0]]
    t0 = time.perf_counter()
    back = ext("addon.operators_markers").read_take(take_obj, space=space)
    seconds = time.perf_counter() - t0
    same_mask = bool(np.array_equal(back.visible, take.visible))
    v = take.visible
    err = float(np.abs(back.positions[v] - take.positions[v]).max()) if v.any() else 0.0
    return {"read_back_same_mask": same_mask, "read_back_max_abs": err, "read_back_seconds": round(seconds, 4),
            "read_back_labels_equal": back.labels == take.labels, "read_back_rate": back.rate}


def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    assert MODULE in bpy.context.preferences.addons
    assert bpy.ops.lengths_angles.import_markers.idname() == "LENGTHS_ANGLES_OT_import_markers"
    props = bpy.ops.lengths_angles.import_markers.get_rna_type().properties
    names = sorted(k for k in props.keys() if k in {"filepath", "scale", "frame_start", "rate_mode", "axis_forward",
                                                     "axis_up", "set_frame_range", "marker_size", "filter_glob"})
    menu = ext("addon.operators_markers").menu_func_import
    in_menu = menu in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
    assert in_menu
    handler = getattr(bpy.types, "LENGTHS_ANGLES_FH_markers", None)
    drop = None if handler is None else [handler.bl_import_operator, handler.bl_file_extensions]
    modes = [i.identifier for i in props["rate_mode"].enum_items]
    return {"properties": names, "in_file_import_menu": in_menu, "file_handler": drop, "rate_modes": modes,
            "defaults": {"axis_forward": props["axis_forward"].default, "axis_up": props["axis_up"].default,
                         "rate_mode": props["rate_mode"].default, "scale": props["scale"].default,
                         "frame_start": props["frame_start"].default}}


def real_files():
    """Every C3D file of shared/data/mocap, default options."""
    read_markers = ext("lacore.markers.io").read_markers
    out = {}
    files = sorted(glob.glob(os.path.join(MOCAP, "*.c3d")))
    assert files, MOCAP
    for path in files:
        reset()
        take = read_markers(path)
        t0 = time.perf_counter()
        assert import_markers(path) == {"FINISHED"}
        seconds = time.perf_counter() - t0
        res = check_take(path, take)
        res.update(read_back(path, take))
        res["seconds"] = round(seconds, 4)
        res["expected_occluded"] = int((~take.visible).sum())
        res["expected_markers"] = take.n_markers
        res["rate"] = take.rate
        out[os.path.basename(path)] = res
    return {"files": out}


def import_from_edit_mode():
    """A mesh in Edit Mode (active) when a take is imported: the take becomes the active object in Object Mode."""
    reset()
    mesh = bpy.data.meshes.new("Cube")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    cube = bpy.data.objects.new("Cube", mesh)
    bpy.context.scene.collection.objects.link(cube)
    bpy.context.view_layer.objects.active = cube
    cube.select_set(True)
    bpy.ops.object.mode_set(mode='EDIT')
    result = sorted(import_markers(os.path.join(MOCAP, "Walk1.c3d")))
    return {"result": result, "active": bpy.context.view_layer.objects.active.name, "context_mode": bpy.context.mode,
            "modes": sorted({o.mode for o in bpy.context.view_layer.objects}), "cube_selected": cube.select_get()}


def not_markers(name):
    """``[[label, reason]]`` of the points the take empty ``name`` records as no skin markers."""
    return [[str(v) for v in pair] for pair in bpy.data.objects[name]["lengths_angles_take"]["not_markers"]]


def options():
    """Scale, axis conversion, start frame, mapping by time to the scene's rate."""
    read_markers = ext("lacore.markers.io").read_markers
    path = os.path.join(MOCAP, "Walk1.c3d")
    take = read_markers(path)
    reset()
    bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = 24, 1.0
    # file Y-up, -Z forward (as many optical systems): Blender (x, y, z) = (x, -z, y) of the file
    expected = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float) * 2.5
    assert import_markers(path, scale=2.5, axis_forward='-Z', axis_up='Y', frame_start=10) == {"FINISHED"}
    converted = check_take(path, take, frame_start=10, matrix=expected)
    # a centimetre scene (Unit Scale 0.01): metres become 100 units unless a Scale is given
    reset()
    bpy.context.scene.unit_settings.scale_length = 0.01
    assert import_markers(path, frame_start=10) == {"FINISHED"}
    centimetres = check_take(path, take, frame_start=10, matrix=100.0 * np.eye(3))
    bpy.context.scene.unit_settings.scale_length = 1.0
    reset()
    bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = 24, 1.0
    assert import_markers(path, rate_mode='RETIME', frame_start=1, set_frame_range=True) == {"FINISHED"}
    retimed = check_take(path, take, frame_start=1, step=24 / 60, verify_depsgraph=False)
    retimed.update(read_back(path, take))  # keys on fractional frames, read back at the same frames
    # the time of every key is the sample's time (frame 1 = time 0)
    retimed["fps_unchanged"] = scene_fps() == 24
    retimed["not_markers"] = not_markers("Walk1")
    reset()
    bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = 24, 1.0
    assert import_markers(path, rate_mode='RESAMPLE') == {"FINISHED"}
    resampled_take = ext("lacore.markers.takes").resample(take, 24.0)
    resampled = check_take(path, resampled_take, file_take=take)
    resampled["fps_unchanged"] = scene_fps() == 24
    resampled["not_markers"] = not_markers("Walk1")
    # TRC: the same take written as TRC (mm) imports to the same keys
    reset()
    trc = os.path.join(ARGS.workdir, "Walk1.trc")
    ext("lacore.markers.io").write_trc(trc, take)
    assert import_markers(trc) == {"FINISHED"}
    trc_take = ext("lacore.markers.io").read_markers(trc)
    trc_res = check_take(trc, trc_take)
    trc_res["labels_equal"] = trc_take.labels == take.labels
    trc_res["max_abs_vs_c3d_take"] = float(np.nanmax(np.abs(trc_take.positions - take.positions)))
    trc_res["same_visibility"] = bool(np.array_equal(trc_take.visible, take.visible))
    return {"converted": converted, "centimetres": centimetres, "retimed": retimed, "resampled": resampled,
            "trc": trc_res,
            "walk1_visible": int(take.visible.sum()), "resampled_frames": resampled_take.n_frames,
            "resampled_visible": int(resampled_take.visible.sum())}


def errors_create_nothing():
    """Truncated / non-C3D / missing files: RuntimeError from the ERROR report, no objects, no actions,
    scene rate unchanged; a failure in the middle of creating removes everything created."""
    src = os.path.join(MOCAP, "Eb015pr.c3d")
    with open(src, "rb") as fh:
        data = fh.read()
    cases = {"truncated_data": data[:200_000], "truncated_header": data[:300], "not_c3d": b"ply\nformat ascii\n" * 40,
             "empty": b""}
    messages = {}
    reset()
    bpy.context.scene.render.fps = 25
    before = counts()
    for name, blob in cases.items():
        path = os.path.join(ARGS.workdir, f"{name}.c3d")
        with open(path, "wb") as fh:
            fh.write(blob)
        try:
            import_markers(path)
        except RuntimeError as exc:
            messages[name] = str(exc)
        else:
            raise AssertionError(f"{name}: no error")
        assert counts() == before, (name, counts(), before)
        assert scene_fps() == 25
    try:
        import_markers(os.path.join(ARGS.workdir, "missing.c3d"))
    except RuntimeError as exc:
        messages["missing"] = str(exc)
    assert counts() == before
    # failure in the middle: the 40th F-curve write raises
    mod = ext("addon.operators_markers")
    original = mod._write_curve
    calls = {"n": 0}

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 40:
            raise ext("lacore.errors").InputError("simulated failure while writing keys")
        return original(*args, **kwargs)

    mod._write_curve = failing
    try:
        import_markers(os.path.join(MOCAP, "Walk1.c3d"))
    except RuntimeError as exc:
        messages["mid_way"] = str(exc)
    finally:
        mod._write_curve = original
    assert calls["n"] == 40
    after_mid_way = counts()
    assert after_mid_way == before, (after_mid_way, before)
    assert scene_fps() == 25
    return {"messages": messages, "objects_and_actions": list(before)}


def read_take_cases():
    """read_take: world space through a moved take empty, edited curves, missing empties, wrong object."""
    mod = ext("addon.operators_markers")
    mio = ext("lacore.markers.io")
    path = os.path.join(MOCAP, "Walk1.c3d")
    take = mio.read_markers(path)
    reset()
    assert import_markers(path, scale=2.0) == {"FINISHED"}
    take_obj = bpy.data.objects["Walk1"]
    take_obj.location = (1.0, -2.0, 0.5)
    take_obj.rotation_euler = (0.3, -0.2, 1.1)
    take_obj.scale = (1.5, 1.5, 1.5)
    bpy.context.view_layer.update()
    mw = np.array(take_obj.matrix_world)
    expected = (2.0 * take.positions) @ mw[:3, :3].T + mw[:3, 3]
    world = mod.read_take(take_obj)
    v = take.visible
    world_err = float(np.abs(world.positions[v] - expected[v]).max())
    assert np.array_equal(world.visible, v)
    # a few frames through the depsgraph agree with read_take
    dg_err = 0.0
    markers = dict(mod.marker_objects(take_obj))
    for t in (3, 77, 150):
        bpy.context.scene.frame_set(1 + t)
        dg = bpy.context.evaluated_depsgraph_get()
        for m, label in enumerate(world.labels):
            if v[t, m]:
                pos = np.array(markers[label].evaluated_get(dg).matrix_world.translation)
                dg_err = max(dg_err, float(np.abs(pos - world.positions[t, m]).max()))
    # an edited curve (BEZIER keys) is evaluated key by key: values at the keys are unchanged
    label = world.labels[0]
    fc = fcurves(markers[label]).find("location", index=0)
    for k in fc.keyframe_points:
        k.interpolation = 'BEZIER'
    fc.update()
    edited = mod.read_take(take_obj, space='LOCAL')
    edited_err = float(np.abs(edited.positions[v] - 2.0 * take.positions[v]).max())
    # sampled between keys (half frames): linear between two visible samples
    half = mod.read_take(take_obj, frames=np.arange(1, 151) + 0.5, space='LOCAL')
    both = v[:-1] & v[1:]
    mid = 0.5 * 2.0 * (take.positions[:-1] + take.positions[1:])
    sel = both.copy()
    sel[:, 0] = False  # the BEZIER-edited marker
    half_err = float(np.abs(half.positions[sel] - mid[sel]).max())
    half_rate = half.rate
    messages = {}
    for name, fn in {"not_a_take": lambda: mod.read_take(markers[world.labels[1]]),
                     "deleted_marker": lambda: (bpy.data.objects.remove(markers[world.labels[2]]),
                                                mod.read_take(take_obj))}.items():
        try:
            fn()
        except ext("lacore.errors").InputError as exc:
            messages[name] = str(exc)
    return {"world_max_abs": world_err, "depsgraph_max_abs": dg_err, "edited_max_abs": edited_err,
            "half_frame_max_abs": half_err, "half_frame_rate": half_rate, "messages": messages,
            "deleted_label": world.labels[2]}


def take_time():
    """The take's own scene frames per second (take_frame_rate) under each rate mode, and after the scene's frame
    rate is changed: the keys' span over it is the take's duration in seconds; read_take's rate for given frames."""
    mod = ext("addon.operators_markers")
    path = os.path.join(MOCAP, "Walk1.c3d")
    out = {}
    for mode in ("SCENE", "RETIME", "RESAMPLE"):
        reset()
        bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = 24, 1.0
        assert import_markers(path, rate_mode=mode) == {"FINISHED"}
        take_obj = bpy.data.objects["Walk1"]
        rate = mod.take_frame_rate(take_obj)
        at_import = scene_fps()
        bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = 30, 1.001   # changed after import
        first, last = math.inf, -math.inf
        for obj in take_obj.children:
            for axis in range(3):
                kf, _ = keys(fcurves(obj).find("location", index=axis))
                if len(kf):
                    first, last = min(first, kf.min()), max(last, kf.max())
        out[mode] = {"rate": rate, "rate_after_fps_change": mod.take_frame_rate(take_obj), "scene_fps_at_import":
                     at_import, "seconds": float((last - first) / mod.take_frame_rate(take_obj)),
                     "read_rate": mod.read_take(take_obj, frames=[1, 2, 3]).rate}
    return out


def cleared_markers():
    """Marker empties whose animation was cleared (no action; location channels deleted, all or one) read as never
    visible in a take of several samples, named by unkeyed_markers; a marker never seen in the file is not one of
    them; in a one-sample take a cleared marker is read where its empty is."""
    mod = ext("addon.operators_markers")
    mio = ext("lacore.markers.io")
    path = os.path.join(MOCAP, "Walk1.c3d")
    take = mio.read_markers(path)
    reset()
    assert import_markers(path) == {"FINISHED"}
    take_obj = bpy.data.objects["Walk1"]
    markers = dict(mod.marker_objects(take_obj))
    seen = [lb for m, lb in enumerate(take.labels) if take.visible[:, m].all()]
    never = [lb for m, lb in enumerate(take.labels) if not take.visible[:, m].any()]
    cleared = seen[:3]
    markers[cleared[0]].animation_data_clear()                      # Clear Keyframes: no action left
    curves = fcurves(markers[cleared[1]])                           # the location channels deleted, visible kept
    for axis in range(3):
        curves.remove(curves.find("location", index=axis))
    curves = fcurves(markers[cleared[2]])                           # one location channel deleted
    curves.remove(curves.find("location", index=1))
    curves = fcurves(markers[never[0]])                             # never seen, its visible channel deleted
    curves.remove(curves.find('["visible"]'))
    back = mod.read_take(take_obj)
    idx = [take.labels.index(lb) for lb in cleared]
    others = [m for m in range(take.n_markers) if m not in idx]
    out = {"cleared": cleared, "never_seen": never[:3], "n_never_seen": len(never),
           "cleared_finite": int(np.isfinite(back.positions[:, idx]).sum()),
           "never_seen_finite": int(np.isfinite(back.positions[:, take.labels.index(never[0])]).sum()),
           "others_same_mask": bool(np.array_equal(back.visible[:, others], take.visible[:, others])),
           "others_max_abs": float(np.abs(back.positions[:, others][take.visible[:, others]]
                                          - take.positions[:, others][take.visible[:, others]]).max())}
    out["unkeyed"] = mod.unkeyed_markers(take_obj)
    out["unkeyed_of"] = mod.unkeyed_markers(take_obj, labels=[cleared[1], seen[5]])
    out["notes"] = [mod.unkeyed_note(cleared[:1]), mod.unkeyed_note(cleared), mod.unkeyed_note([])]
    # one sample: the empty's location is the marker (nothing to corrupt over time)
    one = mio.MarkerTake(labels=["A", "B", "C"], positions=take.positions[:1, idx], rate=60.0, source="one")
    one_obj, one_markers = mod.import_take(bpy.context, one, "one")
    one_markers[0].animation_data_clear()
    one_back = mod.read_take(one_obj, space='LOCAL')
    out["one_sample_max_abs"] = float(np.abs(one_back.positions[0] - one.positions[0]).max())
    out["one_sample_unkeyed"] = mod.unkeyed_markers(one_obj)
    return out


def several_files():
    """Several files at once (file browser multi-select, or a drop): all or nothing."""
    mod = ext("addon.operators_markers")
    out = {}

    def run(names, **kwargs):
        return bpy.ops.lengths_angles.import_markers(directory=MOCAP, files=[{"name": n} for n in names], **kwargs)

    reset()
    assert run(["Eb015pr.c3d", "Eb015vi.c3d"]) == {"FINISHED"}
    takes = sorted(o.name for o in bpy.data.objects if "lengths_angles_take" in o)
    out["two_takes"] = {"takes": takes, "children": [len(bpy.data.objects[t].children) for t in takes],
                        "frame_range": [bpy.context.scene.frame_start, bpy.context.scene.frame_end],
                        "selected": sorted(o.name for o in bpy.context.selected_objects)}
    # different rates and one scene rate: refused, nothing created
    reset()
    before = counts()
    try:
        run(["Walk1.c3d", "Eb015pr.c3d"])
    except RuntimeError as exc:
        out["different_rates_message"] = str(exc)
    out["different_rates_unchanged"] = counts() == before
    # mapped by time onto 24 fps: both, frame range covering both
    bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = 24, 1.0
    assert run(["Walk1.c3d", "Eb015pr.c3d"], rate_mode='RETIME') == {"FINISHED"}
    out["retime_frame_range"] = [bpy.context.scene.frame_start, bpy.context.scene.frame_end]
    out["retime_takes"] = sorted(o.name for o in bpy.data.objects if "lengths_angles_take" in o)
    # a bad second file: nothing created
    reset()
    before = counts()
    bad = os.path.join(ARGS.workdir, "bad_second.c3d")
    with open(bad, "wb") as fh:
        fh.write(b"not a c3d file at all" * 30)
    try:
        bpy.ops.lengths_angles.import_markers(directory=ARGS.workdir, files=[{"name": "bad_second.c3d"}])
    except RuntimeError as exc:
        out["bad_file_message"] = str(exc)
    import shutil

    shutil.copy(os.path.join(MOCAP, "Static_Pose.c3d"), os.path.join(ARGS.workdir, "Static_Pose.c3d"))
    try:
        bpy.ops.lengths_angles.import_markers(directory=ARGS.workdir,
                                              files=[{"name": "Static_Pose.c3d"}, {"name": "bad_second.c3d"}])
    except RuntimeError as exc:
        out["good_then_bad_message"] = str(exc)
    out["bad_file_unchanged"] = counts() == before
    # a failure while creating the second take removes the first one too
    original, calls = mod._write_curve, {"n": 0}

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 26 * 4 + 10:  # inside the second take (26 markers x 4 curves each)
            raise ext("lacore.errors").InputError("simulated failure in the second take")
        return original(*args, **kwargs)

    mod._write_curve = failing
    try:
        run(["Eb015pr.c3d", "Eb015si.c3d"])
    except RuntimeError as exc:
        out["mid_way_message"] = str(exc)
    finally:
        mod._write_curve = original
    out["mid_way_unchanged"] = counts() == before
    out["mid_way_calls"] = calls["n"]
    return out


def save_and_reload():
    path = os.path.join(MOCAP, "Static_Pose.c3d")
    reset()
    assert import_markers(path) == {"FINISHED"}
    blend = os.path.join(ARGS.workdir, "markers.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.open_mainfile(filepath=blend)
    take = ext("lacore.markers.io").read_markers(path)
    res = check_take(path, take, verify_depsgraph=False)
    return {"markers": res["markers"], "max_abs_key_error": res["max_abs_key_error"]}


def speed():
    """A generated 5,000-frame, 50-marker take (5 % occluded in gaps), written as C3D: import time."""
    mio = ext("lacore.markers.io")
    rng = np.random.default_rng(7)
    T, M = 5000, 50
    t = np.arange(T)[:, None, None] / 100.0
    pos = rng.uniform(-1, 1, (1, M, 3)) + 0.2 * np.sin(2 * np.pi * rng.uniform(0.2, 2, (1, M, 3)) * t)
    for m in range(M):  # occlusion gaps of 5..40 frames
        for start in rng.integers(0, T - 40, 6):
            pos[start:start + rng.integers(5, 40), m] = np.nan
    take = mio.MarkerTake(labels=[f"M{m:02d}" for m in range(M)], positions=pos, rate=100.0, source="generated")
    path = os.path.join(ARGS.workdir, "big_take.c3d")
    mio.write_c3d(path, take)
    back = mio.read_markers(path)
    times, read_times = [], []
    for _ in range(3):
        reset()
        t0 = time.perf_counter()
        mio.read_markers(path)
        read_times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        assert import_markers(path) == {"FINISHED"}
        times.append(time.perf_counter() - t0)
    res = check_take(path, back, verify_depsgraph=False)
    res.update(read_back(path, back))
    return {"frames": T, "markers": M, "import_seconds": [round(x, 3) for x in times],
            "best_import_seconds": round(min(times), 3), "read_seconds": round(min(read_times), 4),
            "occluded_fraction": round(float((~back.visible).mean()), 4), "check": res}


if __name__ == "__main__":
    run_cases([install_and_enable, real_files, options, read_take_cases, take_time, cleared_markers,
               errors_create_nothing, several_files, save_and_reload, import_from_edit_mode, speed])
