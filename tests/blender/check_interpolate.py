"""Blender-side checks of the Interpolate and Bake Keyframes operators of the INSTALLED extension
(run in a SUBPROCESS by tests/test_blender_interpolate.py; bpy can be imported once per process).

usage: BLENDER_USER_RESOURCES=<tmp> python check_interpolate.py --zip EXT.zip --workdir DIR --result OUT.json

Every case returns the numbers it measured; pytest asserts on them (and every
case also raises on a failed check: non-zero exit code, traceback on stderr).
"""

import json
import math
import os

# harness first: it checks the environment and imports bpy
from harness import ARGS, MODULE, REPO, bpy, draw_panel, plain, reset, run_cases
import numpy as np
import blend_sample_cases as cases
import blender_samples as samples
import libraries

BAR_SEGMENTS = (64, 4, 4)  # 1058 vertices


def ops_context(obj):
    return bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj] if obj else [])


def interpolate(obj, **kwargs):
    with ops_context(obj):
        return bpy.ops.lengths_angles.interpolate(**kwargs)


def bake(obj, **kwargs):
    with ops_context(obj):
        return bpy.ops.lengths_angles.bake_keyframes(**kwargs)


def key_names(obj):
    return [kb.name for kb in obj.data.shape_keys.key_blocks] if obj.data.shape_keys else []


def coords(obj, name):
    return cases.key_coords(obj, name)


def channelbag(obj):
    """The F-curve owner of the object's shape keys, via the installed add-on's version shim (addon/compat.py)."""
    import importlib

    key = obj.data.shape_keys
    return None if key is None else importlib.import_module(MODULE + ".addon.compat").animation_channels(key)


def value_path(name):
    return f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'


def curve_values(obj, names, frames):
    """``{name: [value at frame]}`` evaluated from the F-curves of the Key datablock (0 without a curve)."""
    cb = channelbag(obj)
    out = {}
    for n in names:
        fc = cb.fcurves.find(value_path(n)) if cb is not None else None
        out[n] = [float(fc.evaluate(f)) if fc is not None else 0.0 for f in frames]
    return out


def snapshot(obj):
    """Everything the operators could change: ID properties, key list, coordinates, key settings, F-curves."""
    mesh = obj.data
    keys = []
    if mesh.shape_keys is not None:
        for kb in mesh.shape_keys.key_blocks:
            co = np.empty(3 * len(kb.points), np.float32)
            kb.points.foreach_get("co", co)
            keys.append((kb.name, kb.value, kb.relative_key.name, co.tolist()))
    cb = channelbag(obj)
    curves = [] if cb is None else [(fc.data_path, [tuple(k.co) for k in fc.keyframe_points],
                                     [k.interpolation for k in fc.keyframe_points]) for fc in cb.fcurves]
    return json.dumps({"mesh_props": {k: plain(mesh[k]) for k in mesh.keys()},
                       "object_props": {k: plain(obj[k]) for k in obj.keys()},
                       "keys": keys, "curves": curves, "mode": obj.mode,
                       "n": [len(mesh.vertices), len(mesh.edges), len(mesh.polygons)],
                       "actions": sorted(a.name for a in bpy.data.actions)}, sort_keys=True)


def expect_error(run, obj, *fragments):
    """Run ``run(obj)``: it must raise RuntimeError naming ``fragments`` and change nothing."""
    before = snapshot(obj) if obj is not None and obj.type == 'MESH' else None
    try:
        run(obj)
    except (RuntimeError, TypeError) as exc:  # TypeError: a key name the key pickers (enums) do not offer
        msg = str(exc)
        for frag in fragments:
            assert frag.lower() in msg.lower(), f"expected {frag!r} in error message {msg!r}"
        if before is not None:
            assert snapshot(obj) == before, f"the failed operator changed the object ({msg})"
        return msg.replace("Error: ", "").strip()
    raise AssertionError("the operator did not report an error")


def bar_with_keys():
    """The box bar: Basis straight, Bend180 (Simple Deform BEND), SimpleDeform90 (reference)."""
    return cases.bent_bar("Bar", 180.0, segments=BAR_SEGMENTS, reference_deg=90.0)


