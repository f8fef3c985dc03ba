"""Blender-side checks of live nonlinear mixing of the INSTALLED extension (run in a SUBPROCESS by
tests/test_blender_live_mix.py, which prepares ``<work>/inputs.npz`` with the repo's lacore: a box bar's
``basis``, ``faces``, ``keys`` (Bend, Twist, Both), ``grouped`` (a key used with a vertex group), ``group_weights``
(a ramp of weights 0 .. 1 along the bar) and the keys of :func:`vertex_groups_and_relative_keys`).

usage: BLENDER_USER_RESOURCES=<tmp> python check_live_mix.py --zip EXT.zip --workdir DIR --result OUT.json

What Blender showed (evaluated meshes, the key values they were evaluated at, the stored mixer) goes to
``<workdir>/live_mix.npz``; pytest compares it with lacore's own mix of the same weights.
"""

import importlib
import os
import time
from types import SimpleNamespace

from harness import ARGS, MODULE, bpy, draw_panel, esc, evaluated, fake_operator, reset, run_cases, timer
import libraries
import numpy as np

WORK = os.path.dirname(ARGS.workdir)
INPUTS = dict(np.load(os.path.join(WORK, "inputs.npz")))
NAMES = ["Bend", "Twist", "Both"]
WEIGHTS = [(0.5, 0.0, 0.0), (0.5, 0.3, 0.0), (1.0, 0.0, 0.0), (0.3, 0.6, 0.4), (0.0, 0.0, 0.0)]
FRAMES = [1, 4, 7, 11]
BLEND = os.path.join(ARGS.workdir, "live.blend")
#: The mixed keys of :func:`make_rig_bar` and the values they are mixed at.
VG_NAMES = ["Bend", "Twist", "Both", "Masked", "OnBend", "Ghost"]
VG_WEIGHTS = [(0.0, 0.0, 0.0, 1.0, 0.0, 0.0), (0.5, 0.0, 0.0, 0.0, 0.5, 0.0), (0.3, 0.2, 0.0, 0.6, 0.4, 0.3),
              (0.0, 0.0, 0.0, 0.0, 0.0, 1.0)]
OUT = {}


def ext(name):
    return importlib.import_module(f"{MODULE}.addon.{name}")


def ops_context(obj):
    return bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj] if obj else [])


def select_only(obj):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def make_bar(name="Bar", grouped=False):
    """The bar with keys Bend, Twist, Both (values 0); with ``grouped`` also the key Grouped limited to the
    vertex group 'end' (weights 0 .. 1 along the bar)."""
    X, faces = INPUTS["basis"], INPUTS["faces"]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(X.tolist(), [], faces.tolist())
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    for n, K in zip(NAMES, INPUTS["keys"], strict=True):
        kb = obj.shape_key_add(name=n, from_mix=False)
        kb.data.foreach_set("co", K.astype(np.float32).ravel())
        kb.value = 0.0  # (new keys are at 1 in Blender 5)
    if grouped:
        group = obj.vertex_groups.new(name="end")
        for i, w in enumerate(INPUTS["group_weights"]):
            group.add([i], float(w), 'REPLACE')
        kb = obj.shape_key_add(name="Grouped", from_mix=False)
        kb.data.foreach_set("co", INPUTS["grouped"].astype(np.float32).ravel())
        kb.vertex_group = "end"
        kb.value = 0.0
    select_only(obj)
    return obj


def add_rig(obj, modifier):
    """An armature 'Rig' with one bone along the bar (x, 0 .. 6) deforming ``obj`` through the group 'Bone' (all
    vertices at 1) and an Armature modifier named ``modifier``; returns the armature object."""
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    select_only(rig)
    with ops_context(rig):
        bpy.ops.object.mode_set(mode='EDIT')
    bone = rig.data.edit_bones.new("Bone")
    bone.head, bone.tail = (0.0, 0.0, 0.0), (6.0, 0.0, 0.0)
    with ops_context(rig):
        bpy.ops.object.mode_set(mode='OBJECT')
    obj.vertex_groups.new(name="Bone").add(list(range(len(obj.data.vertices))), 1.0, 'REPLACE')
    obj.modifiers.new(modifier, 'ARMATURE').object = rig
    return rig


def set_values(obj, values, names=NAMES):
    for n, v in zip(names, values, strict=True):
        obj.data.shape_keys.key_blocks[n].value = v


def values(obj, names=NAMES):
    return [obj.data.shape_keys.key_blocks[n].value for n in names]


def snapshot(obj):
    """Everything of the user's a live-mixing operator must leave alone (and a failed one: everything)."""
    mesh = obj.data
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    keys = []
    for kb in (mesh.shape_keys.key_blocks if mesh.shape_keys else []):
        c = np.empty(3 * len(kb.points), np.float32)
        kb.points.foreach_get("co", c)
        keys.append((kb.name, kb.value, kb.mute, kb.slider_min, kb.slider_max, kb.relative_key.name,
                     kb.vertex_group, kb.interpolation, c.tobytes()))
    return {"keys": keys, "active": obj.active_shape_key_index, "mesh_props": sorted(mesh.keys()),
            "texts": sorted(t.name for t in bpy.data.texts),
            "co": co.tobytes(), "modifiers": [m.name for m in obj.modifiers], "mode": obj.mode,
            "use_relative": None if mesh.shape_keys is None else mesh.shape_keys.use_relative}


def enable(obj):
    with ops_context(obj):
        return sorted(bpy.ops.lengths_angles.live_mix_enable())


def disable(obj):
    with ops_context(obj):
        return sorted(bpy.ops.lengths_angles.live_mix_disable())


def status(obj):
    s = ext("live_mix").status(obj.data)
    return None if s is None else {k: v for k, v in s.items() if k != "mix_seconds"}


def panel_labels(obj):
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_live_mix, SimpleNamespace(object=obj))
    return [kw.get("text") for name, _, kw in calls if name == "label"]


def panel_controls(obj):
    """The panel's buttons ``[operator idname, text]`` and properties ``[property name, text]``."""
    calls = draw_panel(bpy.types.LENGTHS_ANGLES_PT_live_mix, SimpleNamespace(object=obj))
    return {"operators": [[args[0], kw.get("text")] for name, args, kw in calls if name == "operator"],
            "props": [[args[1], kw.get("text")] for name, args, kw in calls if name == "prop"]}


def stored_mixer(obj):
    live_mix = ext("live_mix")
    return np.frombuffer(live_mix.stored_npz(obj.data[live_mix.MIXER_PROP]), np.uint8)


# --------------------------------------------------------------------------------------------------- cases
def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    live_mix = ext("live_mix")
    return {"operators": [bpy.ops.lengths_angles.live_mix_enable.idname(),
                          bpy.ops.lengths_angles.live_mix_disable.idname()],
            "handlers": sorted(name for name, fn in live_mix._HANDLERS if fn in getattr(bpy.app.handlers, name))}


def enable_mix_disable():
    """Enable, set values (the evaluated mesh = lacore's mix), a modifier after the keys, disable (Blender's
    linear mix again, bit for bit; the user's keys untouched)."""
    reset()
    obj = make_bar()
    linear = []
    for w in WEIGHTS:
        set_values(obj, w)
        linear.append(evaluated(obj))
    set_values(obj, (0.0, 0.0, 0.0))
    before = snapshot(obj)
    t = time.perf_counter()
    result = enable(obj)
    seconds = time.perf_counter() - t
    after_enable = snapshot(obj)
    OUT["mixer_npz"] = stored_mixer(obj)
    meta = obj.data[ext("live_mix").MIXER_PROP]
    storage = {"record_bytes": len(repr(meta.to_dict())), "text": meta["text"],
               "texts": sorted(t.name for t in bpy.data.texts), "fake_user": bpy.data.texts[meta["text"]].use_fake_user}
    mixed = []
    for w in WEIGHTS:
        set_values(obj, w)
        mixed.append(evaluated(obj))
    OUT["weights"] = np.array(WEIGHTS)
    OUT["mixed"] = np.array(mixed)
    OUT["linear"] = np.array(linear)
    st = status(obj)
    labels = panel_labels(obj)
    controls = panel_controls(obj)
    # a modifier after the shape keys applies to the mix: Displace along X without a texture shifts every
    # vertex by strength * (1 - midlevel)
    set_values(obj, WEIGHTS[3])
    mod = obj.modifiers.new("Shift", 'DISPLACE')
    mod.direction, mod.strength, mod.mid_level = 'X', 0.4, 0.0
    OUT["with_modifier"] = evaluated(obj)
    obj.modifiers.remove(mod)
    OUT["without_modifier"] = evaluated(obj)
    # disable: the linear mix, bit for bit, at every weight; the keys exactly as before
    assert disable(obj) == ["FINISHED"]
    relinear = []
    for w in WEIGHTS:
        set_values(obj, w)
        relinear.append(evaluated(obj))
    set_values(obj, (0.0, 0.0, 0.0))
    return {"result": result, "seconds": round(seconds, 3), "status": st, "panel": labels, "storage": storage,
            "user_keys_untouched_by_enable": after_enable["keys"][:4] == before["keys"],
            "keys_after_enable": [k[0] for k in after_enable["keys"]],
            "mix_key": after_enable["keys"][-1][1:7],
            "active_kept": after_enable["active"] == before["active"],
            "linear_bit_for_bit": all(np.array_equal(a, b) for a, b in zip(linear, relinear, strict=True)),
            "snapshot_restored": snapshot(obj) == before, "status_after_disable": status(obj),
            "panel_after_disable": panel_labels(obj), "controls": controls,
            "controls_after_disable": panel_controls(obj)}


def keyframe_values(obj):
    """Keyframes Bend 0 -> 1 and Twist 0.2 -> 0.9 over frames 1 -> 11; returns the key blocks."""
    kbs = obj.data.shape_keys.key_blocks
    for n, (a, b) in zip(NAMES[:2], [(0.0, 1.0), (0.2, 0.9)], strict=True):
        kbs[n].value = a
        kbs[n].keyframe_insert("value", frame=1)
        kbs[n].value = b
        kbs[n].keyframe_insert("value", frame=11)
    return kbs


def keyframes_drivers_and_save():
    """Keyframed values through frame_set, a driven value, then save the .blend (reopened by the next case)."""
    reset()
    os.makedirs(ARGS.workdir, exist_ok=True)
    obj = make_bar()
    assert enable(obj) == ["FINISHED"]
    OUT["anim_mixer_npz"] = stored_mixer(obj)
    kbs = keyframe_values(obj)
    # Both: driven by an empty's x location (a simple expression: no Python needed)
    empty = bpy.data.objects.new("Control", None)
    bpy.context.scene.collection.objects.link(empty)
    fc = kbs["Both"].driver_add("value")
    var = fc.driver.variables.new()
    var.name, var.type = "x", 'TRANSFORMS'
    var.targets[0].id = empty
    var.targets[0].transform_type = 'LOC_X'
    fc.driver.expression = "x"
    empty.location.x = 0.25
    scene = bpy.context.scene
    frame_values, frame_mixed = [], []
    t = time.perf_counter()
    for f in FRAMES:
        scene.frame_set(f)
        frame_mixed.append(evaluated(obj))
        frame_values.append(values(obj))
    seconds = time.perf_counter() - t
    OUT["frame_values"], OUT["frame_mixed"] = np.array(frame_values), np.array(frame_mixed)
    empty.location.x = 0.6
    scene.frame_set(4)
    OUT["driven_values"], OUT["driven_mixed"] = np.array(values(obj)), evaluated(obj)
    scene.frame_set(7)
    record = obj.data[ext("live_mix").MIXER_PROP]
    for name in ("groups", "relative"):  # saved as a record made before keys with vertex groups were mixed
        del record[name]
    bpy.ops.wm.save_as_mainfile(filepath=BLEND)
    return {"frame_seconds": round(seconds / len(FRAMES), 4)}


