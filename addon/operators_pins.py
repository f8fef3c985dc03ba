# SPDX-License-Identifier: GPL-3.0-or-later
"""Pins and placement of a character for Calibrate & Fit on takes without standard marker names (glue only).

Calibrate & Fit places the character over a take by the standard marker-set names it knows (a humanoid).
Any other character (a creature, a custom marker set) is placed by the user, in one of two ways:

* *as placed*: the character is moved, rotated and scaled over the markers at the take's first frame; its
  transform is the placement (the object's :data:`PLACEMENT_PROP`, shown in the panel:
  ``'AUTO'`` -- marker names if the take has them, else the pins if there are 3 or more, else as placed --
  or ``'PLACED'``);
* *pins*: markers pinned to vertices (``lengths_angles.pin_marker`` in Edit Mode: the selected marker empty, or
  a typed label, to the selected vertex), stored on the object as ``{label: vertex}`` in the ID property
  :data:`PINS_PROP`, listed in the panel with a remove button each (``lengths_angles.remove_pin``).
"""

import bpy
import numpy as np
from bpy.props import EnumProperty, IntProperty, StringProperty

from .mesh_access import MeshAccessError, require_kept, require_mesh_object
from .operators_markers import MARKER_PROP

__all__ = ["PINS_PROP", "PLACEMENT_PROP", "PLACEMENT_ITEMS", "pins_of", "selected_vertex", "classes",
           "register_properties", "unregister_properties"]

PINS_PROP = "lengths_angles_pins"
PLACEMENT_PROP = "lengths_angles_placement"
#: Items of the Placement option (stable identifiers: scripts and saved files use them).
PLACEMENT_ITEMS = (
    ('AUTO', "Automatic", "Standard marker names place the character; without them the pins (3 or more), else the "
                          "character as placed over the markers"),
    ('PLACED', "As Placed", "The character as it stands over the markers at the take's first frame (move, rotate "
                            "and scale it there)"),
)


class PinError(Exception):
    """A pin that cannot be made (one line, for the report)."""


def pins_of(obj):
    """``{label: vertex}`` pinned on ``obj`` (empty if none)."""
    pins = obj.get(PINS_PROP)
    return {} if pins is None else {str(k): int(v) for k, v in pins.items()}


def selected_vertex(obj):
    """The one selected vertex of ``obj``'s mesh (Edit Mode selection included); PinError otherwise."""
    mesh = require_mesh_object(obj)
    if obj.mode == 'EDIT':
        obj.update_from_editmode()
    sel = np.zeros(len(mesh.vertices), bool)
    mesh.vertices.foreach_get("select", sel)
    idx = np.flatnonzero(sel)
    if len(idx) != 1:
        raise PinError(f"select one vertex of '{obj.name}' in Edit Mode to pin the marker to ({len(idx)} "
                       "selected)")
    return int(idx[0])


def _scene_labels(context):
    return {str(o[MARKER_PROP]) for o in context.scene.objects if MARKER_PROP in o}


def _marker_label(context, label):
    """The label to pin: ``label`` if given (a marker of a take in the scene), else the one selected marker empty."""
    if label:
        if label not in _scene_labels(context):
            raise PinError(f"no take in the scene has a marker '{label}': type a marker's name (as in the "
                           "Outliner) or select its empty")
        return label
    chosen = [o for o in (context.selected_objects or []) if MARKER_PROP in o]
    if len(chosen) != 1:
        raise PinError(f"select one marker empty and the character (active) before entering Edit Mode, or give "
                       f"the marker's label ({len(chosen)} marker empties selected)")
    return str(chosen[0][MARKER_PROP])


class LENGTHS_ANGLES_OT_pin_marker(bpy.types.Operator):
    """Pin a marker to the selected vertex of the character (Calibrate & Fit places characters without
    standard marker names by 3 or more pins)"""
    bl_idname = "lengths_angles.pin_marker"
    bl_label = "Pin Marker"
    bl_description = ("Pin the selected marker empty (or the marker named by Label) to the selected vertex: "
                      "Calibrate & Fit places the character by 3 or more pins")
    bl_options = {'REGISTER', 'UNDO'}

    label: StringProperty(name="Label", default="",
                          description="Marker to pin (empty: the selected marker empty)")
    vertex: IntProperty(name="Vertex", default=-1, min=-1,
                        description="Vertex index to pin to (-1: the selected vertex)")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type == 'MESH'

    def execute(self, context):
        obj = context.active_object
        try:
            require_kept([obj], "pin the markers")  # the pins are stored on the object
            label = _marker_label(context, self.label.strip())
            vertex = selected_vertex(obj) if self.vertex < 0 else int(self.vertex)
            if vertex >= len(obj.data.vertices):
                raise PinError(f"'{obj.name}' has {len(obj.data.vertices)} vertices, no vertex {vertex}")
        except (PinError, MeshAccessError) as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        pins = pins_of(obj)
        pins[label] = vertex
        obj[PINS_PROP] = pins
        self.report({'INFO'}, f"Pinned marker '{label}' to vertex {vertex} of '{obj.name}' ({len(pins)} pins)")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_remove_pin(bpy.types.Operator):
    """Remove a marker's pin from the character"""
    bl_idname = "lengths_angles.remove_pin"
    bl_label = "Remove Pin"
    bl_description = "Remove this marker's pin from the character"
    bl_options = {'REGISTER', 'UNDO', 'INTERNAL'}

    label: StringProperty(name="Label", default="", description="Marker whose pin to remove")

    def execute(self, context):
        obj = context.object
        pins = pins_of(obj) if obj is not None else {}
        if self.label not in pins:
            self.report({'ERROR'}, f"'{obj.name if obj else None}' has no pin for marker '{self.label}'")
            return {'CANCELLED'}
        try:
            require_kept([obj], "remove the pin")
        except MeshAccessError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        del pins[self.label]
        if pins:
            obj[PINS_PROP] = pins
        else:
            del obj[PINS_PROP]
        return {'FINISHED'}


def draw_pins(layout, obj):
    """The Placement option and the pins with a remove button each (in the Model and Markers panel)."""
    layout.prop(obj, PLACEMENT_PROP, text="Placement")
    pins = pins_of(obj)
    col = layout.column(align=True)
    row = col.row()
    row.label(text=f"Pins: {len(pins)}" if pins else "Pins: none (Edit Mode: Pin Marker)", icon='PINNED')
    row.operator(LENGTHS_ANGLES_OT_pin_marker.bl_idname, text="", icon='ADD')
    for label, vertex in sorted(pins.items()):
        row = col.row()
        row.label(text=f"{label} -> vertex {vertex}")
        row.operator(LENGTHS_ANGLES_OT_remove_pin.bl_idname, text="", icon='X').label = label


def register_properties():
    setattr(bpy.types.Object, PLACEMENT_PROP, EnumProperty(
        name="Placement", items=PLACEMENT_ITEMS, default='AUTO', override={'LIBRARY_OVERRIDABLE'},
        description="How Calibrate & Fit places the character over the take"))


def unregister_properties():
    delattr(bpy.types.Object, PLACEMENT_PROP)


classes = (LENGTHS_ANGLES_OT_pin_marker, LENGTHS_ANGLES_OT_remove_pin)
