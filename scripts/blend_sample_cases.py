# SPDX-License-Identifier: GPL-3.0-or-later
"""Reproducible test cases made with Blender's own tools (used by `make samples`, the tests, the demo,
the comparison figure and the benchmark).

* :func:`make_box_bar` -- a closed box bar along x whose six sides are regular quad grids
  (a "subdivided cube", built from explicit coordinates, no operator defaults involved);
* :func:`add_simple_deform_key` -- Blender's Simple Deform modifier (BEND, TWIST, ...)
  applied as a new shape key (``object.modifier_apply_as_shapekey``);
* :func:`bent_bar` / :func:`twisted_bar` -- the bar with a straight ``Basis`` and a
  Simple Deform key;
* :func:`shared_mesh_pair` -- two shared meshes in correspondence (e.g. finger0/finger1)
  as one object with ``Basis`` + a second key;
* :func:`build_sample_files` -- everything above, one compressed ``.blend`` per case.

Needs ``bpy`` (Blender or the ``bpy`` module).  All objects are linked into the
current scene, made active and returned.
"""

import math
import os
import sys

import bpy
import numpy as np

from blender_samples import add_shape_key, make_object

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _rigid_module():
    """lacore.geometry.rigid: the installed extension's copy inside the Blender checks (whose bpy-only interpreters
    have no SciPy for the repository's ``lacore`` package), else the repository's."""
    import importlib

    try:
        return importlib.import_module("bl_ext.user_default.lengths_angles.lacore.geometry.rigid")
    except ImportError:
        if REPO not in sys.path:
            sys.path.insert(0, REPO)
        return importlib.import_module("lacore.geometry.rigid")


def rigid_align(source, target):
    """``source`` moved rigidly onto ``target`` (:func:`lacore.geometry.rigid.rigid_align`)."""
    return _rigid_module().rigid_align(source, target)

__all__ = ["make_box_bar", "add_simple_deform_key", "simple_deform_coords", "bent_bar", "twisted_bar",
           "shared_mesh_pair", "key_coords", "build_sample_files", "SAMPLE_FILES"]


# ----------------------------------------------------------------------------- geometry
def box_bar_surface(length=8.0, width=1.0, segments=(64, 4, 4)):
    """Vertices and outward quads of the surface of the box ``[-L/2, L/2] x [-w/2, w/2]^2``.

    ``segments = (nx, ny, nz)`` grid cells along x, y, z; every side is a regular grid.
    Returns ``(V, 3)`` float64 vertices and a list of quads (vertex index 4-tuples).
    """
    nx, ny, nz = (int(s) for s in segments)
    if min(nx, ny, nz) < 1:
        raise ValueError(f"segments must be positive, got {segments}")
    shape = (nx + 1, ny + 1, nz + 1)
    i, j, k = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    on_surface = (i == 0) | (i == nx) | (j == 0) | (j == ny) | (k == 0) | (k == nz)
    index = np.full(shape, -1, np.int64)
    index[on_surface] = np.arange(int(on_surface.sum()))
    steps = np.array([length / nx, width / ny, width / nz])
    lower = np.array([-length / 2, -width / 2, -width / 2])
    verts = np.stack([i[on_surface], j[on_surface], k[on_surface]], axis=1) * steps + lower

    quads = []
    for axis in range(3):
        a, b = [d for d in range(3) if d != axis]
        for side, outward in ((0, -1.0), (shape[axis] - 1, 1.0)):
            sl = [slice(None)] * 3
            sl[axis] = side
            grid = index[tuple(sl)]  # 2-d, axes (a, b)
            q = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], axis=-1).reshape(-1, 4)
            # (a, b, axis) right-handed <=> the loop a -> b is counter-clockwise seen from +axis
            right_handed = (b - a) % 3 == 1
            if right_handed != (outward > 0):
                q = q[:, ::-1]
            quads.extend(map(tuple, q.tolist()))
    return verts, quads


def make_box_bar(name="Bar", length=8.0, width=1.0, segments=(64, 4, 4), collection=None):
    """A box bar object (quads only) along x, centred at the origin, with a ``Basis`` shape key."""
    verts, quads = box_bar_surface(length, width, segments)
    obj = make_object(name, verts, quads, collection=collection)
    add_shape_key(obj, "Basis")
    return obj


