"""Blender-side checks of addon/compat.py (the 4.2 .. 5.2 API shims) in the INSTALLED extension, and of the
.blend files the repository gives users (blend_samples/, `make demo`'s) opening in every supported Blender
(run in a SUBPROCESS by tests/test_blender_compat.py, once per tested Blender).

usage: BLENDER_USER_RESOURCES=<tmp> [LACORE_DEMO_OUTPUT=<dir>] python check_compat.py --zip EXT.zip --workdir DIR
       --result OUT.json
"""

import importlib
import os

# harness first: it checks the environment and imports bpy
from harness import ARGS, MODULE, bpy, reset, run_cases
import blender_samples as samples


def compat():
    return importlib.import_module(MODULE + ".addon.compat")


def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    c = compat()
    # the slotted-action path from 4.4 on, Action.fcurves before
    assert c.HAS_SLOTTED_ACTIONS == (bpy.app.version >= (4, 4, 0)), (c.HAS_SLOTTED_ACTIONS, bpy.app.version)
    return {"version": list(bpy.app.version), "slotted": c.HAS_SLOTTED_ACTIONS}


def object_fcurves():
    """id_fcurves on an Object: none before, created on demand (action named), keys evaluate, reused."""
    reset()
    c = compat()
    obj = samples.make_cube("Cube", size=2.0)
    assert c.id_fcurves(obj) is None and c.animation_channels(obj) is None
    fcurves = c.id_fcurves(obj, create=True, action_name="LA markers")
    assert obj.animation_data.action.name == "LA markers"
    for axis in range(3):
        fc = fcurves.new("location", index=axis)
        fc.keyframe_points.add(2)
        fc.keyframe_points.foreach_set("co", [1.0, 0.0, 11.0, 10.0 * (axis + 1)])
        fc.update()
    again = c.id_fcurves(obj, create=True)  # the existing action: no new one
    assert len(bpy.data.actions) == 1 and len(again) == 3
    values = [again.find("location", index=a).evaluate(6.0) for a in range(3)]
    assert all(abs(v - 5.0 * (a + 1)) < 1e-6 for a, v in enumerate(values)), values
    bpy.context.scene.frame_set(6)
    assert abs(obj.location.z - 15.0) < 1e-5, tuple(obj.location)  # the animation drives the object
    owner, created = c.ensure_animation_channels(obj, "unused")
    assert created == "" and len(owner.fcurves) == 3
    return {"values_at_6": values, "location_at_6": list(obj.location)}


def shape_key_fcurves_survive_reload():
    """On a Key datablock (what Bake uses): created action, curves found again after save/reload."""
    reset()
    c = compat()
    obj = samples.make_cube("Cube", size=2.0)  # keys Basis, Scaled, Rigid
    key = obj.data.shape_keys
    owner, created = c.ensure_animation_channels(key, "Cube LA bake")
    assert created == "Cube LA bake" and c.animation_channels(key) is not None
    fc = owner.fcurves.new('key_blocks["Scaled"].value')
    fc.keyframe_points.add(2)
    fc.keyframe_points.foreach_set("co", [1.0, 0.0, 5.0, 1.0])
    fc.update()
    path = os.path.join(ARGS.workdir, "compat.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    key = bpy.data.objects["Cube"].data.shape_keys
    fcurves = c.id_fcurves(key)
    assert [f.data_path for f in fcurves] == ['key_blocks["Scaled"].value']
    value = fcurves.find('key_blocks["Scaled"].value').evaluate(3.0)
    assert abs(value - 0.5) < 1e-6, value
    fcurves.remove(fcurves[0])
    assert len(c.id_fcurves(key)) == 0
    return {"value_at_3": value}


def sample_files_open():
    """Every blend_samples/*.blend (the README's "open one of them") opens in this Blender, and its meshes with
    shape keys encode."""
    from harness import REPO
    folder = os.path.join(REPO, "blend_samples")
    opened = {}
    for name in sorted(f for f in os.listdir(folder) if f.endswith(".blend")):
        bpy.ops.wm.open_mainfile(filepath=os.path.join(folder, name))
        meshes = [o for o in bpy.data.objects if o.type == "MESH" and o.data.shape_keys]
        assert meshes, name
        for obj in meshes:
            bpy.context.view_layer.objects.active = obj
            assert bpy.ops.lengths_angles.encode() == {"FINISHED"}, (name, obj.name)
        opened[name] = [o.name for o in meshes]
    reset()
    return {"opened": opened}


def demo_files_open():
    """The .blend files of `make demo` (its Blender steps, run into LACORE_DEMO_OUTPUT by the test) open in this
    Blender with what the demo stored: the encodings, the in-betweens and baked motion, a Mesh Cache modifier
    that plays its PC2 next to the file."""
    from harness import evaluated
    folder = os.environ["LACORE_DEMO_OUTPUT"]
    storage = importlib.import_module(MODULE + ".addon.storage")
    read_pc2 = importlib.import_module(MODULE + ".lacore.io.point_cache").read_pc2
    saved_in = {}

    def open_blend(name):
        bpy.ops.wm.open_mainfile(filepath=os.path.join(folder, name))  # RuntimeError if it cannot
        saved_in[name] = list(bpy.data.version)

    open_blend("demo_scene.blend")
    encoded = {name: sorted(storage.read_encoding(bpy.data.objects[name].data)["keys"])
               for name in ("Cube", "Bar", "Grid")}
    open_blend("bar_inbetweens.blend")
    keys = [k.name for k in bpy.data.objects["Bar"].data.shape_keys.key_blocks]
    open_blend("human_mocap_fit.blend")
    body, scene = bpy.data.objects["Body"], bpy.context.scene
    mod = body.modifiers["LA Fit"]
    cache, _, _ = read_pc2(bpy.path.abspath(mod.filepath))
    frame = scene.frame_start + len(cache) // 2
    scene.frame_set(frame)
    played = float(abs(evaluated(body) - cache[frame - scene.frame_start]).max())
    moved = float(abs(cache[frame - scene.frame_start] - cache[0]).max())
    modifier = mod.type  # (read before the next file frees it)
    # live mixing: the saved mixer reopens live and the keyframed sliders are mixed, not added linearly
    live_mix = importlib.import_module(MODULE + ".addon.live_mix")
    open_blend("human_live_mix.blend")
    body, scene = bpy.data.objects["Body"], bpy.context.scene
    scene.frame_set(32)
    blocks = body.data.shape_keys.key_blocks
    mixed, mix_key = evaluated(body), blocks[live_mix.LIVE_MIX_KEY]
    mix_key.mute = True  # Blender's linear mix (the mixer is stale while its key is muted)
    linear = evaluated(body)
    mix_key.mute = False
    unmuted = evaluated(body)
    live = {"status": live_mix.status(body.data)["stale"], "arm_value": blocks["ArmRaised"].value,
            "mixed_vs_linear": float(abs(mixed - linear).max()), "unmuted_again": float(abs(unmuted - mixed).max())}
    reset()
    return {"saved_in": saved_in, "encoded": encoded, "inbetweens": [k for k in keys if k.startswith("LA Basis>")],
            "baked_keys": len([k for k in keys if k.startswith("LA bake ")]), "modifier": modifier,
            "cache_frames": len(cache), "played_vs_cache": played, "cache_moved": moved, "live_mix": live}


def main():
    cases = [install_and_enable, object_fcurves, shape_key_fcurves_survive_reload, sample_files_open]
    if os.environ.get("LACORE_DEMO_OUTPUT"):
        cases.append(demo_files_open)
    run_cases(cases)


if __name__ == "__main__":
    main()