def reload_still_live():
    """The saved .blend reopens mixing live (its record without the keys' vertex groups and relative keys, as made
    before those keys were mixed): load_post re-registers the mesh; playback and sliders mix."""
    bpy.ops.wm.open_mainfile(filepath=BLEND)
    obj = bpy.data.objects["Bar"]
    st = status(obj)
    scene = bpy.context.scene
    reload_values, reload_mixed = [], []
    for f in (4, 11):
        scene.frame_set(f)
        reload_mixed.append(evaluated(obj))
        reload_values.append(values(obj))
    OUT["reload_values"], OUT["reload_mixed"] = np.array(reload_values), np.array(reload_mixed)
    return {"status": st, "live": ext("live_mix").is_live(obj.data)}


def mixer_text_deleted():
    """The stored mixer's text deleted (and the file saved and reopened): Blender's linear mix, a panel message."""
    bpy.ops.wm.open_mainfile(filepath=BLEND)
    bpy.data.texts.remove(bpy.data.texts["LA live mixer Bar"])
    path = os.path.join(ARGS.workdir, "no_text.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    bpy.context.scene.frame_set(7)
    shown = evaluated(obj)
    obj.data.shape_keys.key_blocks["LA live mix"].mute = True
    linear = evaluated(obj)
    return {"status": status(obj), "panel": panel_labels(obj),
            "linear_bit_for_bit": bool(np.array_equal(shown, linear))}


def stale_when_edited():
    """An edited key or mesh: stale, the linear mix shown (bit for bit), the panel says so; restored: live."""
    bpy.ops.wm.open_mainfile(filepath=BLEND)
    obj = bpy.data.objects["Bar"]
    scene = bpy.context.scene
    scene.frame_set(7)
    live_shape = evaluated(obj)
    mix_kb = obj.data.shape_keys.key_blocks["LA live mix"]
    kb = obj.data.shape_keys.key_blocks["Twist"]
    co = np.empty(3 * len(kb.points), np.float32)
    kb.points.foreach_get("co", co)
    edited = co.copy()
    edited[:3] += 0.1
    kb.points.foreach_set("co", edited)
    obj.data.update()
    stale_shape = evaluated(obj)
    st = status(obj)
    labels = panel_labels(obj)
    mix_kb.mute = True  # Blender's linear mix without the add-on's key
    linear = evaluated(obj)
    mix_kb.mute = False
    kb.points.foreach_set("co", co)  # the edit undone by hand: live again
    obj.data.update()
    back = evaluated(obj)
    st_back = status(obj)
    # the add-on's key muted: stale, the linear mix; unmuted: live again.  Its value changed (a script, Clear
    # Shape Key Weights) is set back to 1; keyed or driven to another value: stale
    mix_kb.mute = True
    obj.data.update()
    linear_now = evaluated(obj)         # without the add-on's key: Blender's linear mix of the keys as they are
    mix_changed = {"status": status(obj)["stale"],
                   "linear_differs_from_live": float(np.abs(linear_now - live_shape).max())}
    mix_kb.mute = False
    obj.data.update()
    mix_changed["restored_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    mix_kb.value = 0.3
    obj.data.update()
    mix_changed["value_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    mix_changed["value_set_back"] = mix_kb.value
    mix_changed["value_status"] = status(obj)["stale"]
    with ops_context(obj):
        mix_changed["clear_weights"] = sorted(bpy.ops.object.shape_key_clear())
    evaluated(obj)
    mix_changed["cleared_value"] = mix_kb.value
    mix_changed["cleared_status"] = status(obj)["stale"]
    # renamed (found by the correction it holds) or its slider range cut below 1: set back, still live -- the
    # mix at other key values too (frame 4), not the correction of frame 7 frozen under another name
    scene.frame_set(4)
    live_4 = evaluated(obj)
    scene.frame_set(7)
    mix_kb.name = "Mine"
    evaluated(obj)
    scene.frame_set(4)
    mix_changed["renamed_back"] = [kb.name for kb in obj.data.shape_keys.key_blocks]
    mix_changed["renamed_status"] = status(obj)["stale"]
    mix_changed["renamed_vs_live"] = float(np.abs(evaluated(obj) - live_4).max())
    scene.frame_set(7)
    mix_kb = obj.data.shape_keys.key_blocks["LA live mix"]
    mix_kb.slider_max = 0.5
    evaluated(obj)
    mix_changed["range_set_back"] = [mix_kb.slider_max, mix_kb.value]
    mix_changed["range_status"] = status(obj)["stale"]
    mix_changed["range_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    # its coordinates edited (a script; Edit Mode on the key): written over by the next update, at the same values
    co_mix = np.empty(3 * len(mix_kb.points), np.float32)
    mix_kb.points.foreach_get("co", co_mix)
    mix_kb.points.foreach_set("co", co_mix + 0.3)
    obj.data.update()
    mix_changed["edited_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    select_only(obj)
    active = obj.active_shape_key_index
    obj.active_shape_key_index = list(obj.data.shape_keys.key_blocks).index(mix_kb)
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='EDIT')
        bpy.ops.mesh.select_all(action='SELECT')
        bpy.ops.transform.translate(value=(0.0, 0.0, 1.0))
        bpy.ops.object.mode_set(mode='OBJECT')
    obj.active_shape_key_index = active
    mix_changed["edit_mode_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    # made relative to another key (with the basis' coordinates it would subtract that key): set back to the basis
    mix_kb.relative_key = obj.data.shape_keys.key_blocks["Bend"]
    mix_changed["relative_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    mix_changed["relative_set_back"] = [mix_kb.relative_key.name, status(obj)["stale"]]
    key = obj.data.shape_keys
    fc = key.driver_add('key_blocks["LA live mix"].value')
    fc.driver.type = 'SCRIPTED'
    fc.driver.expression = "0.3"
    obj.data.update()
    evaluated(obj)
    mix_changed["driven_status"] = status(obj)["stale"]
    key.driver_remove('key_blocks["LA live mix"].value')
    obj.data.update()
    scene.frame_set(7)                  # the keys' own animation back
    mix_changed["undriven_status"] = status(obj)["stale"]
    mix_changed["undriven_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    # a topology edit (a vertex deleted in Edit Mode)
    select_only(obj)
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='EDIT')
        bpy.ops.mesh.select_all(action='DESELECT')
    obj.data.vertices[0].select = True
    import bmesh
    bm = bmesh.from_edit_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    bmesh.ops.delete(bm, geom=[bm.verts[0]], context='VERTS')
    bmesh.update_edit_mesh(obj.data)
    in_edit = ext("live_mix").status(obj.data)["stale"]
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='OBJECT')
    evaluated(obj)
    st_topology = status(obj)
    topology_labels = panel_labels(obj)
    return {"status": st, "panel": labels, "linear_bit_for_bit": bool(np.array_equal(stale_shape, linear)),
            "differs_from_live": float(np.abs(stale_shape - live_shape).max()),
            "restored_vs_live": float(np.abs(back - live_shape).max()), "status_restored": st_back,
            "stale_in_edit_mode": in_edit, "status_topology": st_topology, "panel_topology": topology_labels,
            "mix_key_changed": mix_changed}


def out_of_range_and_vertex_groups():
    """A value outside the mixer's accurate range: the result's message in the panel.  A key with a vertex
    group is mixed; a key added after the build is mixed linearly on top until Rebuild."""
    reset()
    obj = make_bar(grouped=True)
    assert enable(obj) == ["FINISHED"]
    OUT["grouped_mixer_npz"] = stored_mixer(obj)
    st = status(obj)
    set_values(obj, (0.5, 0.0, 0.0, 1.0), NAMES + ["Grouped"])
    OUT["grouped_values"] = np.array(values(obj, NAMES + ["Grouped"]))
    OUT["grouped_mixed"] = evaluated(obj)
    kb = obj.data.shape_keys.key_blocks["Bend"]
    kb.slider_max = 3.0
    kb.value = 2.5
    evaluated(obj)
    far = status(obj)
    labels = panel_labels(obj)
    kb.value = 5.0  # beyond slider_max: Blender clamps, so does the mix
    clamped = values(obj, ["Bend"])[0]
    obj.shape_key_add(name="Later", from_mix=False)  # a key added after the build: mixed linearly
    linear_after = status(obj)["linear"]
    panel_after = panel_labels(obj)
    # the quality choice (the panel's Reduced Size), applied by Rebuild (= Enable on a live mesh)
    obj.data.lengths_angles_live_mix_reduced_size = 12
    rebuilt = enable(obj)
    return {"status": st, "far": far, "panel": labels, "clamped": clamped, "linear_after_adding": linear_after,
            "panel_after_adding": panel_after,
            "rebuilt": rebuilt, "rebuilt_status": status(obj),
            "rebuilt_size": ext("live_mix")._live(obj.data).mixer.reduced_size,
            "texts_after_rebuild": sorted(t.name for t in bpy.data.texts)}


def try_op(obj, op, **kw):
    """``(result, message)`` of ``op`` run on ``obj`` (an ERROR report's message, the result CANCELLED)."""
    try:
        with ops_context(obj):
            return sorted(op(**kw)), ""
    except RuntimeError as exc:  # bpy.ops raise on ERROR reports
        return ["CANCELLED"], str(exc).strip()


def refusal(obj, op):
    """``op`` run on ``obj``: its result and message, whether the message is one line and ``obj`` unchanged."""
    before = snapshot(obj)
    res, msg = try_op(obj, op)
    return {"result": res, "message": msg, "one_line": "\n" not in msg and "Traceback" not in msg,
            "unchanged": snapshot(obj) == before}


def several_objects_and_undo():
    """Two live objects at once; undo of Enable gives back the linear mix, redo the live one; undo of Disable the
    live mix again (its mixer text back), redo the linear one."""
    reset()
    a, b = make_bar("A"), make_bar("B")
    assert enable(a) == ["FINISHED"] and enable(b) == ["FINISHED"]
    set_values(a, (0.5, 0.0, 0.0))
    set_values(b, (0.0, 0.7, 0.0))
    OUT["two_mixed"] = np.array([evaluated(a), evaluated(b)])
    select_only(a)  # Shift+D: the copy's mesh carries the mixer and mixes live too
    with ops_context(a):
        bpy.ops.object.duplicate()
    copy = bpy.context.view_layer.objects.active
    set_values(copy, (0.0, 0.0, 0.6))
    OUT["copy_mixed"] = evaluated(copy)
    copy_mesh = copy.data.name
    # the original disabled: the duplicate (sharing its mixer text) still mixes live; an object sharing the
    # duplicate's mesh (obj.copy()) shows the same; disabled from that object, the text goes with the last record
    assert disable(a) == ["FINISHED"]
    shared = copy.copy()
    bpy.context.scene.collection.objects.link(shared)
    set_values(copy, (0.3, 0.0, 0.6))
    OUT["copy_after_original_disabled"] = evaluated(copy)
    shared_vs_copy = float(np.abs(evaluated(shared) - OUT["copy_after_original_disabled"]).max())
    texts_one_left = sorted(t.name for t in bpy.data.texts)
    assert disable(shared) == ["FINISHED"]
    texts_none_left = sorted(t.name for t in bpy.data.texts)
    # undo / redo (memfile undo: the mix key and the stored mixer come and go with the mesh)
    reset()
    obj = make_bar()
    set_values(obj, (0.5, 0.3, 0.0))
    linear = evaluated(obj)
    bpy.ops.ed.undo_push(message="before live mixing")
    assert enable(obj) == ["FINISHED"]
    bpy.ops.ed.undo_push(message="live mixing")
    live_shape = evaluated(obj)
    bpy.ops.ed.undo()
    obj = bpy.data.objects["Bar"]
    undone = evaluated(obj)
    undone_live = ext("live_mix").is_live(obj.data)
    bpy.ops.ed.redo()
    obj = bpy.data.objects["Bar"]
    redone = evaluated(obj)
    redo_live = ext("live_mix").is_live(obj.data)
    # Disable undone: live again (its mixer text back), the mix follows the sliders; redone: linear again
    bpy.ops.ed.undo_push(message="live again")
    assert disable(obj) == ["FINISHED"]
    bpy.ops.ed.undo_push(message="disabled")
    bpy.ops.ed.undo()
    obj = bpy.data.objects["Bar"]
    disable_undone = {"live": ext("live_mix").is_live(obj.data), "status": status(obj)["stale"],
                      "vs_live": float(np.abs(evaluated(obj) - live_shape).max()),
                      "texts": sorted(t.name for t in bpy.data.texts)}
    set_values(obj, (0.0, 0.0, 0.6))
    OUT["disable_undone_mixed"] = evaluated(obj)
    bpy.ops.ed.redo()
    obj = bpy.data.objects["Bar"]
    set_values(obj, (0.5, 0.3, 0.0))
    disable_undone["redo_linear_bit_for_bit"] = bool(np.array_equal(evaluated(obj), linear))
    disable_undone["redo_live"] = ext("live_mix").is_live(obj.data)
    return {"disable_undone": disable_undone, "copy_mesh": copy_mesh, "shared_vs_copy": shared_vs_copy,
            "texts_one_left": texts_one_left, "texts_none_left": texts_none_left,
            "undo_linear_bit_for_bit": bool(np.array_equal(undone, linear)),
            "undone_live": undone_live,
            "redo_live": redo_live,
            "redo_vs_live": float(np.abs(redone - live_shape).max()),
            "live_differs": float(np.abs(live_shape - linear).max())}


def appended_and_deleted():
    """A live object appended from another .blend into a file with a live object of the same name brings its
    mixer along (the text renamed) and mixes; a deleted live object's mixer is gone once the saved file is opened
    again; a record of earlier versions (the text named only) is pointed at its text on loading."""
    reset()
    src = os.path.join(ARGS.workdir, "append_source.blend")
    obj = make_bar()
    assert enable(obj) == ["FINISHED"]
    bpy.ops.wm.save_as_mainfile(filepath=src)
    reset()
    here = make_bar()
    assert enable(here) == ["FINISHED"]
    with bpy.data.libraries.load(src) as (_source, target):
        target.objects = ["Bar"]
    appended = target.objects[0]
    bpy.context.scene.collection.objects.link(appended)
    w = (0.5, 0.3, 0.0)
    set_values(appended, w)
    set_values(here, w)
    shown, other = evaluated(appended), evaluated(here)
    out = {"names": [appended.name, appended.data.name], "status": status(appended),
           "texts": sorted(t.name for t in bpy.data.texts), "vs_other": float(np.abs(shown - other).max())}
    appended.data.shape_keys.key_blocks["LA live mix"].mute = True
    out["vs_linear"] = float(np.abs(shown - evaluated(appended)).max())
    appended.data.shape_keys.key_blocks["LA live mix"].mute = False
    # the first object deleted (its mesh left without users is not saved, its mixer's text was)
    bpy.data.objects.remove(here)
    path = os.path.join(ARGS.workdir, "deleted.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    out["texts_reopened"] = sorted(t.name for t in bpy.data.texts)
    obj = bpy.data.objects["Bar.001"]
    out["status_reopened"] = status(obj)
    # an earlier version's record (no pointer to its text, which had a fake user; an appended text has none)
    record = obj.data[ext("live_mix").MIXER_PROP]
    out["record_text_reopened"] = record["text"]  # the appended text's name
    record["text_id"].use_fake_user = True
    del record["text_id"]
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar.001"]
    record = obj.data[ext("live_mix").MIXER_PROP]
    out["legacy_pointed"] = record["text_id"] == bpy.data.texts[record["text"]]
    out["status_legacy"] = status(obj)
    return out


def edit_mode_round_trip():
    """Edit Mode entered and left without an edit, with the basis and then the add-on's key active: still live; the
    panel warns while the add-on's key is the active one (Edit Mode and Shape Key Lock show the active key alone)."""
    reset()
    obj = make_bar()
    kbs = obj.data.shape_keys.key_blocks
    assert enable(obj) == ["FINISHED"]
    set_values(obj, (0.5, 0.3, 0.4))
    live_shape = evaluated(obj)
    edit = []
    for active in (0, len(kbs) - 1):
        obj.active_shape_key_index = active
        with ops_context(obj):
            bpy.ops.object.mode_set(mode='EDIT')
            bpy.ops.object.mode_set(mode='OBJECT')
        edit.append([status(obj)["stale"], float(np.abs(evaluated(obj) - live_shape).max())])
    out = {"edit_mode_round_trip": edit, "panel_mix_key_active": panel_labels(obj)}
    obj.active_shape_key_index = 0
    out["panel_basis_active"] = panel_labels(obj)
    return out


def linked_from_library():
    """A live object linked from another .blend: its mix key cannot be rewritten there, so the panel says so and
    Enable / Disable are refused in one line (nothing changed); made local, it mixes live."""
    reset()
    obj = make_bar()
    assert enable(obj) == ["FINISHED"]
    OUT["linked_mixer_npz"] = stored_mixer(obj)
    kb = obj.data.shape_keys.key_blocks["Bend"]
    for f, v in ((1, 0.0), (10, 1.0)):
        kb.value = v
        kb.keyframe_insert("value", frame=f)
    bpy.context.scene.frame_set(1)
    plain = make_bar("Plain")  # not live
    library = os.path.join(ARGS.workdir, "library.blend")
    bpy.ops.wm.save_as_mainfile(filepath=library)
    reset()
    linked, plain = libraries.link_objects(library, ["Bar", "Plain"])
    bpy.context.scene.frame_set(5)
    evaluated(linked)
    out = {"status": status(linked), "panel": panel_labels(linked),
           "inbetween_note": ext("operators_interpolate").mixer_note(linked, ["Basis", "Bend"])}
    for name, o, op in (("enable", plain, bpy.ops.lengths_angles.live_mix_enable),
                        ("disable", linked, bpy.ops.lengths_angles.live_mix_disable)):
        out[name] = refusal(o, op)
    select_only(linked)
    with bpy.context.temp_override(active_object=linked, object=linked, selected_objects=[linked],
                                   selected_editable_objects=[linked]):
        assert bpy.ops.object.make_local(type='ALL') == {'FINISHED'}
    local = bpy.data.objects["Bar"]
    out["local"] = [local.data.library is None, status(local)["stale"]]
    shapes, weights = [], []
    for f in (5, 3):
        bpy.context.scene.frame_set(f)
        shapes.append(evaluated(local))
        weights.append(values(local))
    OUT["local_mixed"], OUT["local_values"] = np.array(shapes), np.array(weights)
    return out



def live_character(path, driven=False):
    """Save a library .blend at ``path`` holding the collection 'Character': the bar mixing live (its mixer ``.npz``
    returned), with ``driven`` also an empty 'Control' whose x location drives the value of Both."""
    reset()
    obj = make_bar()
    objects = [obj]
    if driven:
        control = bpy.data.objects.new("Control", None)
        bpy.context.scene.collection.objects.link(control)
        objects.append(control)
        fc = obj.data.shape_keys.key_blocks["Both"].driver_add("value")
        var = fc.driver.variables.new()
        var.name, var.type = "x", 'TRANSFORMS'
        var.targets[0].id = control
        var.targets[0].transform_type = 'LOC_X'
        fc.driver.expression = "x"
    assert enable(obj) == ["FINISHED"]
    npz = stored_mixer(obj)
    libraries.save_character(path, objects)
    return npz


def override_character(path, editable):
    """A new file with the collection 'Character' linked from ``path`` and made a library override."""
    reset()
    return libraries.override_character(path, editable)


def library_override():
    """A live character linked into a shot as a collection and made a library override: the hierarchy leaves the mesh
    linked (said stale, naming Library Override); the mesh made an override too, its key values keyed in the shot mix
    live (the mixer's text came along), also after an undo push; Enable and Disable are refused; the saved shot
    reopens live, and a system override of the mesh mixes live too; an edited key is stale (rebuilt in the library),
    and the shot follows the library's Rebuild and Disable when reopened."""
    library = os.path.join(ARGS.workdir, "character.blend")
    OUT["override_mixer_npz"] = live_character(library)
    scene, shot = override_character(library, editable=True)
    obj = shot.objects["Bar"]
    out = {"object": [obj.override_library is not None, obj.override_library.is_system_override],
           "mesh_linked": obj.data.library is not None, "status_linked": status(obj)}
    mesh = obj.data.override_create(remap_local_usages=True)  # the Outliner's Library Override > Make > Selected
    out["mesh"] = [obj.data == mesh, mesh.override_library is not None, mesh.override_library.is_system_override]
    out["texts"] = [[t.name, t.library is not None] for t in bpy.data.texts]
    kbs = mesh.shape_keys.key_blocks
    for f, v in ((1, 0.0), (11, 1.0)):
        kbs["Bend"].value = v
        kbs["Bend"].keyframe_insert("value", frame=f)
    kbs["Twist"].value = 0.3
    kbs["Twist"].keyframe_insert("value", frame=1)

    def frames(*numbers):
        shapes, weights = [], []
        for f in numbers:
            scene.frame_set(f)
            shapes.append(evaluated(obj))
            weights.append(values(obj))
        return shapes, weights

    shapes, weights = frames(4, 8)
    kbs["Both"].value = 0.4  # a slider set by hand
    shapes.append(evaluated(obj))
    weights.append(values(obj))
    bpy.ops.ed.undo_push(message="keyed")
    out["after_undo_push"] = float(np.abs(evaluated(obj) - shapes[-1]).max())
    out["status"], out["panel"] = status(obj), panel_labels(obj)
    mix_kb = kbs["LA live mix"]  # the override's mix key is written through Blender's own array, not point by point
    current = np.empty(3 * len(mix_kb.points), np.float32)
    mix_kb.points.foreach_get("co", current)
    out["key_block_array"] = ext("mesh_access").key_block_array(mix_kb, current) is not None
    point = kbs["Twist"].data[0]
    x = point.co.x
    point.co.x = x + 0.1  # an edit of a key in the shot: stale, rebuilt in the library; undone: live again
    evaluated(obj)
    out["edited"] = [status(obj)["stale"], panel_labels(obj)]
    point.co.x = x
    shown = evaluated(obj)
    out["edit_undone"] = [status(obj)["stale"], float(np.abs(shown - shapes[-1]).max())]
    for name, op in (("enable", bpy.ops.lengths_angles.live_mix_enable),
                     ("disable", bpy.ops.lengths_angles.live_mix_disable)):
        out[name] = refusal(obj, op)
    path = os.path.join(ARGS.workdir, "shot.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    scene = bpy.context.scene
    obj = next(o for o in bpy.data.objects if o.name == "Bar" and o.library is None)
    out["reopened"] = [obj.data.override_library is not None, status(obj)["stale"]]
    reopened, reopened_weights = frames(8, 4)
    # a system override (not editable in the UI: its values driven, here set by a script) mixes live too
    obj.data.override_library.is_system_override = True
    obj.data.shape_keys.key_blocks["Both"].value = 0.7
    reopened.append(evaluated(obj))
    reopened_weights.append(values(obj))
    out["system_override"] = [obj.data.override_library.is_system_override, status(obj)["stale"]]
    OUT["override_mixed"], OUT["override_values"] = np.array(shapes + reopened), np.array(weights + reopened_weights)
    # rebuilt in the library (another quality), then disabled there: the shot follows when reopened
    bpy.ops.wm.save_as_mainfile(filepath=path)
    for step in ("rebuilt", "disabled"):
        bpy.ops.wm.open_mainfile(filepath=library)
        obj = bpy.data.objects["Bar"]
        if step == "rebuilt":
            obj.data.lengths_angles_live_mix_reduced_size = 12
            assert enable(obj) == ["FINISHED"]
            OUT["override_rebuilt_npz"] = stored_mixer(obj)
        else:
            assert disable(obj) == ["FINISHED"]
        bpy.ops.wm.save_mainfile()
        bpy.ops.wm.open_mainfile(filepath=path)
        obj = next(o for o in bpy.data.objects if o.name == "Bar" and o.library is None)
        st = status(obj)
        out[step] = [None if st is None else [st["stale"], st["reduced_size"]],
                     [kb.name for kb in obj.data.shape_keys.key_blocks]]
        OUT[f"override_{step}_values"], OUT[f"override_{step}_mixed"] = np.array(values(obj)), evaluated(obj)
    return out

def library_override_driven():
    """A live character whose key is driven by an object of its own (a rig's control): the hierarchy overrides the
    mesh too (a system override); the control made editable and moved in the shot, the mesh mixes live, also in an
    animation render."""
    OUT["driven_override_mixer_npz"] = live_character(os.path.join(ARGS.workdir, "driven.blend"), driven=True)
    scene, shot = override_character(os.path.join(ARGS.workdir, "driven.blend"), editable=False)
    obj, control = shot.objects["Bar"], shot.objects["Control"]
    control.override_library.is_system_override = False  # Make Editable
    control.location.x = 0.6
    OUT["driven_override_mixed"] = evaluated(obj)
    OUT["driven_override_values"] = np.array(values(obj))
    override = obj.data.override_library
    out = {"mesh": [obj.data.library is None, override is not None and override.is_system_override],
           "stale": status(obj)["stale"]}
    # an animation render (the control keyed) shows the mix the viewport shows, not the linear one
    for f, x in ((1, 0.5), (2, 0.4)):
        control.location.x = x
        control.keyframe_insert("location", index=0, frame=f)
    render_setup(scene)
    live = render_png(scene, os.path.join(ARGS.workdir, "override_"), animation=True)
    plain = plain_renders(scene, obj, "override_")
    obj.data.shape_keys.key_blocks["LA live mix"].mute = True
    linear = render_png(scene, os.path.join(ARGS.workdir, "override_linear_"), animation=True)
    out["render"] = [[float(np.abs(a - b).max()), float(np.abs(a - c).max()), float((a > 0.5).mean())]
                     for a, b, c in zip(live, plain, linear, strict=True)]
    return out

def mix_key_muted_shape(obj):
    """The evaluated mesh without the add-on's key: Blender's linear mix of the keys as they are."""
    kb = obj.data.shape_keys.key_blocks["LA live mix"]
    kb.mute = True
    shape = evaluated(obj)
    kb.mute = False
    evaluated(obj)
    return shape


def artist_edits():
    """What an artist does to a live mesh: a muted key, a negative slider range, a key relative to a key that is not
    mixed (an add-on key: mixed linearly on top), Armature and Subdivision Surface after the keys, a key renamed
    (stale, the linear mix; named back: live) or deleted, Apply All Shape Keys."""
    reset()
    obj = make_bar()
    kbs = obj.data.shape_keys.key_blocks
    on_bend = obj.shape_key_add(name="OnBend", from_mix=False)
    co = np.empty(3 * len(on_bend.points), np.float32)
    kbs["Bend"].points.foreach_get("co", co)
    on_bend.points.foreach_set("co", co + np.tile(np.float32([0.0, 0.0, 0.2]), len(on_bend.points)))
    base = obj.shape_key_add(name="LA Base", from_mix=False)  # a key named like the add-on's: not mixed
    base.points.foreach_set("co", co)
    base.value = 0.0
    on_bend.relative_key, on_bend.value = base, 0.0
    assert enable(obj) == ["FINISHED"]
    OUT["edits_mixer_npz"] = stored_mixer(obj)
    out = {"linear": status(obj)["linear"]}
    set_values(obj, (0.5, 0.3, 0.0))
    kbs["Bend"].mute = True
    OUT["muted_mixed"] = evaluated(obj)
    kbs["Bend"].mute = False
    kbs["Twist"].slider_min = -1.0
    set_values(obj, (0.4, -0.5, 0.0))
    OUT["negative_mixed"] = evaluated(obj)
    set_values(obj, (0.4, 0.0, 0.0))
    on_bend.value = 0.5
    OUT["on_bend_mixed"] = evaluated(obj)
    on_bend.value = 0.0
    # an Armature (the bone, along x, moved 0.5 along itself) and a Subdivision Surface after the keys
    arm = add_rig(obj, "Rig")
    arm.pose.bones["Bone"].location = (0.0, 0.5, 0.0)
    select_only(obj)
    set_values(obj, (0.5, 0.3, 0.0))
    plain_shape = mix_key_muted_shape(obj)  # (its linear mix: the plain mesh below must differ from it)
    obj.modifiers["Rig"].show_viewport = False
    mixed = evaluated(obj)
    obj.modifiers["Rig"].show_viewport = True
    OUT["armature_mixed"] = evaluated(obj)
    obj.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    subdivided = evaluated(obj)
    plain = bpy.data.objects.new("Plain", bpy.data.meshes.new("Plain"))
    plain.data.from_pydata(mixed.tolist(), [], INPUTS["faces"].tolist())
    bpy.context.scene.collection.objects.link(plain)
    plain.vertex_groups.new(name="Bone").add(list(range(len(plain.data.vertices))), 1.0, 'REPLACE')
    plain.modifiers.new("Rig", 'ARMATURE').object = arm
    plain.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    out["subdivided_vs_plain"] = float(np.abs(subdivided - evaluated(plain)).max())
    out["subdivided_vertices"] = [len(subdivided), len(mixed)]
    out["mix_vs_linear"] = float(np.abs(mixed - plain_shape).max())
    obj.modifiers.clear()
    # a key renamed: followed, still live, the record takes the name; the basis too; renamed and edited: stale,
    # Blender's linear mix bit for bit; named back and the edit undone: live again
    live_mix = ext("live_mix")
    live_shape = evaluated(obj)
    kbs["Twist"].name = "Twisted"
    kbs["Basis"].name = "Rest"
    shown = evaluated(obj)
    out["renamed_status"] = status(obj)["stale"]
    out["renamed_vs_live"] = float(np.abs(shown - live_shape).max())
    record = obj.data[live_mix.MIXER_PROP]
    out["renamed_record"] = [record["basis"], list(record["keys"]), list(record["relative"])]
    out["renamed_status_keys"] = status(obj)["keys"]
    x0 = kbs["Twisted"].data[0].co.x
    kbs["Twisted"].data[0].co.x = x0 + 0.5
    kbs["Twisted"].name = "Twirl"
    shown = evaluated(obj)
    out["renamed_edited_status"] = status(obj)["stale"]
    out["renamed_edited_linear_bit_for_bit"] = bool(np.array_equal(shown, mix_key_muted_shape(obj)))
    kbs["Twirl"].data[0].co.x = x0
    kbs["Twirl"].name = "Twist"
    kbs["Rest"].name = "Basis"
    out["named_back_vs_live"] = float(np.abs(evaluated(obj) - live_shape).max())
    out["named_back_status"] = status(obj)["stale"]
    record = obj.data[live_mix.MIXER_PROP]
    out["named_back_record"] = [record["basis"], list(record["keys"])]
    # renamed and at once asked for a mixer (In-betweens from a script, or its dialog's draw): followed, stored at
    # the next update
    kbs["Bend"].name = "Bent"
    try:
        _, weights, _, _ = live_mix.mixer_for_keys(obj, ["Basis", "Bent"])
        out["renamed_mixer_for_keys"] = weights.tolist()
    except Exception as exc:
        out["renamed_mixer_for_keys"] = f"{type(exc).__name__}: {exc}"
    out["renamed_record_before_update"] = list(obj.data[live_mix.MIXER_PROP]["keys"])
    evaluated(obj)
    out["renamed_record_after_update"] = list(obj.data[live_mix.MIXER_PROP]["keys"])
    kbs["Bent"].name = "Bend"
    evaluated(obj)
    obj.shape_key_remove(kbs["Twist"])
    shown = evaluated(obj)
    out["deleted_status"] = status(obj)["stale"]
    out["deleted_linear_bit_for_bit"] = bool(np.array_equal(shown, mix_key_muted_shape(obj)))
    # every key applied (Apply All Shape Keys): the mesh keeps the shape shown, Disable drops the mixer
    set_values(obj, (0.5, 0.0), ["Bend", "Both"])
    shown = evaluated(obj)
    with ops_context(obj):
        out["applied"] = sorted(bpy.ops.object.shape_key_remove(all=True, apply_mix=True))
    out["applied_vs_shown"] = float(np.abs(evaluated(obj) - shown).max())
    out["applied_status"] = status(obj)["stale"]
    out["applied_disable"] = [disable(obj), sorted(t.name for t in bpy.data.texts), sorted(obj.data.keys())]
    return out


def new_shape_from_mix():
    """*New Shape from Mix* on a live mesh: the new key is the shape shown (the nonlinear mix); it is added linearly
    until Rebuild (the panel says so), and after Rebuild it is mixed live like the others."""
    reset()
    obj = make_bar()
    assert enable(obj) == ["FINISHED"]
    set_values(obj, (0.5, 0.3, 0.0))
    shown = evaluated(obj)
    with ops_context(obj):
        out = {"added": sorted(bpy.ops.object.shape_key_add(from_mix=True))}
    new = obj.active_shape_key
    co = np.empty(3 * len(new.points), np.float32)
    new.points.foreach_get("co", co)
    OUT["from_mix_key"] = co.reshape(-1, 3)
    OUT["from_mix_shown"] = shown
    new.value = 0.0                                 # (Blender 5 makes new keys at 1)
    out["unchanged_at_0"] = float(np.abs(evaluated(obj) - shown).max())
    s = status(obj)
    out["name"], out["status"] = new.name, [s["keys"], s["linear"], s["stale"]]
    out["panel"] = panel_labels(obj)
    assert enable(obj) == ["FINISHED"]              # Rebuild: the new key is mixed live too
    s = status(obj)
    out["rebuilt_status"] = [s["keys"], s["linear"], s["stale"]]
    set_values(obj, (0.0, 0.0, 0.0))
    new.value = 1.0
    OUT["from_mix_alone"] = evaluated(obj)
    return out


def mix_key_name():
    """A user key already named 'LA live mix': Enable refused, nothing changed; renamed, Enable mixes and leaves it
    alone.  The add-on's key renamed, then saved (Object Mode: which name the save's updates see), renamed in Edit Mode
    (nothing is updated there) and saved, reopened: the mix key again and live at other values.  A user key renamed
    and named back before an update: the panel's state then and after the update."""
    reset()
    obj = make_bar()
    kb = obj.shape_key_add(name="LA live mix", from_mix=False)
    mine = np.empty(3 * len(kb.points), np.float32)
    kb.points.foreach_get("co", mine)
    mine += np.tile(np.float32([0.0, 0.0, 0.2]), len(kb.points))
    kb.points.foreach_set("co", mine)
    kb.value, kb.relative_key = 0.0, kb  # (relative to itself: mixed linearly, adds nothing)
    out = {"clash": refusal(obj, bpy.ops.lengths_angles.live_mix_enable)}
    kb.name = "Mine"
    run = ext("live_mix").enable_run(obj)   # the user's key takes the name while the mixer is built
    kb.name = "LA live mix"
    run.run()
    try:
        run.finish()
        out["named_during_build"] = "written"
    except Exception as exc:
        out["named_during_build"] = f"{type(exc).__name__}: {exc}"
    out["named_during_build_kept"] = bool(np.array_equal(key_coords(obj, ["LA live mix"])[0].ravel(), mine)
                                          and ext("live_mix").MIXER_PROP not in obj.data)
    kb.name = "Mine"
    assert enable(obj) == ["FINISHED"]
    OUT["name_mixer_npz"] = stored_mixer(obj)
    kbs = obj.data.shape_keys.key_blocks
    out["mine_kept"] = bool(np.array_equal(key_coords(obj, ["Mine"])[0].ravel(), mine))
    # a copy saved with the record's digest of the keys' bytes as they are (-0.0 and 0.0 apart), as stored before
    live_mix = ext("live_mix")
    meta, live = obj.data[live_mix.MIXER_PROP], live_mix._live(obj.data)
    coords = live_mix._key_coords(obj.data.shape_keys, [live.basis, *live.names], live.n_vertices)
    by_value = meta["fingerprint"]
    meta["fingerprint"] = live_mix._digest(coords, live_mix._corners(obj.data), signed_zeros=True)
    out["signed_zeros_digest_differs"] = meta["fingerprint"] != by_value
    legacy = os.path.join(ARGS.workdir, "signed_zeros_digest.blend")
    bpy.ops.wm.save_as_mainfile(filepath=legacy, copy=True)
    meta["fingerprint"] = by_value
    set_values(obj, (0.5, 0.3, 0.0))
    evaluated(obj)
    seen = []  # the add-on's key's name at each update while saving (after the add-on's handler)
    bpy.app.handlers.depsgraph_update_post.append(lambda *_a: seen.append(kbs[-1].name))
    kbs["LA live mix"].name = "Renamed"
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(ARGS.workdir, "renamed.blend"))
    out["save_updates"] = list(seen)
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='EDIT')
    kbs["LA live mix"].name = "Renamed"
    kbs["Both"].name = "Both Ways"  # a user key renamed in Edit Mode: the save takes its name into the record
    evaluated(obj)
    out["renamed_in_edit_mode"] = kbs[-1].name
    path = os.path.join(ARGS.workdir, "renamed_edit.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    out["reopened_mode"] = obj.mode
    select_only(obj)
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='OBJECT')
    kbs = obj.data.shape_keys.key_blocks
    out["reopened_keys"] = [kb.name for kb in kbs]
    evaluated(obj)
    out["reopened_renamed"] = [status(obj)["stale"], status(obj)["keys"]]
    kbs["Both Ways"].name = "Both"
    set_values(obj, (0.2, 0.6, 0.0))
    OUT["reopened_mixed"] = evaluated(obj)
    OUT["reopened_values"] = np.array(values(obj))
    out["reopened_status"] = status(obj)["stale"]
    # a user key made relative to another key (an update: stale) and set back before the next update
    kbs["Twist"].relative_key = kbs["Bend"]
    evaluated(obj)
    out["user_renamed"] = status(obj)["stale"]
    kbs["Twist"].relative_key = kbs["Basis"]
    offset = key_coords(obj, [kbs[-1].name])[0] - key_coords(obj, ["Basis"])[0]  # (the add-on's key, last)
    out["named_back_before_update"] = [status(obj)["stale"], float(np.abs(offset).max())]
    out["named_back_panel"] = panel_labels(obj)
    evaluated(obj)
    out["named_back_after_update"] = status(obj)["stale"]
    bpy.ops.wm.open_mainfile(filepath=legacy)
    out["signed_zeros_digest_status"] = status(bpy.data.objects["Bar"])["stale"]
    return out


def bad_input():
    """No shape keys, one key, a key not yet shaped, a degenerate key, Edit Mode, absolute keys, disable without a
    mixer, a mesh without faces: one line, nothing changed."""
    reset()
    out = {}

    def attempt(name, obj, op):
        out[name] = refusal(obj, op)

    mesh = bpy.data.meshes.new("Plain")
    mesh.from_pydata(INPUTS["basis"].tolist(), [], INPUTS["faces"].tolist())
    plain = bpy.data.objects.new("Plain", mesh)
    bpy.context.scene.collection.objects.link(plain)
    select_only(plain)
    attempt("no_shape_keys", plain, bpy.ops.lengths_angles.live_mix_enable)
    plain.shape_key_add(name="Basis", from_mix=False)
    attempt("one_key", plain, bpy.ops.lengths_angles.live_mix_enable)
    attempt("disable_not_live", plain, bpy.ops.lengths_angles.live_mix_disable)
    key = plain.shape_key_add(name="Key 1", from_mix=False)        # added, not yet shaped
    attempt("unchanged_key", plain, bpy.ops.lengths_angles.live_mix_enable)
    a, b = (int(i) for i in INPUTS["faces"][0][:2])
    key.data[a].co = key.data[b].co                                 # an edge collapsed: degenerate triangles
    attempt("degenerate_key", plain, bpy.ops.lengths_angles.live_mix_enable)
    obj = make_bar()
    obj.data.shape_keys.use_relative = False
    attempt("absolute_keys", obj, bpy.ops.lengths_angles.live_mix_enable)
    obj.data.shape_keys.use_relative = True
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='EDIT')
    attempt("edit_mode", obj, bpy.ops.lengths_angles.live_mix_enable)
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='OBJECT')
    def keyed(name, vertices, faces, moved, to):
        """A selected object with a Basis and a key 'Key 1' whose vertex ``moved`` is at ``to``."""
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata(vertices, [], faces)
        made = bpy.data.objects.new(name, mesh)
        bpy.context.scene.collection.objects.link(made)
        made.shape_key_add(name="Basis", from_mix=False)
        made.shape_key_add(name="Key 1", from_mix=False).data[moved].co = to
        select_only(made)
        return made
    cloud = keyed("Points", INPUTS["basis"].tolist(), [], 0, (9.0, 9.0, 9.0))  # vertices only, keys shaped
    attempt("no_faces", cloud, bpy.ops.lengths_angles.live_mix_enable)
    fan = keyed("Fan", [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1)],  # 3 triangles on the edge (0, 1)
                [(0, 1, 2), (1, 0, 3), (0, 1, 4)], 2, (0.0, 1.0, 0.5))
    attempt("non_manifold", fan, bpy.ops.lengths_angles.live_mix_enable)
    other = obj.copy()  # the same mesh, in Edit Mode through another object
    bpy.context.scene.collection.objects.link(other)

    def other_mode(mode):
        select_only(other)
        with ops_context(other):
            bpy.ops.object.mode_set(mode=mode)
        select_only(obj)
    other_mode('EDIT')
    attempt("shared_edit_mode", obj, bpy.ops.lengths_angles.live_mix_enable)
    other_mode('OBJECT')
    assert enable(obj) == ["FINISHED"]
    other_mode('EDIT')
    attempt("shared_edit_mode_disable", obj, bpy.ops.lengths_angles.live_mix_disable)
    other_mode('OBJECT')
    return out


def many_keys_kept_linear():
    """More keys than a mixer takes (Bend, Twist, Both and ``INPUTS["many"]``: 7): Enable refused in one line naming
    Keep Linear, nothing changed.  Keep Linear on the active key Swell (the panel says so): Enable mixes the other six
    and Blender adds Swell linearly on top.  Mix Live on Swell and Keep Linear on Bend apply at the next Rebuild (the
    report and the panel say so); Keep Linear on the basis is refused."""
    reset()
    obj = make_bar()
    names = ["Lift", "Push", "Slide", "Swell"]
    for name, shape in zip(names, INPUTS["many"], strict=True):
        obj.shape_key_add(name=name, from_mix=False).points.foreach_set("co", shape.astype(np.float32).ravel())
    out = {"too_many": refusal(obj, bpy.ops.lengths_angles.live_mix_enable)}
    kbs = obj.data.shape_keys.key_blocks

    def keep(name, linear=True):
        obj.active_shape_key_index = kbs.find(name)
        return try_op(obj, bpy.ops.lengths_angles.live_mix_keep_linear, linear=linear)
    obj.active_shape_key_index = 0
    out["basis"] = refusal(obj, bpy.ops.lengths_angles.live_mix_keep_linear)
    out["keep_swell"] = keep("Swell")
    out["panel_before"] = [t for t in panel_labels(obj) if t and "Swell" in t]
    out["enable"] = enable(obj)
    st = status(obj)
    out["keys"], out["linear_reasons"] = st["keys"], st["linear_reasons"]
    mixed = [0.4, 0.3, 0.2, 0.0, 0.5, 0.0]
    set_values(obj, mixed, st["keys"])
    kbs["Swell"].value = 0.0
    OUT["kept_mixer_npz"] = stored_mixer(obj)
    OUT["kept_mixed"] = evaluated(obj)
    OUT["kept_weights"] = np.array(mixed)
    kbs["Swell"].value = 0.5
    OUT["kept_swell_half"] = evaluated(obj)
    kbs["Swell"].value = 0.0
    out["mix_swell_live"] = keep("Swell", linear=False)
    out["keep_bend"] = keep("Bend")
    st = status(obj)
    out["kept_linear_mixed"] = st["kept_linear_mixed"]
    out["panel_after"] = [t for t in panel_labels(obj) if t and ("Rebuild" in t or "Bend" in t)]
    out["linear_choice"] = sorted(ext("live_mix").linear_choice(obj.data))
    keep("Bend", linear=False)                                      # seven keys to mix again
    obj.data.lengths_angles_live_mix_max_keys = 7
    out["panel_most_keys"] = [p for p in panel_controls(obj)["props"] if "max_keys" in p[0]]
    out["rebuild_seven"] = enable(obj)
    st = status(obj)
    out["seven_keys"] = st["keys"]
    seven = [0.4, 0.3, 0.2, 0.0, 0.5, 0.0, 0.3]
    set_values(obj, seven, st["keys"])
    OUT["seven_mixer_npz"] = stored_mixer(obj)
    OUT["seven_mixed"] = evaluated(obj)
    OUT["seven_weights"] = np.array(seven)
    return out


def kept_linear_renamed():
    """Keep Linear on Swell, then Swell renamed Puff: still kept linear (found by its coordinates), in the panel
    and at Enable, which stores the new name.  A file that stored names only keeps them.  Renamed and edited, or
    deleted, it is no longer kept; edited, saved (which stores its coordinates) and then renamed, it is."""
    reset()
    obj = make_bar()
    kbs = obj.data.shape_keys.key_blocks
    obj.shape_key_add(name="Swell", from_mix=False).points.foreach_set(
        "co", INPUTS["many"][3].astype(np.float32).ravel())
    obj.active_shape_key_index = kbs.find("Swell")
    live_mix = ext("live_mix")
    out = {"keep": try_op(obj, bpy.ops.lengths_angles.live_mix_keep_linear)}
    kbs["Swell"].name = "Puff"
    out["choice_renamed"] = sorted(live_mix.linear_choice(obj.data))
    obj.active_shape_key_index = kbs.find("Puff")
    out["panel_renamed"] = [t for t in panel_labels(obj) if t and "Puff" in t]
    out["enable"] = enable(obj)
    st = status(obj)
    out["keys"], out["linear_reasons"] = st["keys"], st["linear_reasons"]
    out["stored"] = sorted(obj.data[live_mix.LINEAR_KEYS_PROP].keys())
    obj.data[live_mix.LINEAR_KEYS_PROP] = ["Puff"]  # a file that stored names only
    out["choice_names_only"] = sorted(live_mix.linear_choice(obj.data))
    out["keep_again"] = try_op(obj, bpy.ops.lengths_angles.live_mix_keep_linear)
    kbs["Puff"].name = "Puff2"
    x0 = kbs["Puff2"].data[0].co.x
    kbs["Puff2"].data[0].co.x = x0 + 0.5
    out["choice_renamed_edited"] = sorted(live_mix.linear_choice(obj.data))
    kbs["Puff2"].data[0].co.x = x0
    out["choice_edit_undone"] = sorted(live_mix.linear_choice(obj.data))
    obj.active_shape_key_index = kbs.find("Puff2")  # kept under this name, edited, saved, renamed: still kept
    out["keep_puff2"] = try_op(obj, bpy.ops.lengths_angles.live_mix_keep_linear)
    kbs["Puff2"].data[0].co.x = x0 + 0.5
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(ARGS.workdir, "kept_linear.blend"))
    obj = bpy.data.objects["Bar"]
    kbs = obj.data.shape_keys.key_blocks
    kbs["Puff2"].name = "Puff3"
    out["choice_edited_saved_renamed"] = sorted(live_mix.linear_choice(obj.data))
    obj.shape_key_remove(kbs["Puff3"])
    out["choice_deleted"] = sorted(live_mix.linear_choice(obj.data))
    obj.active_shape_key_index = kbs.find("Bend")
    out["keep_bend"] = try_op(obj, bpy.ops.lengths_angles.live_mix_keep_linear)
    out["stored_after_delete"] = sorted(obj.data[live_mix.LINEAR_KEYS_PROP].keys())
    return out


def modal_run_and_cancel():
    """From the UI the mixer is built in a worker process (timer events drive modal()); Esc kills it at once and
    writes nothing."""
    runs = ext("runs")
    reset()
    obj = make_bar()
    op, run = fake_operator(), ext("live_mix").enable_run(obj)
    op._begin_modal(bpy.context, run)
    state, end = {'RUNNING_MODAL'}, time.perf_counter() + 120
    ticks = 0
    while state == {'RUNNING_MODAL'} and time.perf_counter() < end:
        state = op.modal(bpy.context, timer(op))
        ticks += 1
        time.sleep(0.005)
    finished = {"state": sorted(state), "reports": [r[0] for r in op.reports], "ticks": ticks,
                "live": ext("live_mix").is_live(obj.data)}
    assert disable(obj) == ["FINISHED"]
    before = snapshot(obj)
    op, run = fake_operator(), ext("live_mix").enable_run(obj)
    op._begin_modal(bpy.context, run)
    op.modal(bpy.context, timer(op))  # the build starts in a worker process (from the worker thread)
    parallel = importlib.import_module(f"{MODULE}.lacore.parallel")
    deadline = time.perf_counter() + 10.0
    while not parallel._RUNNING and time.perf_counter() < deadline:   # Esc while the worker runs, however fast
        time.sleep(0.005)
    started = len(parallel._RUNNING)
    t = time.perf_counter()
    cancelled = op.modal(bpy.context, esc())
    runs.wait_for_worker_thread()
    return {"finished": finished, "cancelled": sorted(cancelled), "cancel_reports": op.reports,
            "unchanged": snapshot(obj) == before, "workers_started": started,
            "workers_left": len(parallel._RUNNING), "cancel_seconds": time.perf_counter() - t}


def render_png(scene, path, animation=False):
    """Cycles (1 sample, transparent film) to PNG; returns the alpha channels (the silhouettes) per frame."""
    scene.render.filepath = path
    assert bpy.ops.render.render(animation=animation, write_still=not animation) == {'FINISHED'}
    frames = range(scene.frame_start, scene.frame_end + 1) if animation else [None]
    out = []
    for f in frames:
        file = scene.render.frame_path(frame=f) if f is not None else path
        img = bpy.data.images.load(file)
        px = np.array(img.pixels[:], np.float32).reshape(img.size[1], img.size[0], 4)
        bpy.data.images.remove(img)
        out.append(px[..., 3])
    return out


def render_setup(scene):
    """An orthographic camera onto the bar, Cycles at 1 sample and 48 x 48 pixels, frames 1 to 2."""
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale = 'ORTHO', 9.0
    cam.location, cam.rotation_euler = (3.0, -20.0, 2.0), (np.pi / 2, 0.0, 0.0)
    scene.camera = cam
    scene.render.engine = 'CYCLES'
    scene.cycles.samples = 1
    scene.render.film_transparent = True
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.render.image_settings.file_format = 'PNG'
    scene.frame_start, scene.frame_end = 1, 2


def plain_renders(scene, obj, prefix):
    """Renders (alpha) of the viewport's evaluated ``obj`` at frames 1 and 2, each as a plain mesh in its place."""
    copies = []
    for f in (1, 2):
        scene.frame_set(f)
        X = evaluated(obj)
        mesh = bpy.data.meshes.new(f"Copy{f}")
        mesh.from_pydata(X.tolist(), [], INPUTS["faces"].tolist())
        copies.append(bpy.data.objects.new(f"Copy{f}", mesh))
    obj.hide_render = True
    plain = []
    for copy in copies:
        scene.collection.objects.link(copy)
        plain.append(render_png(scene, os.path.join(ARGS.workdir, f"{prefix}{copy.name}.png"))[0])
        scene.collection.objects.unlink(copy)
    obj.hide_render = False
    return plain


def renders():
    """An animation render (as on the command line: the render's own depsgraph at every frame) shows the live
    mix -- the same pixels as a render of a plain mesh holding the viewport's evaluated mix -- and not the
    linear one; so does a still (F12) render of the current frame."""
    reset()
    obj = make_bar()
    kb = obj.shape_key_add(name="Fold", from_mix=False)
    kb.data.foreach_set("co", INPUTS["fold"].astype(np.float32).ravel())
    for f, v in ((1, 0.5), (2, 0.75)):
        kb.value = v
        kb.keyframe_insert("value", frame=f)
    group = obj.vertex_groups.new(name="ramp")  # a twist limited to a ramp of weights, set for the exact render
    for i, w in enumerate(INPUTS["group_weights"]):
        group.add([i], float(w), 'REPLACE')
    kb = obj.shape_key_add(name="Ramp", from_mix=False)
    kb.data.foreach_set("co", INPUTS["masked"].astype(np.float32).ravel())
    kb.vertex_group, kb.value = "ramp", 0.0
    assert enable(obj) == ["FINISHED"]
    scene = bpy.context.scene
    render_setup(scene)
    t = time.perf_counter()
    live = render_png(scene, os.path.join(ARGS.workdir, "live_"), animation=True)
    seconds = time.perf_counter() - t
    scene.frame_set(2)
    still = render_png(scene, os.path.join(ARGS.workdir, "still.png"))[0]
    plain = plain_renders(scene, obj, "")
    # Exact in Renders: a still render at frame 2, three more keys set (one extrapolated, one limited to a vertex
    # group), polishes the mix; the viewport keeps the render's shape
    live_mix = ext("live_mix")
    keys = obj.data.shape_keys.key_blocks
    keys["Bend"].value, keys["Twist"].value, keys["Ramp"].value = 0.7, 1.4, 0.8
    reduced = evaluated(obj)
    setattr(obj.data, live_mix.EXACT_RENDERS_PROP, True)
    t = time.perf_counter()
    render_png(scene, os.path.join(ARGS.workdir, "exact.png"))
    exact_seconds = time.perf_counter() - t
    OUT["render_reduced"], OUT["render_exact"] = reduced, evaluated(obj)
    OUT["render_mixer_npz"] = stored_mixer(obj)
    OUT["render_weights"] = ext("live_mix")._live(obj.data).last
    exact_state = live_mix.status(obj.data)
    setattr(obj.data, live_mix.EXACT_RENDERS_PROP, False)
    keys["Bend"].value = keys["Twist"].value = keys["Ramp"].value = 0.0
    assert disable(obj) == ["FINISHED"]
    linear = render_png(scene, os.path.join(ARGS.workdir, "linear_"), animation=True)
    diff = lambda a, b: float(np.abs(a - b).max())  # noqa: E731
    return {"seconds": round(seconds, 2), "exact_seconds": round(exact_seconds, 2),
            "exact_state": {k: exact_state[k] for k in ("polished", "in_range", "message")},
            "covered": [float((a > 0.5).mean()) for a in live],
            "live_vs_plain": [diff(a, b) for a, b in zip(live, plain, strict=True)],
            "live_vs_linear": [diff(a, b) for a, b in zip(live, linear, strict=True)],
            "still_vs_frame2": diff(still, live[1])}


def key_coords(obj, names):
    out = []
    for n in names:
        kb = obj.data.shape_keys.key_blocks[n]
        c = np.empty(3 * len(kb.points), np.float32)
        kb.points.foreach_get("co", c)
        out.append(c.reshape(-1, 3))
    return np.array(out)


def inbetweens_and_bake_with_mixer():
    """In-betweens and Bake with the live mixer (the default on a live mesh): one mix per in-between, placed like
    the other methods; Gauss-Newton for comparison; without a mixer (or a stale one) the default stays Fast and
    the Live Mixer method is refused in one line; an extrapolated factor outside the mixer's range is named."""
    ops_mod, runs, jobs = ext("operators_interpolate"), ext("runs"), ext("jobs")
    reset()
    obj = make_bar()
    out = {"default_without_mixer": ops_mod.default_method(obj, ["Basis", "Bend"]),
           "note_without_mixer": ops_mod.mixer_note(obj, ["Basis", "Bend"])}
    before = snapshot(obj)
    out["refused"] = try_op(obj, bpy.ops.lengths_angles.interpolate, key_from="Basis", key_to="Bend",
                            factors="0.5", method='MIXER')
    out["refused_unchanged"] = snapshot(obj) == before
    assert enable(obj) == ["FINISHED"]
    OUT["inb_mixer_npz"] = stored_mixer(obj)
    out["default_with_mixer"] = ops_mod.default_method(obj, ["Basis", "Bend"])
    out["default_other_key"] = ops_mod.default_method(obj, ["Basis", "LA live mix"])
    out["notes"] = [ops_mod.mixer_note(obj, ["Basis", "Bend"]), ops_mod.mixer_note(obj, ["Basis", "LA live mix"])]
    pairs = [("Basis", "Bend"), ("Twist", "Both")]
    factors = (0.25, 0.5, 0.75)
    for method in ('GAUSS_NEWTON', None):
        shapes = []
        for a, b in pairs:
            kw = {} if method is None else {"method": method}
            t = time.perf_counter()
            res, msg = try_op(obj, bpy.ops.lengths_angles.interpolate, key_from=a, key_to=b,
                              factors=" ".join(map(str, factors)), **kw)
            out[f"seconds_{method or 'default'}_{a}"] = round(time.perf_counter() - t, 3)
            assert res == ["FINISHED"], (res, msg)
            shapes.append(key_coords(obj, [ext("naming").inbetween_key_name(a, b, f) for f in factors]))
        OUT[f"inb_{(method or 'default').lower()}"] = np.array(shapes)
    OUT["inb_factors"] = np.array(factors)
    # Bake through Basis, Bend, Twist at frames 1, 5, 9 (default method: the mixer)
    keys_before = ext("mesh_access").key_names(obj.data)
    res, msg = try_op(obj, bpy.ops.lengths_angles.bake_keyframes, keys="Basis, Bend, Twist", frames="1, 5, 9")
    assert res == ["FINISHED"], (res, msg)
    baked = [n for n in ext("mesh_access").key_names(obj.data) if n not in keys_before]
    out["baked_names"] = baked
    OUT["baked"] = key_coords(obj, baked)
    # an extrapolated factor far outside the keys: written, and the warning names it and suggests Gauss-Newton
    run = ops_mod.inbetween_run(obj, "Basis", "Bend", [2.5], 'MIXER')
    jobs.run_job(run.job)
    out["far_warning"] = runs.failure_warning(run.job.failures)
    # a stale mixer: the default goes back to Fast and the Live Mixer method says why
    kb = obj.data.shape_keys.key_blocks["Twist"]
    co = np.empty(3 * len(kb.points), np.float32)
    kb.points.foreach_get("co", co)
    co[:3] += 0.1
    kb.points.foreach_set("co", co)
    obj.data.update()
    out["default_stale"] = ops_mod.default_method(obj, ["Basis", "Bend"])
    out["note_stale"] = ops_mod.mixer_note(obj, ["Basis", "Bend"])
    out["refused_stale"] = try_op(obj, bpy.ops.lengths_angles.interpolate, key_from="Basis", key_to="Bend",
                                  factors="0.5", method='MIXER')
    return out


def make_rig_bar():
    """The bar as a facial rig has its keys: besides Bend, Twist and Both, Masked (a twist limited to the vertex group
    'ramp', weights 0 .. 1 along the bar), OnBend (relative to Bend), Ghost (limited to the group 'nope', which the
    mesh does not have), SelfRel (relative to itself), an add-on key 'LA Extra' and OnExtra relative to it."""
    obj = make_bar()
    kbs = obj.data.shape_keys.key_blocks
    group = obj.vertex_groups.new(name="ramp")
    for i, w in enumerate(INPUTS["group_weights"]):
        group.add([i], float(w), 'REPLACE')

    def add(name, co, relative=None, group=""):
        kb = obj.shape_key_add(name=name, from_mix=False)
        kb.data.foreach_set("co", np.asarray(co, np.float32).ravel())
        kb.value = 0.0
        if relative is not None:
            kb.relative_key = kb if relative == name else kbs[relative]
        kb.vertex_group = group
    add("Masked", INPUTS["masked"], group="ramp")
    add("OnBend", INPUTS["on_bend"], relative="Bend")
    add("Ghost", INPUTS["ghost"], group="nope")
    add("SelfRel", INPUTS["on_bend"], relative="SelfRel")
    add("LA Extra", INPUTS["extra"])
    add("OnExtra", INPUTS["on_extra"], relative="LA Extra")
    return obj


def vertex_groups_and_relative_keys():
    """Keys limited to a vertex group and keys relative to another key are mixed (the evaluated mesh = lacore's mix
    with the same masks and relative keys); keys relative to themselves or to a key that is not mixed stay linear
    on top.  A weight edited, a key's group or relative key changed: stale; undone or set back: live.  Saved and
    reopened: live; Disable: Blender's linear mix bit for bit.  A group name the mesh lacks: the key applies to all
    vertices, in Blender and in the mix."""
    live_mix, ops_mod = ext("live_mix"), ext("operators_interpolate")
    reset()
    out = {}
    # a vertex group but no weights stored on the mesh at all: Blender limits nothing, nor does the add-on's read
    probe = make_bar("Probe")
    probe.vertex_groups.new(name="empty")
    kb = probe.data.shape_keys.key_blocks["Bend"]
    kb.value = 1.0
    full = evaluated(probe)
    kb.vertex_group = "empty"
    masks = live_mix.vertex_masks(probe.data, live_mix._group_indices(probe, ["empty"]))  # (must not add weights)
    out["no_weights_stored"] = [bool(np.array_equal(evaluated(probe), full)), float(masks.min())]
    reset()
    obj = make_rig_bar()
    kbs = obj.data.shape_keys.key_blocks
    # what Blender does with a group name the mesh does not have: the key applies to all vertices
    kbs["Ghost"].value = 1.0
    ghost_shown = evaluated(obj)
    kbs["Ghost"].vertex_group = ""
    out["missing_group_as_none"] = bool(np.array_equal(ghost_shown, evaluated(obj)))
    kbs["Ghost"].vertex_group, kbs["Ghost"].value = "nope", 0.0
    before = []
    for w in VG_WEIGHTS:
        set_values(obj, w, VG_NAMES)
        before.append(evaluated(obj))
    set_values(obj, [0.0] * len(VG_NAMES), VG_NAMES)
    assert enable(obj) == ["FINISHED"]
    OUT["vg_mixer_npz"] = stored_mixer(obj)
    record = obj.data[live_mix.MIXER_PROP]
    out["record"] = {k: list(record[k]) for k in ("keys", "groups", "relative")}
    st = status(obj)
    out["status"] = {k: st[k] for k in ("keys", "linear", "linear_reasons", "stale")}
    out["panel"] = panel_labels(obj)
    mixed, linear = [], []
    for w in VG_WEIGHTS:
        set_values(obj, w, VG_NAMES)
        mixed.append(evaluated(obj))
        linear.append(mix_key_muted_shape(obj))
    OUT["vg_mixed"], OUT["vg_linear"], OUT["vg_weights"] = np.array(mixed), np.array(linear), np.array(VG_WEIGHTS)
    kbs["OnExtra"].value = 0.5  # linear on top of the mix
    OUT["vg_on_extra"] = evaluated(obj)
    kbs["OnExtra"].value = 0.0
    # in-betweens: the mixer only for keys whose weight 1 is their shape
    out["inbetween"] = {"default_bend": ops_mod.default_method(obj, ["Basis", "Bend"]),
                        "default_masked": ops_mod.default_method(obj, ["Basis", "Masked"]),
                        "note_masked": ops_mod.mixer_note(obj, ["Basis", "Masked"]),
                        "note_on_bend": ops_mod.mixer_note(obj, ["Bend", "OnBend"])}
    res, msg = try_op(obj, bpy.ops.lengths_angles.interpolate, key_from="Basis", key_to="Bend", factors="0.5")
    assert res == ["FINISHED"], (res, msg)
    OUT["vg_inbetween"] = key_coords(obj, [ext("naming").inbetween_key_name("Basis", "Bend", 0.5)])[0]
    # a weight painted (a script's edit: vertex 0 from 0 to 0.9): stale, the linear mix; undone: live
    live_shape = evaluated(obj)
    bpy.ops.ed.undo_push(message="before the weight edit")
    obj.vertex_groups["ramp"].add([0], 0.9, 'REPLACE')
    shown = evaluated(obj)
    out["weight_edit"] = [status(obj)["stale"], bool(np.array_equal(shown, mix_key_muted_shape(obj)))]
    bpy.ops.ed.undo_push(message="weight edit")
    bpy.ops.ed.undo()
    obj = bpy.data.objects["Bar"]
    kbs = obj.data.shape_keys.key_blocks
    out["weight_undone"] = [status(obj)["stale"], float(np.abs(evaluated(obj) - live_shape).max())]
    # Weight Paint: no weights read while painting, one read once the painting pauses (a group no key uses: still
    # live; a mixed key's group: stale) and one on leaving the mode (the weights painted back: live)
    reads, read = [], live_mix.vertex_masks
    live_mix.vertex_masks = lambda *a: (reads.append(1), read(*a))[1]
    try:
        select_only(obj)
        with ops_context(obj):
            bpy.ops.object.mode_set(mode='WEIGHT_PAINT')
        skin = obj.vertex_groups.new(name="skin")
        for i in range(3):
            skin.add([i], 0.5, 'REPLACE')
            evaluated(obj)
        paint = [len(reads)]
        time.sleep(live_mix.PAINT_SETTLE)
        live_mix.settle_painting()
        shown = evaluated(obj)
        paint.append([len(reads), status(obj)["stale"], float(np.abs(shown - live_shape).max())])
        ramp = obj.vertex_groups["ramp"]
        for i in range(3):
            ramp.add([i], 0.9, 'REPLACE')
            evaluated(obj)
        paint.append([len(reads), status(obj)["stale"]])
        time.sleep(live_mix.PAINT_SETTLE)
        live_mix.settle_painting()
        shown = evaluated(obj)
        paint.append([len(reads), status(obj)["stale"], bool(np.array_equal(shown, mix_key_muted_shape(obj)))])
        for i in range(3):
            ramp.add([i], float(INPUTS["group_weights"][i]), 'REPLACE')
            evaluated(obj)
        with ops_context(obj):
            bpy.ops.object.mode_set(mode='OBJECT')
        shown = evaluated(obj)
        paint.append([len(reads), status(obj)["stale"], float(np.abs(shown - live_shape).max())])
        obj.vertex_groups.remove(skin)
    finally:
        live_mix.vertex_masks = read
    out["weight_paint"] = paint
    # a key's relative key, a key's vertex group, the group renamed: stale; set back: live
    changes = []
    for what, change, back in (
            ("relative", lambda: setattr(kbs["OnBend"], "relative_key", kbs["Basis"]),
             lambda: setattr(kbs["OnBend"], "relative_key", kbs["Bend"])),
            ("group", lambda: setattr(kbs["Masked"], "vertex_group", ""),
             lambda: setattr(kbs["Masked"], "vertex_group", "ramp")),
            ("renamed", lambda: setattr(obj.vertex_groups["ramp"], "name", "ramp2"),
             lambda: setattr(obj.vertex_groups["ramp2"], "name", "ramp"))):
        change()
        shown = evaluated(obj)
        changes.append([what, status(obj)["stale"], bool(np.array_equal(shown, mix_key_muted_shape(obj)))])
        back()
        shown = evaluated(obj)
        changes[-1] += [status(obj)["stale"], float(np.abs(shown - live_shape).max())]
    out["changes"] = changes
    # saved and reopened: live; Disable: the linear mix bit for bit
    path = os.path.join(ARGS.workdir, "rig.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    set_values(obj, VG_WEIGHTS[2], VG_NAMES)
    OUT["vg_reopened"] = evaluated(obj)
    out["reopened"] = status(obj)["stale"]
    assert disable(obj) == ["FINISHED"]
    after = []
    for w in VG_WEIGHTS:
        set_values(obj, w, VG_NAMES)
        after.append(evaluated(obj))
    out["disable_bit_for_bit"] = all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))
    out["disabled_vs_linear"] = all(np.array_equal(a, b) for a, b in zip(linear, after, strict=True))
    return out