def key_coords(obj, name):
    """``(V, 3)`` float64 coordinates of the shape key ``name``."""
    kb = obj.data.shape_keys.key_blocks[name]
    co = np.empty(3 * len(kb.points), np.float32)
    kb.points.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def add_simple_deform_key(obj, key_name, method="BEND", angle=math.pi, axis="Z", keep=True):
    """Apply a Simple Deform modifier (``method`` 'BEND'/'TWIST'/'TAPER'/'STRETCH', ``angle`` in
    radians or the factor for TAPER/STRETCH, ``deform_axis`` ``axis``) to the basis of ``obj``
    as a new shape key ``key_name`` (value 0).

    The modifier deforms about the object's origin, like in the UI.  With ``keep=False`` the
    key is removed again and only its coordinates are returned (``(V, 3)`` float64).
    """
    mesh = obj.data
    if mesh.shape_keys is None:
        add_shape_key(obj, "Basis")
    mod = obj.modifiers.new("LA_SimpleDeform", 'SIMPLE_DEFORM')
    mod.deform_method = method
    mod.deform_axis = axis
    if method in ('BEND', 'TWIST'):
        mod.angle = angle
    else:
        mod.factor = angle
    before = {kb.name for kb in mesh.shape_keys.key_blocks}
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj],
                                   selected_editable_objects=[obj]):
        result = bpy.ops.object.modifier_apply_as_shapekey(modifier=mod.name, keep_modifier=False)
    if result != {'FINISHED'}:
        raise RuntimeError(f"modifier_apply_as_shapekey returned {result}")
    (new,) = [kb for kb in mesh.shape_keys.key_blocks if kb.name not in before]
    new.name = key_name
    new.value = 0.0
    coords = key_coords(obj, new.name)
    if not keep:
        obj.shape_key_remove(new)
    return coords


def simple_deform_coords(obj, method="BEND", angle=math.pi, axis="Z"):
    """Coordinates of the basis of ``obj`` deformed by Simple Deform; ``obj`` is not changed.

    Works on a temporary object with the same polygons and the basis coordinates but no
    shape keys (so neither the object's key values nor its animation enter the result).
    """
    src = obj.data
    basis = key_coords(obj, src.shape_keys.reference_key.name) if src.shape_keys is not None else None
    if basis is None:
        basis = np.empty(3 * len(src.vertices), np.float32)
        src.vertices.foreach_get("co", basis)
    n_loops, n_polys = len(src.loops), len(src.polygons)
    loop_vert = np.empty(n_loops, np.int32)
    loop_start = np.empty(n_polys, np.int32)
    loop_total = np.empty(n_polys, np.int32)
    src.loops.foreach_get("vertex_index", loop_vert)
    src.polygons.foreach_get("loop_start", loop_start)
    src.polygons.foreach_get("loop_total", loop_total)
    mesh = bpy.data.meshes.new(obj.name + "_simple_deform_tmp")
    mesh.vertices.add(len(src.vertices))
    mesh.vertices.foreach_set("co", np.asarray(basis, np.float32).ravel())
    mesh.loops.add(n_loops)
    mesh.loops.foreach_set("vertex_index", loop_vert)
    mesh.polygons.add(n_polys)
    mesh.polygons.foreach_set("loop_start", loop_start)
    mesh.polygons.foreach_set("loop_total", loop_total)
    mesh.update(calc_edges=True)
    tmp = bpy.data.objects.new(mesh.name, mesh)
    bpy.context.scene.collection.objects.link(tmp)
    tmp.matrix_world = obj.matrix_world
    try:
        return add_simple_deform_key(tmp, "SimpleDeform", method=method, angle=angle, axis=axis, keep=False)
    finally:
        bpy.data.objects.remove(tmp)
        bpy.data.meshes.remove(mesh)  # also frees its Key datablock


def bent_bar(name="BarBend", angle_deg=180.0, segments=(64, 4, 4), length=8.0, width=1.0, key_name=None,
             reference_deg=None):
    """The box bar with ``Basis`` (straight) and a key bent by Simple Deform BEND about z.

    ``key_name`` defaults to ``"Bend<angle>"``; with ``reference_deg`` a second key
    ``"SimpleDeform<ref>"`` holds Blender's own bend by that angle (a reference for in-betweens).
    """
    obj = make_box_bar(name, length=length, width=width, segments=segments)
    add_simple_deform_key(obj, key_name or f"Bend{angle_deg:g}", method="BEND", angle=math.radians(angle_deg))
    if reference_deg is not None:
        add_simple_deform_key(obj, f"SimpleDeform{reference_deg:g}", method="BEND",
                              angle=math.radians(reference_deg))
    return obj


def twisted_bar(name="BarTwist", angle_deg=180.0, segments=(64, 4, 4), length=8.0, width=1.0):
    """The box bar with ``Basis`` (straight) and ``Twist<angle>``: Simple Deform TWIST about x."""
    obj = make_box_bar(name, length=length, width=width, segments=segments)
    add_simple_deform_key(obj, f"Twist{angle_deg:g}", method="TWIST", angle=math.radians(angle_deg), axis="X")
    return obj


def shared_mesh_pair(name, basis_path, key_path, key_name, load_mesh):
    """One object from two meshes in correspondence: ``Basis`` = ``basis_path``, ``key_name`` = ``key_path``.

    ``load_mesh`` is :func:`lacore.io.meshes.load_mesh` (keeps the vertex order).
    """
    V0, F0 = load_mesh(basis_path)
    V1, F1 = load_mesh(key_path)
    if V0.shape != V1.shape or not np.array_equal(F0, F1):
        raise ValueError(f"{basis_path} and {key_path} are not in correspondence")
    obj = make_object(name, V0, F0.tolist())
    add_shape_key(obj, "Basis")
    add_shape_key(obj, key_name, V1)
    return obj