# ----------------------------------------------------------------------------- cases
def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    assert MODULE in bpy.context.preferences.addons, list(bpy.context.preferences.addons.keys())
    ids = {bpy.ops.lengths_angles.interpolate.idname(), bpy.ops.lengths_angles.bake_keyframes.idname(),
           bpy.ops.lengths_angles.clear_bake.idname()}
    assert ids == {"LENGTHS_ANGLES_OT_interpolate", "LENGTHS_ANGLES_OT_bake_keyframes",
                   "LENGTHS_ANGLES_OT_clear_bake"}, ids
    props = bpy.ops.lengths_angles.interpolate.get_rna_type().properties
    assert {"key_from", "key_to", "factors", "count", "method"} <= set(props.keys()), props.keys()
    assert [i.identifier for i in props["method"].enum_items] == ["PREVIEW", "FAST", "GAUSS_NEWTON", "PATH", "MIXER"]
    assert props["method"].default == "FAST"
    import importlib
    ops_mod = importlib.import_module(MODULE + ".addon.operators_interpolate")
    preset = importlib.import_module(MODULE + ".lacore.reconstruction.settings").DEFAULT_PROJECTION
    # Fast is lacore's default projection (the CLI's and the library's), not a table of its own
    fast = ops_mod.METHOD_OPTIONS["FAST"]
    assert (fast.method, fast.options, fast.hybrid) == (preset.method, preset.options, preset.hybrid)
    assert props["interactive"].is_hidden and not props["interactive"].default  # scripts run synchronously
    bake_props = bpy.ops.lengths_angles.bake_keyframes.get_rna_type().properties
    assert {"keys", "frames", "smooth", "method"} <= set(bake_props.keys()), bake_props.keys()
    assert bpy.ops.lengths_angles.interpolate.bl_options == {'REGISTER', 'UNDO'}
    return {"operators": sorted(ids)}


def interpolate_bar():
    """Factors, end points, extrapolation, naming, key settings, quality vs Blender's 90-degree bend."""
    reset()
    obj = bar_with_keys()
    V = len(obj.data.vertices)
    A, B, R90 = coords(obj, "Basis"), coords(obj, "Bend180"), coords(obj, "SimpleDeform90")
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="0 0.25, 0.5 1,1.5") == {"FINISHED"}
    expected = [f"LA Basis>Bend180 {t}" for t in ("0.000", "0.250", "0.500", "1.000", "1.500")]
    assert key_names(obj) == ["Basis", "Bend180", "SimpleDeform90", *expected], key_names(obj)
    blocks = obj.data.shape_keys.key_blocks
    for n in expected:
        assert len(blocks[n].points) == V
        assert blocks[n].relative_key.name == "Basis" and blocks[n].value == 0.0
    X0, X1, X5, Xe = (coords(obj, n) for n in (expected[0], expected[3], expected[2], expected[4]))
    diag = float(np.linalg.norm(A.max(0) - A.min(0)))
    end_raw = max(np.abs(X0 - A).max(), np.abs(X1 - B).max())  # placed on the keys themselves
    end_rigid = max(np.abs(cases.rigid_align(X0, A) - A).max(), np.abs(cases.rigid_align(X1, B) - B).max())
    assert end_raw < 1e-5 and end_rigid < 1e-5, (end_raw, end_rigid)
    assert np.all(np.isfinite(Xe))
    edges = cases.mesh_edges(obj)
    la = cases.blend_metrics(X5, R90, A, edges)
    lin = cases.blend_metrics(0.5 * A + 0.5 * B, R90, A, edges)
    ref = cases.blend_metrics(R90, R90, A, edges)
    assert la["rms_error_per_diagonal"] < 0.01, la
    # extrapolation to 1.5: lengths continue linearly (lengths of the 270-degree Simple Deform bend)
    R270 = cases.simple_deform_coords(obj, "BEND", math.radians(270.0))
    extra = cases.blend_metrics(Xe, R270, A, edges)
    # placement: the 0.5 key sits on the linear blend (rigid fit), not around one fixed triangle
    placement = float(np.sqrt(np.mean(np.sum((X5 - (0.5 * A + 0.5 * B)) ** 2, 1))) / diag)
    centroid_shift = float(np.linalg.norm(X5.mean(0) - (0.5 * A + 0.5 * B).mean(0)))

    # Count (factors empty): evenly spaced strictly inside (0, 1)
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="", count=3) == {"FINISHED"}
    names = key_names(obj)
    assert names.count("LA Basis>Bend180 0.250") == 1 and "LA Basis>Bend180 0.750" in names
    assert len(names) == 3 + 5 + 1, names  # 0.250 and 0.500 replaced, 0.750 new

    # Gauss-Newton method on the same pair
    assert interpolate(obj, key_from="Bend180", key_to="Basis", factors="0.5", method='GAUSS_NEWTON') == {"FINISHED"}
    gn = cases.blend_metrics(coords(obj, "LA Bend180>Basis 0.500"), R90, A, edges)
    assert gn["rms_error_per_diagonal"] < 0.01, gn
    # Preview method (least-squares relaxation only): replaces the 0.5 key in place
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="0.5", method='PREVIEW') == {"FINISHED"}
    preview = cases.blend_metrics(coords(obj, "LA Basis>Bend180 0.500"), R90, A, edges)
    assert preview["rms_error_per_diagonal"] < 0.01, preview
    return {"preview": preview, "vertices": V, "keys": key_names(obj), "end_point_max_abs_error": float(end_raw),
            "end_point_rigid_max_abs_error": float(end_rigid), "lengths_angles": la, "linear": lin,
            "simple_deform_90": ref, "gauss_newton": gn, "extrapolated_1_5_vs_simple_deform_270": extra,
            "placement_rms_vs_linear_blend_per_diagonal": placement, "centroid_shift": centroid_shift,
            "diagonal": diag}