def weight_paint_while_stale():
    """Weight Paint on a mesh whose mixer is stale for another reason (a key edited): the weights read once the
    painting pauses leave no painting pending, so the pause timer does not tag the keys again and again."""
    live_mix = ext("live_mix")
    reset()
    obj = make_bar(grouped=True)
    assert enable(obj) == ["FINISHED"]
    kb = obj.data.shape_keys.key_blocks["Bend"]
    kb.value = 0.5
    evaluated(obj)
    select_only(obj)
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='WEIGHT_PAINT')
    obj.vertex_groups["end"].add([0], 0.5, 'REPLACE')  # a dab
    evaluated(obj)
    co = np.empty(3 * len(kb.points), np.float32)  # and a key edited (a script): stale
    kb.points.foreach_get("co", co)
    co[0] += 0.25
    kb.points.foreach_set("co", co)
    obj.data.shape_keys.update_tag()
    evaluated(obj)
    out = {"stale": status(obj)["stale"]}
    live = live_mix._LIVE[obj.data.name_full]
    pending = [live.painted_at is not None]
    settled = []
    for _ in range(3):  # the timer's rounds: each a pause, the timer, the update its tag causes
        time.sleep(live_mix.PAINT_SETTLE)
        settled.append(live_mix.settle_painting())
        evaluated(obj)
        pending.append(live.painted_at is not None)
    out["pending"], out["settled"] = pending, settled
    with ops_context(obj):
        bpy.ops.object.mode_set(mode='OBJECT')
    return out


