# SPDX-License-Identifier: GPL-3.0-or-later
"""UI: a sub-panel of Properties > Object Data > Shape Keys."""

import bpy

from . import storage
from .operators import LENGTHS_ANGLES_OT_encode

__all__ = ["LENGTHS_ANGLES_PT_shape_keys", "classes"]


class LENGTHS_ANGLES_PT_shape_keys(bpy.types.Panel):
    bl_label = "Lengths & Angles"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "data"
    # Shown inside the Shape Keys panel, i.e. right where the keys are listed.
    bl_parent_id = "DATA_PT_shape_keys"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == 'MESH'

    def draw(self, context):
        layout = self.layout
        mesh = context.object.data
        layout.operator(LENGTHS_ANGLES_OT_encode.bl_idname, icon='MOD_EDGESPLIT')
        rows = storage.key_status(mesh)
        if not rows:
            layout.label(text="No shape keys to encode", icon='INFO')
            return
        col = layout.column(align=True)
        header = col.row()
        header.label(text="Shape key")
        header.label(text="Integrability violation")
        for name, encoded, violation in rows:
            row = col.row()
            row.label(text=name, icon='CHECKMARK' if encoded else 'X')
            row.label(text=f"{violation:.3g}" if encoded else "not encoded")


classes = (LENGTHS_ANGLES_PT_shape_keys,)