def path_method():
    """Method Path: in-betweens within the tolerance of Gauss-Newton, the default from PATH_MIN_VERTICES vertices for
    piecewise-linear motions, a bake through three keys, and no Path with Spline."""
    import importlib

    ops_mod = importlib.import_module(MODULE + ".addon.operators_interpolate")
    jobs_mod = importlib.import_module(MODULE + ".addon.jobs")
    reset()
    obj = bar_with_keys()
    A = coords(obj, "Basis")
    diag = float(np.linalg.norm(A.max(0) - A.min(0)))
    factors = "0.2 0.4 0.6 0.8"
    names = [f"LA Basis>Bend180 {t}" for t in ("0.200", "0.400", "0.600", "0.800")]
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors=factors, method='GAUSS_NEWTON') == {"FINISHED"}
    gn = np.array([coords(obj, n) for n in names])
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors=factors, method='PATH') == {"FINISHED"}
    path = np.array([coords(obj, n) for n in names])
    rms = np.sqrt(((path - gn) ** 2).sum(axis=2).mean(axis=1)) / diag
    run = ops_mod.inbetween_run(obj, "Basis", "Bend180", [0.3, 0.7], 'PATH')
    jobs_mod.run_job(run.job)
    session = importlib.import_module(MODULE + ".addon.session")
    session.clear_results()
    in_worker = ops_mod.inbetween_run(obj, "Basis", "Bend180", [0.3, 0.7], 'PATH').job
    in_worker.all_in_workers = True                   # as a modal run does: the frames in a worker process
    jobs_mod.run_job(in_worker)
    worker_difference = float(np.abs(np.array(in_worker.results) - np.array(run.job.results)).max() / diag)
    small_default = ops_mod.default_method(obj, ["Basis", "Bend180"])
    saved = ops_mod.PATH_MIN_VERTICES
    try:
        ops_mod.PATH_MIN_VERTICES = len(A)
        big_default = ops_mod.default_method(obj, ["Basis", "Bend180"])
        big_spline_default = ops_mod.default_method(obj, ["Basis", "Bend180"], smooth=True)
    finally:
        ops_mod.PATH_MIN_VERTICES = saved
    # a bake through three keys (piecewise linear), and Path with Spline is refused, changing nothing
    assert bake(obj, keys="Basis, Bend180, SimpleDeform90", frames="1, 5, 9", method='PATH') == {"FINISHED"}
    bake_keys = [n for n in key_names(obj) if n not in ("Basis", "Bend180", "SimpleDeform90") and n not in names]
    spline = expect_error(lambda o: bake(o, keys="Basis, Bend180, SimpleDeform90", frames="1, 5, 9", smooth=True,
                                         method='PATH'), obj, "Spline")
    return {"rms_to_gauss_newton_per_diagonal": [float(r) for r in rms], "job_indicator": run.job.indicator.tolist(),
            "job_summary": run.job.summary, "job_failures": list(run.job.failures), "small_default": small_default,
            "big_default": big_default, "big_spline_default": big_spline_default, "bake_keys": len(bake_keys),
            "spline_message": spline, "worker_processes": in_worker.processes,
            "worker_difference_per_diagonal": worker_difference}


def redo_replaces():
    """Re-running with the same names overwrites those keys in place (no duplicates, order kept)."""
    reset()
    obj = bar_with_keys()
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="0.5") == {"FINISHED"}
    name = "LA Basis>Bend180 0.500"
    good = coords(obj, name)
    obj.data.shape_keys.key_blocks[name].points.foreach_set("co", np.zeros(3 * len(good), np.float32))
    obj.data.shape_keys.key_blocks[name].value = 0.3  # the user dialled it in: kept
    order = key_names(obj)
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="0.5") == {"FINISHED"}
    assert key_names(obj) == order, key_names(obj)
    again = coords(obj, name)
    diff = float(np.abs(again - good).max())
    assert diff < 1e-5, diff
    assert obj.data.shape_keys.key_blocks[name].value == np.float32(0.3)
    # the operator's redo (REGISTER): last properties are remembered by the window manager
    return {"keys": key_names(obj), "max_abs_difference_of_rerun": diff}