def posing_reads_no_weights():
    """Posing a rig that deforms a live mesh (Armature modifier) or moving the mesh's object changes no mesh data: the
    vertex-group weights are not read at those updates; a weight edited still is (once, and the mixer is stale)."""
    live_mix = ext("live_mix")
    reset()
    obj = make_bar(grouped=True)
    assert enable(obj) == ["FINISHED"]
    rig = add_rig(obj, "Armature")
    obj.data.shape_keys.key_blocks["Bend"].value = 0.5
    evaluated(obj)
    reads, read = [], live_mix.vertex_masks
    live_mix.vertex_masks = lambda *a: (reads.append(1), read(*a))[1]
    try:
        pose = rig.pose.bones["Bone"]
        pose.rotation_mode = 'XYZ'
        counts = []
        for change in (lambda i: setattr(pose, "rotation_euler", (0.0, 0.0, 0.1 * i)),
                       lambda i: setattr(obj, "location", (0.0, 0.0, 0.1 * i)),
                       lambda i: setattr(rig, "location", (0.0, 0.1 * i, 0.0))):
            before = len(reads)
            for i in (1, 2, 3):
                change(i)
                evaluated(obj)
            counts.append(len(reads) - before)
        stale = status(obj)["stale"]
        before = len(reads)
        obj.vertex_groups["end"].add([0], 0.5, 'REPLACE')
        evaluated(obj)
        edited = [len(reads) - before, status(obj)["stale"]]
    finally:
        live_mix.vertex_masks = read
    return {"reads": counts, "stale": stale, "edited": edited}


