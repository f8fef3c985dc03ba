"""Blender-side checks of the installed extension (run in a SUBPROCESS by tests/test_blender_extension.py).

bpy can be imported only once per process and the extension directory comes from
BLENDER_USER_RESOURCES, which must be set before ``import bpy``; hence this script.

usage: BLENDER_USER_RESOURCES=<tmp> python check_extension.py --zip EXT.zip --workdir DIR --result OUT.json

Installs the zip with ``extensions.package_install_files``, enables it, runs the
cases below and writes ``{"ok": true, "cases": {...}}`` to OUT.json.  Any failed
check raises (non-zero exit code, traceback on stderr).
"""

import json
import math
import os
import sys
from types import SimpleNamespace

# harness first: it checks the environment and imports bpy
from harness import ARGS, MODULE, bpy, draw_panel, plain, reset, run_cases
import numpy as np
import blender_samples as samples


def ext():
    """The installed extension package and its sub-modules."""
    import importlib

    pkg = importlib.import_module(MODULE)
    return SimpleNamespace(
        pkg=pkg,
        mesh_access=importlib.import_module(MODULE + ".addon.mesh_access"),
        storage=importlib.import_module(MODULE + ".addon.storage"),
        panels=importlib.import_module(MODULE + ".addon.panels"),
        topology=importlib.import_module(MODULE + ".lacore.geometry.topology"),
        lengths_angles=importlib.import_module(MODULE + ".lacore.geometry.lengths_angles"),
        integrability=importlib.import_module(MODULE + ".lacore.integrability.local"),
        sparse_cholesky=importlib.import_module(MODULE + ".lacore.linalg.sparse_cholesky"),
    )


def encode(obj):
    """Run the operator on ``obj`` (None: no active object) like a user would."""
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj] if obj else []):
        return bpy.ops.lengths_angles.encode()


def expected_encoding(obj):
    """What lacore computes for the object's keys (independently of the operator)."""
    e = ext()
    names, coords = e.mesh_access.read_shape_keys(obj.data)
    tri = e.mesh_access.triangulate(obj.data)
    topo = e.topology.MeshTopology.from_faces(tri.faces, edges=tri.edges, n_vertices=tri.n_vertices)
    z = {n: e.lengths_angles.lengths_and_angles(coords[k], topo) for k, n in enumerate(names)}
    viol = {n: float(np.max(e.integrability.integrability_violation(z[n], topo))) for n in names}
    return topo, tri, z, viol


def snapshot(obj):
    """Everything the operator could change: ID properties of mesh and object, shape-key data."""
    mesh = obj.data
    keys = []
    if mesh.shape_keys is not None:
        for kb in mesh.shape_keys.key_blocks:
            co = np.empty(3 * len(kb.points), np.float32)
            kb.points.foreach_get("co", co)
            keys.append((kb.name, co.tolist()))
    return json.dumps({
        "mesh_props": {k: plain(mesh[k]) for k in mesh.keys()},
        "object_props": {k: plain(obj[k]) for k in obj.keys()},
        "keys": keys,
        "n": [len(mesh.vertices), len(mesh.edges), len(mesh.polygons)],
    }, sort_keys=True)


def expect_error(obj, *fragments):
    try:
        encode(obj)
    except RuntimeError as exc:
        msg = str(exc)
        for frag in fragments:
            assert frag.lower() in msg.lower(), f"expected {frag!r} in error message {msg!r}"
        return msg
    raise AssertionError("the operator did not report an error")