def quads_ngons_and_edit_mode():
    """A quad/n-gon mesh (the cube with a key) in Edit Mode: keys are written and survive leaving Edit Mode."""
    reset()
    obj = samples.make_cube("Cube")  # quads; keys Basis, Scaled, Rigid
    # one n-gon: an extra pentagon-shaped prism would change topology; use the bar grid's quads plus a hexagon
    hexagon = np.array([[math.cos(a), math.sin(a), 0.0] for a in np.linspace(0, 2 * math.pi, 7)[:-1]])
    top = hexagon + [0, 0, 1.0]
    verts = np.concatenate([hexagon, top])
    polys = [list(range(6))[::-1], list(range(6, 12))] + [[i, (i + 1) % 6, 6 + (i + 1) % 6, 6 + i] for i in range(6)]
    prism = samples.make_object("Prism", verts, polys)
    samples.add_shape_key(prism, "Basis")
    samples.add_shape_key(prism, "Tall", verts * [1.0, 1.0, 3.0])
    assert interpolate(prism, key_from="Basis", key_to="Tall", factors="0.5") == {"FINISHED"}
    P = coords(prism, "LA Basis>Tall 0.500")
    height = float(P[6:, 2].mean() - P[:6, 2].mean())
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='EDIT')
    assert interpolate(obj, key_from="Basis", key_to="Scaled", factors="0.5") == {"FINISHED"}
    assert obj.mode == 'EDIT'
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='OBJECT')
    X = coords(obj, "LA Basis>Scaled 0.500")
    edge = float(np.linalg.norm(X[0] - X[1]))  # cube edge 2 -> 3: the in-between has 2.5
    assert abs(edge - 2.5) < 1e-4, edge
    return {"prism_height_at_0.5": height, "cube_edge_at_0.5": edge}


def errors_change_nothing():
    messages = {}
    reset()
    messages["no_active_object"] = expect_error(lambda o: interpolate(o), None,
                                                "no active object")
    obj = bar_with_keys()
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="0.5") == {"FINISHED"}  # state to keep
    run = {
        "missing_key": (lambda o: interpolate(o, key_from="Basis", key_to="Nope"), ("Nope",)),
        "same_key": (lambda o: interpolate(o, key_from="Bend180", key_to="Bend180"), ("same",)),
        "unparsable_factors": (lambda o: interpolate(o, key_from="Basis", key_to="Bend180", factors="0.5 abc"),
                               ("abc",)),
        "infinite_factor": (lambda o: interpolate(o, key_from="Basis", key_to="Bend180", factors="inf"),
                            ("finite",)),
        "bake_count_mismatch": (lambda o: bake(o, keys="Basis, Bend180", frames="1 5 9"), ("2 keys", "3 frames")),
        "bake_not_increasing": (lambda o: bake(o, keys="Basis, Bend180, Basis", frames="1 9 9"), ("increase",)),
        "bake_unknown_key": (lambda o: bake(o, keys="Basis, Bent", frames="1 9"), ("Bent",)),
        "bake_bad_frame": (lambda o: bake(o, keys="Basis, Bend180", frames="1 2.5"), ("2.5",)),
        "bake_one_key": (lambda o: bake(o, keys="Basis", frames="1"), ("at least two",)),
    }
    for label, (fn, frags) in run.items():
        messages[label] = expect_error(fn, obj, *frags)
    # a keyframed key that already has the user's own animation
    obj.data.shape_keys.key_blocks["Bend180"].value = 0.0
    obj.data.shape_keys.keyframe_insert(value_path("Bend180"), frame=3)
    messages["bake_foreign_animation"] = expect_error(lambda o: bake(o, keys="Basis, Bend180", frames="1 9"), obj,
                                                      "already has animation")
    messages["bake_no_active_object"] = expect_error(lambda o: bake(o, keys="Basis, Bend180", frames="1 9"), None,
                                                     "no active object")
    # keys that show other than their stored shape, a driven key, absolute keys
    reset()
    obj = bar_with_keys()
    key = obj.data.shape_keys
    key.driver_add(value_path("SimpleDeform90")).driver.expression = "0.25"
    bpy.context.view_layer.update()                             # the driver has set the value before the attempt
    messages["bake_driven_key"] = expect_error(lambda o: bake(o, keys="Basis, SimpleDeform90", frames="1 9"), obj,
                                               "'SimpleDeform90' has a driver")
    obj.vertex_groups.new(name="Half")
    key.key_blocks["Bend180"].vertex_group = "Half"
    messages["vertex_group_key"] = expect_error(
        lambda o: interpolate(o, key_from="Basis", key_to="Bend180", factors="0.5"), obj,
        "shape key 'Bend180' is limited to the vertex group 'Half'", "New Shape from Mix")
    messages["bake_vertex_group_key"] = expect_error(lambda o: bake(o, keys="Basis, Bend180", frames="1 9"), obj,
                                                     "Bake: shape key 'Bend180' is limited to the vertex group")
    key.key_blocks["Bend180"].vertex_group = ""
    key.key_blocks["Bend180"].relative_key = key.key_blocks["SimpleDeform90"]
    messages["relative_key"] = expect_error(
        lambda o: interpolate(o, key_from="Basis", key_to="Bend180", factors="0.5"), obj,
        "'Bend180' is relative to 'SimpleDeform90', not to the basis 'Basis'")
    key.key_blocks["Bend180"].relative_key = key.reference_key
    key.use_relative = False
    messages["bake_absolute_keys"] = expect_error(lambda o: bake(o, keys="Basis, Bend180", frames="1 9"), obj,
                                                  "Bake needs Relative shape keys")

    reset()
    plain = samples.make_object("Plain", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)])
    messages["no_shape_keys"] = expect_error(lambda o: interpolate(o), plain,
                                             "no shape keys")
    empty = bpy.data.objects.new("Empty", None)
    bpy.context.scene.collection.objects.link(empty)
    messages["not_a_mesh"] = expect_error(lambda o: interpolate(o), empty, "not a mesh")

    # non-manifold: a third quad at one cube edge (bmesh keeps the shape keys consistent)
    import bmesh

    reset()
    obj = samples.make_cube("Cube")
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    v0, v1 = bm.verts[0], bm.verts[1]
    extra = [bm.verts.new((x, -3.0, z)) for x, z in ((-1.0, -1.0), (-1.0, 1.0))]
    bm.faces.new([v0, v1, extra[1], extra[0]])
    bm.to_mesh(obj.data)
    bm.free()
    obj.data.update()
    messages["non_manifold"] = expect_error(lambda o: interpolate(o, key_from="Basis", key_to="Scaled"), obj,
                                            "non-manifold")
    messages["bake_non_manifold"] = expect_error(lambda o: bake(o, keys="Basis, Scaled", frames="1 4"), obj,
                                                 "non-manifold")
    return {"messages": messages}


