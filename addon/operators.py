# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators of the Lengths & Angles add-on (glue: Blender data <-> lacore)."""

import time

import bpy
import numpy as np

from ..lacore.errors import InputError, MeshError
from ..lacore.integrability import integrability_violation
from ..lacore.lengths_angles import check_nondegenerate, lengths_and_angles
from ..lacore.topology import MeshTopology, check_vertices
from . import mesh_access, storage

__all__ = ["LENGTHS_ANGLES_OT_encode", "encode_object", "classes"]


def encode_object(obj):
    """Compute the encoding of every shape key of ``obj`` WITHOUT touching Blender data.

    Returns a dict with the arguments of :func:`storage.write_encoding` plus
    ``topology``.  Raises :class:`mesh_access.MeshAccessError` or
    :class:`lacore.errors.MeshError` (both :class:`lacore.errors.InputError`) for unusable input.
    """
    mesh = mesh_access.require_mesh_object(obj)
    names, coords = mesh_access.read_shape_keys(mesh)
    tri = mesh_access.triangulate(mesh)
    try:
        topology = MeshTopology.from_faces(tri.faces, edges=tri.edges, n_vertices=tri.n_vertices)
    except MeshError as exc:
        raise MeshError(f"Mesh '{mesh.name}' cannot be encoded: {exc}") from exc
    E = topology.n_edges
    z = np.empty((len(names), 2 * E), np.float64)
    violations = np.empty(len(names), np.float64)
    for k, name in enumerate(names):
        try:
            X = check_vertices(coords[k], topology.n_vertices, name=f"shape key '{name}'")
            check_nondegenerate(X, topology)
            z[k] = lengths_and_angles(X, topology)
            v = integrability_violation(z[k], topology)
        except MeshError as exc:
            raise MeshError(f"Shape key '{name}': {exc}") from exc
        violations[k] = float(np.max(v)) if len(v) else 0.0
    return {
        "faces": topology.faces,
        "edges": topology.edges,
        "n_mesh_edges": tri.n_mesh_edges,
        "names": names,
        "z": z,
        "violations": violations,
        "topology": topology,
    }


class LENGTHS_ANGLES_OT_encode(bpy.types.Operator):
    """Encode every shape key of the active mesh as edge lengths and dihedral angles,
    stored in the mesh data (saved with the .blend)"""

    bl_idname = "lengths_angles.encode"
    bl_label = "Encode Shape Keys"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        # Deliberately permissive: execute() explains what is wrong instead of a greyed-out button.
        return True

    def execute(self, context):
        obj = context.active_object
        start = time.perf_counter()
        try:
            if obj is not None and obj.type == 'MESH' and obj.mode == 'EDIT':
                obj.update_from_editmode()  # make edit-mode changes visible in the mesh data
            result = encode_object(obj)  # computes everything; nothing is written yet
        except InputError as exc:  # MeshAccessError, MeshError, LengthsAnglesError; anything else is a bug
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        mesh = obj.data
        storage.write_encoding(mesh, faces=result["faces"], edges=result["edges"],
                               n_mesh_edges=result["n_mesh_edges"], names=result["names"], z=result["z"],
                               violations=result["violations"])
        n = len(result["names"])
        worst = float(result["violations"].max())
        self.report({'INFO'}, f"Encoded {n} shape key{'s' if n != 1 else ''} of '{obj.name}' "
                              f"({result['topology'].n_edges} edges, max integrability violation {worst:.3g}, "
                              f"{time.perf_counter() - start:.2f} s)")
        return {'FINISHED'}


classes = (LENGTHS_ANGLES_OT_encode,)