# ----------------------------------------------------------------------------- cases
def install_and_enable():
    result = bpy.ops.extensions.package_install_files(filepath=ARGS.zip, repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    import addon_utils

    _loaded_default, loaded_state = addon_utils.check(MODULE)
    assert loaded_state, f"{MODULE} is not enabled after install"
    assert MODULE in bpy.context.preferences.addons, list(bpy.context.preferences.addons.keys())
    assert bpy.ops.lengths_angles.encode.idname() == "LENGTHS_ANGLES_OT_encode"
    assert hasattr(bpy.types, "LENGTHS_ANGLES_PT_shape_keys")
    panel = bpy.types.LENGTHS_ANGLES_PT_shape_keys
    assert panel.bl_parent_id == "DATA_PT_shape_keys" and panel.bl_context == "data"
    root = os.path.join(os.environ["BLENDER_USER_RESOURCES"], "extensions")
    python = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    site = os.path.join(root, ".local", "lib", python, "site-packages")
    bundled = sorted(os.listdir(site)) if os.path.isdir(site) else []
    assert any(n.startswith("scipy") for n in bundled) and any(n.startswith("trimesh") for n in bundled), bundled
    import numpy
    import scipy

    assert scipy.__file__.startswith(site), (scipy.__file__, site)  # the bundled SciPy, not another one
    return {"bundled_site_packages": site, "extension_dir": os.path.join(root, "user_default", "lengths_angles"),
            "bundled": [n for n in bundled if n.endswith(".dist-info")], "python": python,
            "blender": bpy.app.version_string, "numpy": numpy.__version__, "scipy": scipy.__version__,
            "sparse_cholesky": ext().sparse_cholesky.default_backend(),
            "metis": ext().sparse_cholesky.metis_nested_dissection(_path_graph(4)) is not None,
            "installer_matches_python_tags": installer_matches_python_tags()}


def _path_graph(n):
    """Adjacency of the path 0 - 1 - ... - n-1 (a tiny graph to order)."""
    import scipy.sparse as sp

    off = np.ones(n - 1)
    return sp.diags([off, off], [-1, 1], format="csr")


def installer_matches_python_tags():
    """Whether this Blender's extension installer skips wheels of other Pythons (4.2.13+; not 4.2.0)."""
    import importlib

    for name in ("bl_pkg", "addons_core.bl_pkg", "bl_ext.system.bl_pkg"):
        try:
            ops = importlib.import_module(name + ".bl_extension_ops")
        except ImportError:
            continue
        return hasattr(ops, "_extensions_wheel_filter_for_this_system")
    raise AssertionError("Blender's bl_pkg add-on was not found")


def cube_values():
    """Real numbers: a cube of edge 2 (quads) -> lengths 2 and 2 sqrt 2, angles pi/2 and 0."""
    reset()
    obj = samples.make_cube("Cube", size=2.0)
    mesh = obj.data
    assert encode(obj) == {"FINISHED"}
    stored = ext().storage.read_encoding(mesh)
    assert stored is not None and stored["format_version"] == 1
    assert list(stored["keys"]) == ["Basis", "Scaled", "Rigid"], list(stored["keys"])
    E, n_mesh_edges = len(stored["edges"]), stored["n_mesh_edges"]
    assert (E, n_mesh_edges, len(stored["faces"])) == (18, 12, 12), (E, n_mesh_edges, len(stored["faces"]))
    # the first 12 edges are Blender's edges, in Blender's order (orientation may be swapped)
    blender_edges = np.empty(2 * len(mesh.edges), np.int32)
    mesh.edges.foreach_get("vertices", blender_edges)
    assert np.array_equal(np.sort(stored["edges"][:12], 1), np.sort(blender_edges.reshape(-1, 2), 1))
    for name, scale in (("Basis", 1.0), ("Scaled", 1.5), ("Rigid", 1.0)):
        z = stored["keys"][name]["z"]
        lengths, angles = z[:E], z[E:]
        np.testing.assert_allclose(lengths[:12], 2.0 * scale, rtol=1e-6)
        np.testing.assert_allclose(lengths[12:], 2.0 * math.sqrt(2.0) * scale, rtol=1e-6)
        np.testing.assert_allclose(angles[:12], math.pi / 2, atol=1e-6)  # convex edges (outward normals)
        np.testing.assert_allclose(angles[12:], 0.0, atol=1e-6)  # flat diagonals
        assert stored["keys"][name]["max_integrability_violation"] < 1e-6
    # identical to what lacore computes directly
    topo, _tri, z, viol = expected_encoding(obj)
    np.testing.assert_array_equal(stored["faces"], topo.faces)
    np.testing.assert_array_equal(stored["edges"], topo.edges)
    for name in z:
        np.testing.assert_array_equal(stored["keys"][name]["z"], z[name])
        assert stored["keys"][name]["max_integrability_violation"] == viol[name]
    # the panel's rows
    rows = ext().storage.key_status(mesh)
    assert [r[:2] for r in rows] == [("Basis", True), ("Scaled", True), ("Rigid", True)], rows
    return {"lengths_basis": sorted(set(np.round(stored["keys"]["Basis"]["z"][:E], 9).tolist()))}


def bar_and_grid_save_reload():
    """Quads, bending/twisting keys, a disk-topology grid; data survives save + reload."""
    reset()
    objs = samples.build_demo_scene()
    expected = {}
    for obj in objs:
        assert encode(obj) == {"FINISHED"}
        topo, _tri, z, _viol = expected_encoding(obj)
        stored = ext().storage.read_encoding(obj.data)
        np.testing.assert_array_equal(stored["edges"], topo.edges)
        for name in z:
            np.testing.assert_array_equal(stored["keys"][name]["z"], z[name])
        E = topo.n_edges
        assert np.all(stored["keys"]["Basis"]["z"][E:][topo.is_boundary_edge] == 0.0)
        if "Rigid" in z:  # a rigid motion keeps lengths and angles
            np.testing.assert_allclose(z["Rigid"], z["Basis"], rtol=1e-5, atol=1e-5)
        expected[obj.name] = stored
    grid = bpy.data.objects["Grid"].data
    assert ext().storage.read_encoding(grid)["keys"]["Wave"]["max_integrability_violation"] < 1e-5

    path = os.path.join(ARGS.workdir, "encoded.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    reset()
    assert "Bar" not in bpy.data.objects
    bpy.ops.wm.open_mainfile(filepath=path)
    for name, before in expected.items():
        after = ext().storage.read_encoding(bpy.data.objects[name].data)
        assert after is not None, f"{name}: encoding lost on reload"
        np.testing.assert_array_equal(after["faces"], before["faces"])
        np.testing.assert_array_equal(after["edges"], before["edges"])
        assert list(after["keys"]) == list(before["keys"])
        for key in before["keys"]:
            np.testing.assert_array_equal(after["keys"][key]["z"], before["keys"][key]["z"])
            assert after["keys"][key]["z"].dtype == np.float64
            assert after["keys"][key]["max_integrability_violation"] == \
                before["keys"][key]["max_integrability_violation"]
    return {"blend": path, "objects": sorted(expected)}


def panel_draw():
    """Draw the panel into a recording layout (no GUI in background mode)."""
    reset()
    obj = samples.make_cube("Cube")
    panel = bpy.types.LENGTHS_ANGLES_PT_shape_keys
    ctx = SimpleNamespace(object=obj)
    assert panel.poll(ctx)
    calls = draw_panel(panel, ctx)
    texts = [kw.get("text") for name, _, kw in calls if name == "label"]
    assert texts.count("not encoded") == 3, texts
    assert any(name == "operator" and args[0] == "lengths_angles.encode" for name, args, _ in calls), calls
    encode(obj)
    calls = draw_panel(panel, ctx)
    texts = [kw.get("text") for name, _, kw in calls if name == "label"]
    assert "not encoded" not in texts and "Scaled" in texts, texts
    # "integrable" per key, the number only in the tooltip (the info operator's description)
    verdicts = [kw.get("text") for name, args, kw in calls
                if name == "operator" and args[0] == "lengths_angles.integrability_info"]
    assert verdicts == ["integrable"] * 3, verdicts
    assert not any("e-" in (t or "") for t in texts), texts
    return {"labels": texts, "verdicts": verdicts}


def edit_mode_and_key_io():
    """Edits made in Edit Mode are encoded; shape keys round-trip through read/write_shape_key."""
    import bmesh

    reset()
    obj = samples.make_cube("Cube")
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='EDIT')
    bm = bmesh.from_edit_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    bm.verts[7].co.x += 1.0  # vertex (1, 1, 1) of the active key (Basis) -> (2, 1, 1)
    bmesh.update_edit_mesh(obj.data)
    assert encode(obj) == {"FINISHED"}
    assert obj.mode == 'EDIT'
    stored = ext().storage.read_encoding(obj.data)
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='OBJECT')
    E = len(stored["edges"])
    at7 = np.flatnonzero((stored["edges"] == 7).any(1))
    lengths = stored["keys"]["Basis"]["z"][:E]
    assert np.all(lengths[at7] > 2.0 + 1e-6), lengths[at7]  # edges at the moved vertex got longer
    _, _, z, _ = expected_encoding(obj)
    np.testing.assert_array_equal(stored["keys"]["Basis"]["z"], z["Basis"])

    access = ext().mesh_access
    _names, coords = access.read_shape_keys(obj.data)
    assert coords.shape == (3, 8, 3) and coords.dtype == np.float64
    new = coords[1] * 0.5 + np.array([0.0, 0.0, 0.25])
    access.write_shape_key(obj.data, "Scaled", new)
    _, again = access.read_shape_keys(obj.data)
    np.testing.assert_array_equal(again[1], new.astype(np.float32))
    np.testing.assert_array_equal(again[0], coords[0])
    return {"edited_lengths": lengths[at7].round(6).tolist()}