def _one_hot(values, frames):
    """Per frame: the names at 1 (and that all values are 0 or 1)."""
    hot = []
    for i, _f in enumerate(frames):
        vals = {n: v[i] for n, v in values.items()}
        assert all(v in (0.0, 1.0) for v in vals.values()), vals
        hot.append([n for n, v in vals.items() if v == 1.0])
    return hot


def bake_and_rebake():
    """Bake Basis@1 -> Bend180@6 -> Twist180@12, check keys, values per frame and shapes; re-bake replaces."""
    reset()
    obj = cases.bent_bar("Bar", 180.0, segments=BAR_SEGMENTS)
    cases.add_simple_deform_key(obj, "Twist180", method="TWIST", angle=math.pi, axis="X")
    samples.add_shape_key(obj, "Extra", coords(obj, "Basis") * 1.1)  # the user's unrelated key ...
    key = obj.data.shape_keys
    for f, v in ((1, 0.2), (12, 0.7)):  # ... with its own animation
        key.key_blocks["Extra"].value = v
        key.keyframe_insert(value_path("Extra"), frame=f)
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="0.5") == {"FINISHED"}
    user_before = {n: coords(obj, n).tolist() for n in ("Basis", "Bend180", "Twist180", "Extra",
                                                        "LA Basis>Bend180 0.500")}
    extra_curve = [tuple(k.co) for k in channelbag(obj).fcurves.find(value_path("Extra")).keyframe_points]

    assert bake(obj, keys="Basis, Bend180, Twist180", frames="1, 6 12") == {"FINISHED"}
    baked = [f"LA bake {f:03d}" for f in (2, 3, 4, 5, 7, 8, 9, 10, 11)]
    names = key_names(obj)
    assert [n for n in names if n.startswith("LA bake")] == baked, names
    record = obj.data["lengths_angles_bake"].to_dict()
    assert sorted(record["keys"]) == baked
    frames = list(range(-1, 15))
    managed = ["Basis", "Bend180", "Twist180", *baked]
    hot = _one_hot(curve_values(obj, managed, frames), frames)
    expect = {f: ("Basis" if f <= 1 else "Bend180" if f == 6 else "Twist180" if f >= 12 else f"LA bake {f:03d}")
              for f in frames}
    assert all(h == [expect[f]] for h, f in zip(hot, frames, strict=True)), list(zip(frames, hot, strict=True))
    # scene playback: every baked key at 1 at its frame, through the real depsgraph
    bpy.context.scene.frame_set(4)
    at4 = {kb.name: kb.value for kb in key.key_blocks if kb.name in managed}
    assert [n for n, v in at4.items() if v == 1.0] == ["LA bake 004"], at4
    # shapes: the bend segment follows Blender's own Simple Deform bend at the same angle
    A = coords(obj, "Basis")
    edges = cases.mesh_edges(obj)
    bend_quality = {}
    for f in (2, 4, 5):
        angle = 180.0 * (f - 1) / 5
        R = cases.simple_deform_coords(obj, "BEND", math.radians(angle))
        m = cases.blend_metrics(coords(obj, f"LA bake {f:03d}"), R, A, edges)
        bend_quality[f] = m["rms_error_per_diagonal"]
        assert m["rms_error_per_diagonal"] < 0.01, (f, m)
    # twist segment: lengths between those of the two keys (within 2 %)
    lb, lt = (np.linalg.norm(coords(obj, n)[edges[:, 0]] - coords(obj, n)[edges[:, 1]], axis=1)
              for n in ("Bend180", "Twist180"))
    X9 = coords(obj, "LA bake 009")
    l9 = np.linalg.norm(X9[edges[:, 0]] - X9[edges[:, 1]], axis=1)
    twist_len_err = float(np.max(np.abs(l9 - 0.5 * (lb + lt)) / (0.5 * (lb + lt))))
    assert twist_len_err < 0.02, twist_len_err

    # re-bake (smooth, other frames): the old bake is gone, the user's key, its animation and other keys stay
    assert bake(obj, keys="Basis, Bend180, Twist180", frames="1 4 8", smooth=True) == {"FINISHED"}
    names = key_names(obj)
    rebaked = [f"LA bake {f:03d}" for f in (2, 3, 5, 6, 7)]
    assert [n for n in names if n.startswith("LA bake")] == rebaked, names
    for n, co in user_before.items():
        assert n in names and coords(obj, n).tolist() == co, n
    cb = channelbag(obj)
    assert [tuple(k.co) for k in cb.fcurves.find(value_path("Extra")).keyframe_points] == extra_curve
    paths = sorted(fc.data_path for fc in cb.fcurves)
    assert paths == sorted(value_path(n) for n in ["Basis", "Bend180", "Twist180", "Extra", *rebaked]), paths
    frames2 = list(range(0, 10))
    hot2 = _one_hot(curve_values(obj, ["Basis", "Bend180", "Twist180", *rebaked], frames2), frames2)
    assert all(len(h) == 1 for h in hot2), hot2
    smooth_vs_linear = None
    # smooth differs from piecewise linear in the middle of a segment
    X6s = coords(obj, "LA bake 006")
    assert bake(obj, keys="Basis, Bend180, Twist180", frames="1 4 8", smooth=False) == {"FINISHED"}
    X6l = coords(obj, "LA bake 006")
    smooth_vs_linear = float(np.abs(X6s - X6l).max())
    assert smooth_vs_linear > 1e-3, smooth_vs_linear

    # save + reload keeps keys, animation and the bake record
    path = os.path.join(ARGS.workdir, "baked.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    saved = snapshot(obj)
    reset()
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    assert snapshot(obj) == saved
    hot3 = _one_hot(curve_values(obj, ["Basis", "Bend180", "Twist180", *rebaked], frames2), frames2)
    assert hot3 == hot2

    # clear bake: only the user's keys and animation remain
    with ops_context(obj):
        assert bpy.ops.lengths_angles.clear_bake() == {"FINISHED"}
    names = key_names(obj)
    assert not any(n.startswith("LA bake") for n in names) and "lengths_angles_bake" not in obj.data
    assert [fc.data_path for fc in channelbag(obj).fcurves] == [value_path("Extra")]
    return {"baked_keys": baked, "rebaked_keys": rebaked, "hot_per_frame": dict(zip(map(str, frames), hot,
                                                                                    strict=True)),
            "bend_rms_per_diagonal": {str(k): v for k, v in bend_quality.items()},
            "twist_max_relative_length_error": twist_len_err, "smooth_vs_linear_max_abs": smooth_vs_linear,
            "blend": path}


def shared_meshes_dir():
    env = os.environ.get("LACORE_SHARED_DATA")
    path = os.path.abspath(env if env else os.path.join(REPO, "..", "shared", "data"))
    return path if os.path.basename(path) == "meshes" else os.path.join(path, "meshes")


def finger_pair():
    """Real data: the shared finger pair (2046 vertices) as Basis + key; the in-between's edge lengths."""
    import importlib

    reset()
    load_mesh = importlib.import_module(MODULE + ".lacore.io.meshes").load_mesh
    meshes = shared_meshes_dir()
    obj = cases.shared_mesh_pair("Finger", os.path.join(meshes, "finger", "finger0.ply"),
                                 os.path.join(meshes, "finger", "finger1.ply"), "Finger1", load_mesh)
    assert interpolate(obj, key_from="Basis", key_to="Finger1", factors="0.5") == {"FINISHED"}
    A, B, X = (coords(obj, n) for n in ("Basis", "Finger1", "LA Basis>Finger1 0.500"))
    edges = cases.mesh_edges(obj)

    def lengths(P):
        return np.linalg.norm(P[edges[:, 0]] - P[edges[:, 1]], axis=1)

    target = 0.5 * (lengths(A) + lengths(B))  # the interpolated lengths
    out = {"vertices": len(A), "max_length_change_between_keys": float(np.max(np.abs(lengths(B) / lengths(A) - 1)))}
    for label, P in (("lengths_angles", X), ("linear", 0.5 * A + 0.5 * B)):
        r = lengths(P) / target - 1.0
        out[label] = {"max_relative_length_error": float(np.abs(r).max()),
                      "rms_relative_length_error": float(np.sqrt(np.mean(r ** 2)))}
    assert out["lengths_angles"]["rms_relative_length_error"] < 0.01, out
    return out


def failed_checks_warn():
    """A result failing its checks is written, with a WARNING (finger pair extrapolated to t = 1.25, 'PREVIEW':
    the least-squares relaxation folds faces); 'PREVIEW' does not warn for a target it merely does not reproduce
    (t = 0.5), and 'FAST' (continuation from t = 0.5 on) reaches an unfolded t = 1.25."""
    import importlib

    reset()
    ops_mod = importlib.import_module(MODULE + ".addon.operators_interpolate")
    runs_mod = importlib.import_module(MODULE + ".addon.runs")
    load_mesh = importlib.import_module(MODULE + ".lacore.io.meshes").load_mesh
    topology_mod = importlib.import_module(MODULE + ".lacore.geometry.topology")
    meshes = shared_meshes_dir()
    A, faces = load_mesh(os.path.join(meshes, "finger", "finger0.ply"))
    B, _ = load_mesh(os.path.join(meshes, "finger", "finger1.ply"))
    topo = topology_mod.MeshTopology.from_faces(faces, n_vertices=len(A))
    fast = []
    ops_mod.inbetween_shapes(topo, A, B, [0.5, 1.25], 'FAST', failures=fast)
    preview = []
    ops_mod.inbetween_shapes(topo, A, B, [0.5, 1.25], 'PREVIEW', failures=preview)
    warning = runs_mod.failure_warning(preview)
    assert len(preview) == 1 and preview[0].startswith("t = 1.25: folded"), preview
    assert fast == [] and runs_mod.failure_warning(fast) is None, fast
    obj = cases.shared_mesh_pair("Finger", os.path.join(meshes, "finger", "finger0.ply"),
                                 os.path.join(meshes, "finger", "finger1.ply"), "Finger1", load_mesh)
    status = interpolate(obj, key_from="Basis", key_to="Finger1", factors="1.25", method='PREVIEW')
    written = "LA Basis>Finger1 1.250" in key_names(obj)
    assert status == {"FINISHED"} and written
    return {"fast_failures": fast, "preview_failures": preview, "warning": warning, "status": sorted(status),
            "written": written}


def panel_buttons():
    """The panel draws the Encode, Interpolate and Bake buttons (recording layout, no GUI headless)."""
    from types import SimpleNamespace

    reset()
    obj = bar_with_keys()
    obj.active_shape_key_index = 1
    ctx = SimpleNamespace(object=obj, active_object=obj, scene=bpy.context.scene)
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_shape_keys, ctx)
    ops = [args[0] for name, args, _ in calls if name == "operator"]
    assert {"lengths_angles.encode", "lengths_angles.interpolate", "lengths_angles.bake_keyframes"} <= set(ops), ops
    return {"operators": ops}