def weight_paint_shared_mesh():
    """Weight Paint through a linked duplicate (Alt+D: the same mesh) while the object the mixer was built on stays in
    Object Mode: the dabs are not read either, only once the painting pauses."""
    live_mix = ext("live_mix")
    reset()
    obj = make_bar(grouped=True)
    assert enable(obj) == ["FINISHED"]
    obj.data.shape_keys.key_blocks["Grouped"].value = 0.5
    evaluated(obj)
    twin = obj.copy()  # (the same mesh)
    bpy.context.scene.collection.objects.link(twin)
    select_only(twin)
    with ops_context(twin):
        bpy.ops.object.mode_set(mode='WEIGHT_PAINT')
    evaluated(twin)
    time.sleep(live_mix.PAINT_SETTLE)
    live_mix.settle_painting()
    evaluated(twin)
    reads, read = [], live_mix.vertex_masks
    live_mix.vertex_masks = lambda *a: (reads.append(1), read(*a))[1]
    try:
        for i in range(3):
            twin.vertex_groups["end"].add([i], 0.9, 'REPLACE')  # dabs
            evaluated(twin)
        painting = [len(reads), status(obj)["stale"]]
        time.sleep(live_mix.PAINT_SETTLE)
        live_mix.settle_painting()
        evaluated(twin)
        settled = [len(reads), status(obj)["stale"]]
    finally:
        live_mix.vertex_masks = read
    with ops_context(twin):
        bpy.ops.object.mode_set(mode='OBJECT')
    return {"owner": [obj.mode, twin.mode, twin.data == obj.data], "painting": painting, "settled": settled}


