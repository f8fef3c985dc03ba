# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators of the Lengths & Angles add-on (glue: Blender data <-> lacore): Encode, Remove Data, Integrability."""

import time

import bpy
import numpy as np
from bpy.props import StringProperty

from ..lacore.errors import InputError, MeshError
from ..lacore.integrability import check_integrability
from . import bake, live_mix, session, storage
from .mesh_access import object_mode, require_kept, require_mesh_object, require_writable_keys
from .fit_quality import remove_quality
from .operators_fit import BINDING_PROP, remove_model
from .operators_calibrate import remove_calibration

__all__ = ["LENGTHS_ANGLES_OT_encode", "LENGTHS_ANGLES_OT_remove_data", "LENGTHS_ANGLES_OT_integrability_info",
           "encode_object", "remove_data", "classes"]


def encode_object(obj):
    """Compute the encoding of every shape key of ``obj`` WITHOUT touching Blender data.

    Returns a dict with the arguments of :func:`storage.write_encoding` plus
    ``topology``.  Raises :class:`mesh_access.MeshAccessError` or
    :class:`lacore.errors.MeshError` (both :class:`lacore.errors.InputError`) for unusable input.
    The lengths and angles come from (and go into) the session cache (:mod:`.session`), so
    Encode after In-betweens, or In-betweens after Encode, does not compute them twice.
    """
    data = session.read_mesh(obj, "encoded")
    topology = data.topology
    z = np.empty((len(data.names), 2 * topology.n_edges), np.float64)
    violations = np.empty(len(data.names), np.float64)
    integrability = []
    for k, name in enumerate(data.names):
        z[k] = session.key_z(data, name)
        try:
            check = check_integrability(z[k], topology)  # all of Theorem 3.2: vertices, holes, handles
        except InputError as exc:
            raise MeshError(f"Shape key '{name}': {exc}") from exc
        violations[k] = check.max_local
        integrability.append((check.integrable, check.describe(), check.where()))
    return {
        "faces": topology.faces,
        "edges": topology.edges,
        "n_mesh_edges": len(data.mesh.edges),
        "names": data.names,
        "z": z,
        "violations": violations,
        "integrability": integrability,
        "topology": topology,
        "coords_hashes": data.key_hashes,
        "topology_hash": data.topology_hash,
    }


def remove_data(obj):
    """Remove everything the extension stored for ``obj``: the encoding, the bake (its keys and keyframes,
    by identity), the shape model (with its preview key and slider values), the marker binding, the stored
    calibration, the last fit's quality (summary and per-frame RMS curve), the live mixer (with its key:
    Blender's linear mixing again) and the session cache.  Results you asked for (in-between keys, fitted keys
    or point caches) stay.  Returns a short description of what was removed."""
    mesh = obj.data
    removed = []
    if storage.PROP in mesh:
        storage.clear_encoding(mesh)
        removed.append("encoding")
    if bake.has_bake(obj):
        n = bake.remove_bake(obj)
        removed.append(f"bake ({n} keys)")
    if remove_model(obj):
        removed.append("shape model")
    if BINDING_PROP in obj:
        del obj[BINDING_PROP]
        removed.append("marker binding")
    if remove_calibration(mesh):
        removed.append("calibration")
    if remove_quality(obj):
        removed.append("fit quality")
    if live_mix.disable(obj):
        removed.append("live mixer")
    session.clear()
    return ", ".join(removed) if removed else "nothing stored"


class LENGTHS_ANGLES_OT_encode(bpy.types.Operator):
    """Encode every shape key of the active mesh as edge lengths and dihedral angles,
    stored in the mesh data (saved with the .blend)"""

    bl_idname = "lengths_angles.encode"
    bl_label = "Encode Shape Keys"
    bl_description = ("Encode every shape key as edge lengths and dihedral angles, stored in the mesh (saved with "
                      "the .blend) and reused by In-betweens and Bake")
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        # Deliberately permissive: execute() explains what is wrong instead of a greyed-out button.
        return True

    def execute(self, context):
        obj = context.object
        start = time.perf_counter()
        try:
            require_kept([require_mesh_object(obj)], "encode the shape keys")  # the encoding is stored on the mesh
            result = encode_object(obj)  # computes everything; nothing is written yet
        except InputError as exc:  # MeshAccessError, MeshError, LengthsAnglesError; anything else is a bug
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        mesh = obj.data
        storage.write_encoding(mesh, faces=result["faces"], edges=result["edges"],
                               n_mesh_edges=result["n_mesh_edges"], names=result["names"], z=result["z"],
                               violations=result["violations"], coords_hashes=result["coords_hashes"],
                               topology_hash=result["topology_hash"], integrability=result["integrability"])
        n = len(result["names"])
        worst = float(result["violations"].max())
        failing = [(name, where) for name, (ok, _, where) in zip(result["names"], result["integrability"], strict=True)
                   if not ok]
        verdict = ("integrable" if not failing else
                   f"NOT integrable: '{failing[0][0]}' {failing[0][1]}" + (f" and {len(failing) - 1} more keys"
                                                                          if len(failing) > 1 else ""))
        self.report({'INFO'}, f"Encoded {n} shape key{'s' if n != 1 else ''} of '{obj.name}' "
                              f"({result['topology'].n_edges} edges, {verdict}: max vertex violation {worst:.3g}, "
                              f"{time.perf_counter() - start:.2f} s)")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_remove_data(bpy.types.Operator):
    """Remove everything Lengths & Angles stored on the mesh"""

    bl_idname = "lengths_angles.remove_data"
    bl_label = "Remove Lengths & Angles Data"
    bl_description = ("Remove everything Lengths & Angles stored on this mesh: the encoding, the bake (its keys "
                      "and keyframes), the shape model, the marker binding, the live mixer and the cached "
                      "computations (in-between keys and fitted results stay)")
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return True  # execute() explains what is wrong instead of a greyed-out button

    def execute(self, context):
        obj = context.object
        try:
            require_writable_keys(require_mesh_object(obj), "remove the Lengths & Angles data")
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        with object_mode(obj):  # removing shape keys in Edit Mode would be undone on leaving it
            removed = remove_data(obj)
            obj.data.update()
        self.report({'INFO'}, f"Removed from '{obj.name}': {removed}")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_integrability_info(bpy.types.Operator):
    """Integrability of an encoded shape key"""

    bl_idname = "lengths_angles.integrability_info"
    bl_label = "Integrability"
    bl_description = "Whether the stored lengths and angles describe a shape"
    bl_options = {'INTERNAL'}

    detail: StringProperty(options={'HIDDEN', 'SKIP_SAVE'})

    @classmethod
    def description(cls, context, properties):
        return properties.detail or cls.bl_description

    def execute(self, context):
        self.report({'INFO'}, self.detail)
        return {'FINISHED'}


classes = (LENGTHS_ANGLES_OT_encode, LENGTHS_ANGLES_OT_remove_data, LENGTHS_ANGLES_OT_integrability_info)