def processes_side_by_side():
    """Frames computed in two processes (the worker imports the installed lacore as bl_ext...lacore, without
    the add-on and bpy) match those of one process; the operator's Processes property reaches the job;
    Auto stays in one process for a small mesh."""
    import importlib

    reset()
    obj = bar_with_keys()
    ops_mod = importlib.import_module(MODULE + ".addon.operators_interpolate")
    jobs_mod = importlib.import_module(MODULE + ".addon.jobs")
    session = importlib.import_module(MODULE + ".addon.session")
    A = coords(obj, "Basis")
    diag = float(np.linalg.norm(A.max(0) - A.min(0)))
    factors = [i / 7 for i in range(1, 7)]
    runs = {}
    for method in ("GAUSS_NEWTON", "FAST"):
        for n in (1, 2):
            session.clear_results()
            runner = ops_mod.inbetween_run(obj, "Basis", "Bend180", factors, method, workers=n)
            runner.run()
            runs[method, n] = (runner.job.processes, np.array(runner.job.results))
    differences = {m: float(np.abs(runs[m, 1][1] - runs[m, 2][1]).max() / diag) for m in ("GAUSS_NEWTON", "FAST")}
    session.clear_results()
    before = len(key_names(obj))
    assert interpolate(obj, key_from="Basis", key_to="Bend180", factors="", count=6, processes=2,
                       method='GAUSS_NEWTON') == {"FINISHED"}
    written = key_names(obj)[before:]
    operator_difference = max(float(np.abs(coords(obj, n) - X).max()) for n, X in
                              zip(written, runs["GAUSS_NEWTON", 2][1], strict=True)) / diag
    # the modal path: one tick (starts the worker process, computes this process's first frame), then Esc
    parallel = importlib.import_module(MODULE + ".lacore.parallel")
    session.clear_results()
    runner = ops_mod.inbetween_run(obj, "Basis", "Bend180", factors, "GAUSS_NEWTON", workers=2)
    runner.tick()
    running_after_tick = len(parallel._RUNNING)
    runner.cancel()
    running_after_cancel = len(parallel._RUNNING)
    # the modal operators: every chain in a worker process, Blender's process only collects
    session.clear_results()
    runner = ops_mod.inbetween_run(obj, "Basis", "Bend180", factors, "GAUSS_NEWTON", workers=2)
    runner.job.all_in_workers = True
    runner.run()
    all_in_workers = {"processes": runner.job.processes, "local_frames": runner.job.local_frames,
                      "difference": float(np.abs(np.array(runner.job.results) - runs["GAUSS_NEWTON", 1][1]).max()
                                          / diag)}
    session.clear_results()
    runner = ops_mod.inbetween_run(obj, "Basis", "Bend180", factors, "GAUSS_NEWTON", workers=2)
    runner.job.all_in_workers = True
    runner.tick()  # waits for the first frame of a worker
    runner.cancel()
    all_in_workers["cancel"] = {"done": runner.done, "running": len(parallel._RUNNING)}
    # a worker that cannot start (here: no such interpreter) or dies mid-run: this process takes over its frames
    import sys

    executable = sys.executable
    session.clear_results()
    sys.executable = os.path.join(ARGS.workdir, "no-such-python")
    try:
        runner = ops_mod.inbetween_run(obj, "Basis", "Bend180", factors, "GAUSS_NEWTON", workers=2)
        runner.run()
    finally:
        sys.executable = executable
    no_start = {"processes": runner.job.processes, "notes": list(runner.notes),
                "difference": float(np.abs(np.array(runner.job.results) - runs["GAUSS_NEWTON", 1][1]).max() / diag)}
    session.clear_results()
    runner = ops_mod.inbetween_run(obj, "Basis", "Bend180", factors, "GAUSS_NEWTON", workers=2)
    projection = runner.job.projection
    first_frame = projection._local_frame

    def kill_then_compute(i):      # the workers die once started, before this process's first frame: always
        for worker in list(parallel._RUNNING):  # mid-run, however fast they are on a loaded machine
            worker._process.kill()
        projection._local_frame = first_frame
        return first_frame(i)
    projection._local_frame = kill_then_compute
    runner.run()
    died = {"processes": runner.job.processes, "notes": list(runner.notes),
            "difference": float(np.abs(np.array(runner.job.results) - runs["GAUSS_NEWTON", 1][1]).max() / diag)}
    return {"processes": {f"{m} {n}": runs[m, n][0] for m, n in runs}, "max_difference_per_diagonal": differences,
            "worker_cannot_start": no_start, "worker_died": died, "all_in_workers": all_in_workers,
            "running_after_tick": running_after_tick, "running_after_cancel": running_after_cancel,
            "operator_keys": len(written), "operator_max_difference_per_diagonal": operator_difference,
            "auto_small_mesh": jobs_mod.job_workers(0, len(A), 6),
            "auto_large_mesh": jobs_mod.job_workers(0, 50000, 6)}


