# SPDX-License-Identifier: GPL-3.0-or-later
"""UI: a sub-panel of Properties > Object Data > Shape Keys."""

import bpy

from . import storage
from .operators import LENGTHS_ANGLES_OT_encode
from .operators_interpolate import (BAKE_PROP, LENGTHS_ANGLES_OT_bake_keyframes, LENGTHS_ANGLES_OT_clear_bake,
                                    LENGTHS_ANGLES_OT_interpolate)

__all__ = ["LENGTHS_ANGLES_PT_shape_keys", "LENGTHS_ANGLES_PT_mocap", "classes"]


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
        draw_inbetweens(context, layout, mesh)
        col = layout.column(align=True)
        header = col.row()
        header.label(text="Shape key")
        header.label(text="Integrability violation")
        for name, encoded, violation in rows:
            row = col.row()
            row.label(text=name, icon='CHECKMARK' if encoded else 'X')
            row.label(text=f"{violation:.3g}" if encoded else "not encoded")


def draw_inbetweens(context, layout, mesh):
    """Interpolate from the reference key to the active key (options in the redo panel) and bake."""
    key = mesh.shape_keys
    obj = context.object
    col = layout.column(align=True)
    ref = key.reference_key.name if key.reference_key is not None else ""
    active = obj.active_shape_key.name if obj.active_shape_key is not None else ""
    row = col.row(align=True)
    if active and active != ref:
        op = row.operator(LENGTHS_ANGLES_OT_interpolate.bl_idname, text=f"In-betweens {ref} > {active}",
                          icon='IPO_EASE_IN_OUT')
        op.key_from = ref
        op.key_to = active
    else:
        row.enabled = False
        row.operator(LENGTHS_ANGLES_OT_interpolate.bl_idname, text="In-betweens: select a target key",
                     icon='IPO_EASE_IN_OUT')
    row = col.row(align=True)
    row.operator(LENGTHS_ANGLES_OT_bake_keyframes.bl_idname, text="Bake Keyframes...", icon='KEYFRAME_HLT')
    if BAKE_PROP in mesh:
        row.operator(LENGTHS_ANGLES_OT_clear_bake.bl_idname, text="", icon='X')


class LENGTHS_ANGLES_PT_mocap(bpy.types.Panel):
    """Shape model (one slider per mode), marker binding (marker, offset, warning) and fit."""
    bl_label = "Lengths & Angles: Model and Markers"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "data"
    bl_parent_id = "DATA_PT_shape_keys"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == 'MESH'

    def draw(self, context):
        from . import operators_fit as fit
        layout = self.layout
        obj = context.object
        layout.operator(fit.LENGTHS_ANGLES_OT_build_model.bl_idname, icon='MOD_DATA_TRANSFER')
        meta = obj.data.get(fit.MODEL_PROP)
        if meta is None:
            layout.label(text="No shape model", icon='INFO')
            return
        col = layout.column(align=True)
        col.label(text=f"Model: {len(meta['keys'])} keys, {meta['n_modes']} modes (sliders in std. dev.)")
        for j in range(min(int(meta["n_modes"]), fit.MAX_MODES)):
            col.prop(obj, "lengths_angles_mode_weights", index=j, text=f"Mode {j + 1}", slider=True)
        col.operator(fit.LENGTHS_ANGLES_OT_model_pose_to_shape_key.bl_idname, icon='SHAPEKEY_DATA')
        layout.operator(fit.LENGTHS_ANGLES_OT_bind_markers.bl_idname, icon='EMPTY_DATA')
        binding = obj.get(fit.BINDING_PROP)
        if binding is not None:
            box = layout.box()
            box.label(text=f"Take '{binding['take']}' bound at frame {binding['frame']}")
            for label, face, offset in zip(binding["labels"], binding["faces"], binding["offsets"], strict=True):
                row = box.row()
                row.label(text=label, icon='ERROR' if abs(offset) > 0.05 else 'CHECKMARK')
                row.label(text=f"triangle {face}")
                row.label(text=f"{offset:.4f}")
            layout.operator(fit.LENGTHS_ANGLES_OT_fit_markers.bl_idname, icon='ARMATURE_DATA')


classes = (LENGTHS_ANGLES_PT_shape_keys, LENGTHS_ANGLES_PT_mocap)