def exports():
    """Keyframed values exported to Alembic and to USD without shape keys: both write the evaluated mesh per frame,
    so the files hold the live mix (read back: the shapes Blender showed at those frames)."""
    reset()
    obj = make_bar()
    assert enable(obj) == ["FINISHED"]
    keyframe_values(obj)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 11
    shown = {}
    for f in FRAMES:
        scene.frame_set(f)
        shown[f] = evaluated(obj)
    scene.frame_set(1)
    paths = {"alembic": os.path.join(ARGS.workdir, "live.abc"), "usd": os.path.join(ARGS.workdir, "live.usdc")}
    assert bpy.ops.wm.alembic_export(filepath=paths["alembic"], start=1, end=11) == {"FINISHED"}
    assert bpy.ops.wm.usd_export(filepath=paths["usd"], export_animation=True, export_shapekeys=False) == {"FINISHED"}
    out = {}
    for kind, path in paths.items():
        before = set(bpy.data.objects)
        read_op = bpy.ops.wm.alembic_import if kind == "alembic" else bpy.ops.wm.usd_import
        assert read_op(filepath=path) == {"FINISHED"}
        read = [o for o in bpy.data.objects if o not in before and o.type == 'MESH']
        errors = []
        for f in FRAMES:
            scene.frame_set(f)
            errors.append(float(np.abs(evaluated(read[0]) - shown[f]).max()))
        out[kind] = {"objects": len(read), "errors": errors}
        for o in read:
            bpy.data.objects.remove(o)
    out["moved"] = float(np.abs(shown[FRAMES[-1]] - shown[FRAMES[0]]).max())
    # FBX and glTF write the shape keys as blend shapes / morph targets, the mix key among them (glTF not in bpy 4.2:
    # as a module it crashes at exit after a glTF export)
    import addon_utils
    modules = ("io_scene_fbx", "io_scene_gltf2") if bpy.app.version >= (5, 2, 0) else ("io_scene_fbx",)
    for module in modules:
        addon_utils.enable(module, default_set=False)
    fbx, gltf = os.path.join(ARGS.workdir, "live.fbx"), os.path.join(ARGS.workdir, "live.gltf")
    try:
        assert bpy.ops.export_scene.fbx(filepath=fbx) == {"FINISHED"}
        if "io_scene_gltf2" in modules:
            assert bpy.ops.export_scene.gltf(filepath=gltf, export_format='GLTF_SEPARATE') == {"FINISHED"}
    finally:  # (bpy 4.2 as a module crashes at exit while an add-on's panel is registered)
        for module in modules:
            addon_utils.disable(module, default_set=False)
    with open(fbx, "rb") as fh:
        data = fh.read()
    text = None
    if os.path.exists(gltf):
        with open(gltf) as fh:
            text = fh.read()
    out["keys_written"] = {name: [name.encode() in data, None if text is None else f'"{name}"' in text]
                           for name in [*NAMES, "LA live mix"]}
    out["blender"] = list(bpy.app.version[:2])
    return out


def finish():
    np.savez(os.path.join(ARGS.workdir, "live_mix.npz"), **OUT)


run_cases([install_and_enable, enable_mix_disable, keyframes_drivers_and_save, reload_still_live, mixer_text_deleted,
           stale_when_edited, out_of_range_and_vertex_groups, several_objects_and_undo, appended_and_deleted,
           edit_mode_round_trip, artist_edits, linked_from_library, library_override, library_override_driven,
           new_shape_from_mix, mix_key_name, bad_input, modal_run_and_cancel, inbetweens_and_bake_with_mixer,
           vertex_groups_and_relative_keys, many_keys_kept_linear, kept_linear_renamed, weight_paint_while_stale,
           posing_reads_no_weights, weight_paint_shared_mesh, exports, renders, finish])