# ----------------------------------------------------------------------------- sample files
#: file name -> (description, builder(meshes_dir, load_mesh) -> object)
SAMPLE_FILES = {
    "bar_bend.blend": ("box bar 8 x 1 x 1 (1058 vertices, quads): Basis straight, Bend180 = Simple Deform BEND "
                       "180 degrees about z, SimpleDeform90 = Blender's 90-degree bend (reference for t = 0.5)",
                       lambda meshes, load: bent_bar("BarBend", 180.0, reference_deg=90.0)),
    "bar_twist.blend": ("box bar 8 x 1 x 1 (1058 vertices, quads): Basis straight, Twist180 = Simple Deform "
                        "TWIST 180 degrees about x",
                        lambda meshes, load: twisted_bar("BarTwist", 180.0)),
    "finger.blend": ("shared finger pair (2046 vertices, triangles): Basis = finger0, Finger1 = finger1",
                     lambda meshes, load: shared_mesh_pair("Finger", os.path.join(meshes, "finger", "finger0.ply"),
                                                           os.path.join(meshes, "finger", "finger1.ply"),
                                                           "Finger1", load)),
    "plate_rolled.blend": ("shared rolled plates (121 vertices, triangles): Basis = plate121_rolledA, "
                           "RolledB = plate121_rolledB",
                           lambda meshes, load: shared_mesh_pair(
                               "Plate121", os.path.join(meshes, "plate", "plate121_rolledA.ply"),
                               os.path.join(meshes, "plate", "plate121_rolledB.ply"), "RolledB", load)),
    "plate4SD_rolled.blend": ("shared rolled plates (1089 vertices, triangles): Basis = plate4SD_rolledA, "
                              "RolledB = plate4SD_rolledB",
                              lambda meshes, load: shared_mesh_pair(
                                  "Plate4SD", os.path.join(meshes, "plate", "plate4SD_rolledA.ply"),
                                  os.path.join(meshes, "plate", "plate4SD_rolledB.ply"), "RolledB", load)),
}


def build_sample_files(out_dir, meshes_dir, load_mesh, names=None):
    """Write one compressed .blend per entry of :data:`SAMPLE_FILES` into ``out_dir``.

    Returns ``{file name: {"path", "bytes", "object", "vertices", "polygons", "keys", "description"}}``.
    """
    os.makedirs(out_dir, exist_ok=True)
    written = {}
    for fname, (description, build) in SAMPLE_FILES.items():
        if names and fname not in names:
            continue
        bpy.ops.wm.read_homefile(use_empty=True)
        obj = build(meshes_dir, load_mesh)
        obj.data["lengths_angles_sample"] = description
        path = os.path.join(out_dir, fname)
        bpy.ops.wm.save_as_mainfile(filepath=path, compress=True, copy=False)
        written[fname] = {"path": path, "bytes": os.path.getsize(path), "object": obj.name,
                          "vertices": len(obj.data.vertices), "polygons": len(obj.data.polygons),
                          "keys": [kb.name for kb in obj.data.shape_keys.key_blocks], "description": description}
    bpy.ops.wm.read_homefile(use_empty=True)
    return written


# ----------------------------------------------------------------------------- comparison numbers
def mesh_edges(obj):
    """``(E, 2)`` vertex indices of Blender's edges of ``obj``."""
    e = np.empty(2 * len(obj.data.edges), np.int32)
    obj.data.edges.foreach_get("vertices", e)
    return e.reshape(-1, 2).astype(np.int64)


def blend_metrics(X, reference, straight, edges):
    """How well ``X`` reproduces ``reference`` (up to a rigid motion) and how it changes edge lengths.

    ``rms_error_per_diagonal``: RMS vertex distance after a rigid (Kabsch) fit to ``reference``
    over the bounding-box diagonal of ``reference``; ``max_edge_change_vs_straight``:
    ``max |l / l_straight - 1|``; ``max_edge_error_vs_reference``: ``max |l / l_reference - 1|``.
    """
    diag = float(np.linalg.norm(reference.max(0) - reference.min(0)))
    Y = rigid_align(X, reference)
    rms = float(np.sqrt(np.mean(np.sum((Y - reference) ** 2, axis=1))))

    def lengths(P):
        return np.linalg.norm(P[edges[:, 0]] - P[edges[:, 1]], axis=1)

    l, l0, lr = lengths(X), lengths(straight), lengths(reference)
    return {"rms_error": rms, "rms_error_per_diagonal": rms / diag,
            "max_error_per_diagonal": float(np.linalg.norm(Y - reference, axis=1).max() / diag),
            "max_edge_change_vs_straight": float(np.max(np.abs(l / l0 - 1.0))),
            "max_edge_error_vs_reference": float(np.max(np.abs(l / lr - 1.0)))}