def errors_change_nothing():
    """Every error is reported (RuntimeError in background mode) and leaves the data untouched."""
    messages = {}
    reset()
    messages["no_active_object"] = expect_error(None, "no active object")

    empty = bpy.data.objects.new("Empty", None)
    bpy.context.scene.collection.objects.link(empty)
    messages["not_a_mesh"] = expect_error(empty, "not a mesh")

    reset()
    plain = samples.make_object("Plain", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)])
    before = snapshot(plain)
    messages["no_shape_keys"] = expect_error(plain, "no shape keys")
    assert snapshot(plain) == before

    # non-manifold: three quads sharing the edge (0, 1); keep an old valid encoding to see it survive
    reset()
    obj = samples.make_cube("Cube")
    assert encode(obj) == {"FINISHED"}
    obj["user_prop"] = 7
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    v0, v1 = bm.verts[0], bm.verts[1]
    extra = [bm.verts.new((x, -3.0, z)) for x, z in ((-1.0, -1.0), (-1.0, 1.0))]
    bm.faces.new([v0, v1, extra[1], extra[0]])  # third face at cube edge (0, 1)
    bm.to_mesh(obj.data)
    bm.free()
    obj.data.update()
    before = snapshot(obj)
    messages["non_manifold"] = expect_error(obj, "non-manifold")
    assert snapshot(obj) == before, "the failed operator changed the object"

    # loose edge (added with bmesh, which keeps the shape keys consistent)
    reset()
    obj = samples.make_cube("Cube")
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    v0 = bm.verts[0]
    bm.edges.new([v0, bm.verts.new((5.0, 5.0, 5.0))])
    bm.to_mesh(obj.data)
    bm.free()
    obj.data.update()
    before = snapshot(obj)
    messages["loose_edge"] = expect_error(obj, "loose edge")
    assert snapshot(obj) == before

    # a shape key collapsing the cube to a point: degenerate triangles
    reset()
    obj = samples.make_cube("Cube")
    samples.add_shape_key(obj, "Collapsed", np.zeros((8, 3)))
    before = snapshot(obj)
    messages["degenerate_key"] = expect_error(obj, "mesh 'Cube': shape key 'Collapsed' has faces of no area",
                                              "(Blender face indices)")
    assert snapshot(obj) == before
    return {"messages": messages}


def main():
    run_cases((install_and_enable, cube_values, bar_and_grid_save_reload, panel_draw, edit_mode_and_key_io,
               errors_change_nothing))


if __name__ == "__main__":
    main()