def library_meshes():
    """The bar saved in a library and linked into a shot as a library override, its mesh left linked or made an
    override too (where Blender keeps neither added keys nor bulk writes into keys when the shot is saved): In-betweens,
    Bake, Clear Bake and Remove Data (of a bake made in the library) are refused in one line naming the mesh, the
    library and Make Local, and change nothing."""
    reset()
    library = os.path.join(ARGS.workdir, "bar_library.blend")
    obj = bar_with_keys()
    assert bake(obj, keys="Basis, Bend180", frames="1 3") == {"FINISHED"}
    libraries.save_character(library, [obj])

    def clear(obj):
        with ops_context(obj):
            return bpy.ops.lengths_angles.clear_bake()

    def remove_data(obj):
        with ops_context(obj):
            return bpy.ops.lengths_angles.remove_data()

    runs = {"interpolate": lambda o: interpolate(o, key_from="Basis", key_to="Bend180", factors="0.5"),
            "bake": lambda o: bake(o, keys="Basis, Bend180", frames="1 9"), "clear_bake": clear,
            "remove_data": remove_data}
    out = {}
    for mesh_kind in ("linked", "override"):
        reset()
        obj = libraries.override_character(library, editable=True)[1].objects["Bar"]
        if mesh_kind == "override":
            obj.data.override_create(remap_local_usages=True)
        out[f"{mesh_kind}_mesh"] = [obj.data.library is not None, obj.data.override_library is not None]
        for name, run in runs.items():
            out[f"{mesh_kind}_{name}"] = expect_error(run, obj, "mesh 'Bar'", library, "Make Local")
        out[f"{mesh_kind}_keys"] = key_names(obj)
    return out


def main():
    run_cases((install_and_enable, interpolate_bar, path_method, redo_replaces, quads_ngons_and_edit_mode,
               errors_change_nothing, library_meshes, bake_and_rebake, finger_pair, failed_checks_warn, panel_buttons,
               processes_side_by_side))


if __name__ == "__main__":
    main()
