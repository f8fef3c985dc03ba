# SPDX-License-Identifier: GPL-3.0-or-later
"""UI: a sub-panel of Properties > Object Data > Shape Keys, and entries in the Shape Keys specials menu.

Panel and operators act on ``context.object`` (which follows a pinned Properties editor).
"""

import bpy

from ..lacore.shapes import MixerOptions
from . import live_mix, storage
from . import fit_quality
from . import operators_fit as fit
from . import operators_live_mix as live_ops
from .bake import BAKE_PROP
from .naming import LIVE_MIX_KEY, is_own_key
from .operators import LENGTHS_ANGLES_OT_encode, LENGTHS_ANGLES_OT_integrability_info, LENGTHS_ANGLES_OT_remove_data
from .operators_calibrate import LENGTHS_ANGLES_OT_calibrate_fit
from .operators_pins import draw_pins
from .operators_interpolate import (LENGTHS_ANGLES_OT_bake_keyframes, LENGTHS_ANGLES_OT_clear_bake,
                                    LENGTHS_ANGLES_OT_interpolate)

__all__ = ["LENGTHS_ANGLES_PT_shape_keys", "LENGTHS_ANGLES_PT_live_mix", "LENGTHS_ANGLES_PT_mocap", "classes",
           "draw_shape_key_menu", "integrability_text"]


def integrability_text(violation, integrability=None):
    """``("integrable" | "not integrable", tooltip)`` for an encoded key.

    With the stored verdict of lacore (``integrability``: ``integrable``, ``integrability``, ``integrability_where``,
    see :func:`storage.key_status`) "integrable" means all of Theorem 3.2 and the tooltip says which part fails
    (at a vertex, around a hole, around a handle); without it (older encodings) the vertices' largest violation.
    """
    integrable = None if integrability is None else integrability.get("integrable")
    verdict = "integrable" if storage.is_integrable(violation, integrable) else "not integrable"
    shape = "describe a shape" if verdict == "integrable" else "describe no shape exactly"
    if integrable is None:
        return verdict, (f"Largest per-vertex integrability violation |tr I - 3| = {violation:.3g} (integrable up to "
                         f"{storage.INTEGRABLE_TOLERANCE:g}): the stored lengths and angles {shape}; holes and "
                         "handles not checked (encode again)")
    text = integrability.get("integrability", "")
    where = integrability.get("integrability_where", "")
    head = "The stored lengths and angles " + shape + (f", they fail {where}" if where else "")
    return verdict, f"{head}. {text[:1].upper()}{text[1:]}"


class _ShapeKeysSubpanel:
    """Placement and poll shared by the add-on's panels: inside Properties > Object Data > Shape Keys,
    right where the keys are listed, for the (possibly pinned) mesh object of the editor."""

    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "data"
    bl_parent_id = "DATA_PT_shape_keys"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == 'MESH'


class LENGTHS_ANGLES_PT_shape_keys(_ShapeKeysSubpanel, bpy.types.Panel):
    bl_label = "Lengths & Angles"

    def draw(self, context):
        layout = self.layout
        mesh = context.object.data
        rows = storage.key_status(mesh)
        if not rows:
            layout.label(text="No shape keys: add a Basis and a target key", icon='INFO')
            return
        draw_inbetweens(context, layout, mesh)
        row = layout.row(align=True)
        row.operator(LENGTHS_ANGLES_OT_encode.bl_idname, icon='MOD_EDGESPLIT')
        row.operator(LENGTHS_ANGLES_OT_remove_data.bl_idname, text="", icon='TRASH')
        changed = storage.encoding_mismatch(mesh)
        if changed:
            layout.label(text=f"Mesh changed since encoding ({changed}): encode again", icon='ERROR')
        col = layout.column(align=True)
        for name, encoded, violation, integrability in rows:
            row = col.row()
            row.label(text=name, icon='CHECKMARK' if encoded else 'X')
            if not encoded:
                row.label(text="not encoded")
                continue
            verdict, tip = integrability_text(violation, integrability)
            op = row.operator(LENGTHS_ANGLES_OT_integrability_info.bl_idname, text=verdict, emboss=False,
                              icon='NONE' if verdict == "integrable" else 'ERROR')
            op.detail = tip


def draw_inbetweens(context, layout, mesh):
    """In-betweens (options dialog: From, To, Count ...) and Bake; Clear Bake when there is one."""
    col = layout.column(align=True)
    row = col.row(align=True)
    row.operator_context = 'INVOKE_DEFAULT'
    row.operator(LENGTHS_ANGLES_OT_interpolate.bl_idname, text="In-betweens...", icon='IPO_EASE_IN_OUT')
    row = col.row(align=True)
    row.operator_context = 'INVOKE_DEFAULT'
    row.operator(LENGTHS_ANGLES_OT_bake_keyframes.bl_idname, text="Bake In-betweens...", icon='KEYFRAME_HLT')
    if BAKE_PROP in mesh:
        row.operator(LENGTHS_ANGLES_OT_clear_bake.bl_idname, text="", icon='X')


def draw_shape_key_menu(self, context):
    """Entries in the Shape Keys specials menu (the menu next to the key list; also found by F3 search)."""
    self.layout.separator()
    layout = self.layout.column()  # its own operator context, not the menu's
    layout.operator_context = 'INVOKE_DEFAULT'
    layout.operator(LENGTHS_ANGLES_OT_interpolate.bl_idname, text="Lengths & Angles In-betweens...",
                    icon='IPO_EASE_IN_OUT')
    layout.operator(LENGTHS_ANGLES_OT_bake_keyframes.bl_idname, text="Bake Lengths & Angles In-betweens...",
                    icon='KEYFRAME_HLT')
    layout.operator(LENGTHS_ANGLES_OT_clear_bake.bl_idname, icon='X')
    layout.operator(LENGTHS_ANGLES_OT_encode.bl_idname, text="Encode Lengths & Angles", icon='MOD_EDGESPLIT')
    layout.operator(LENGTHS_ANGLES_OT_remove_data.bl_idname, icon='TRASH')


class LENGTHS_ANGLES_PT_mocap(_ShapeKeysSubpanel, bpy.types.Panel):
    """Shape model (one slider per mode), marker binding (marker, offset, warning) and fit."""
    bl_label = "Lengths & Angles: Model and Markers"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        draw_pins(layout, obj)
        row = layout.row()
        row.operator_context = 'INVOKE_DEFAULT'  # modal: progress bar and Esc
        row.operator(LENGTHS_ANGLES_OT_calibrate_fit.bl_idname, icon='ARMATURE_DATA')
        layout.operator(fit.LENGTHS_ANGLES_OT_build_model.bl_idname, icon='MOD_DATA_TRANSFER')
        meta = obj.data.get(fit.MODEL_PROP)
        if meta is None:
            layout.label(text="No shape model", icon='INFO')
            return
        col = layout.column(align=True)
        col.label(text=f"Model: {len(meta['keys'])} keys, {meta['n_modes']} modes (sliders in std. dev.)")
        for j in range(min(int(meta["n_modes"]), fit.MAX_MODES)):
            col.prop(obj, "lengths_angles_mode_weights", index=j, text=f"Mode {j + 1}", slider=True)
        problem = fit.PREVIEW_PROBLEMS.get(obj.name)
        if problem is not None:
            col.label(text=problem[0].upper() + problem[1:], icon='ERROR')
        col.operator(fit.LENGTHS_ANGLES_OT_model_pose_to_shape_key.bl_idname, icon='SHAPEKEY_DATA')
        layout.operator(fit.LENGTHS_ANGLES_OT_bind_markers.bl_idname, icon='EMPTY_DATA')
        binding = obj.get(fit.BINDING_PROP)
        if binding is not None:
            box = layout.box()
            box.label(text=f"Take '{binding['take']}' bound at frame {binding['frame']}")
            unit = float(binding.get("metres_per_unit", 1.0))
            warn = float(binding.get("warn_distance", 0.05))
            for label, where, offset in zip(binding["labels"], marker_places(binding), binding["offsets"],
                                            strict=True):
                row = box.split(factor=0.3)
                row.label(text=label, icon='ERROR' if abs(offset) * unit > warn else 'CHECKMARK')
                rest = row.split(factor=0.7)
                rest.label(text=where)
                rest.label(text=f"{1000 * offset * unit:.1f} mm")
            not_bound = list(binding.get("not_bound", []))
            reasons = list(binding.get("not_bound_reasons", ["occluded"] * len(not_bound)))  # (older bindings)
            for label, why in zip(not_bound, reasons, strict=True):
                box.row().label(text=f"{label}: not bound ({why})", icon='HIDE_ON')
            layout.operator(fit.LENGTHS_ANGLES_OT_fit_markers.bl_idname, icon='ARMATURE_DATA')
        draw_fit_quality(layout, obj)


def marker_places(binding):
    """Where each bound marker sits, as the Model panel lists it: ``"vertex 812 (LeftForeArm)"`` (a corner of its
    triangle and that vertex's dominant vertex group, :func:`.operators_fit.marker_locations`), or
    ``"triangle N"`` for bindings stored without them."""
    if "vertices" not in binding:
        return [f"triangle {face}" for face in binding["faces"]]
    return [f"vertex {v}" + (f" ({region})" if region else "")
            for v, region in zip(binding["vertices"], binding["regions"], strict=True)]


def draw_fit_quality(layout, obj):
    """The last fit's quality (stored by :func:`.fit_quality.write_quality`): marker RMS / p95 in mm, the
    prior weight and the other settings used, flagged frames and markers; the per-frame curve is the keyed property
    ``RMS_PROP``."""
    q = obj.get(fit_quality.FIT_PROP)
    if q is None:
        return
    box = layout.box()
    box.label(text=f"Fit of '{q['take']}' {q['frame_start']}-{q['frame_end']}: marker RMS {q['marker_rms_mm']:.1f} mm, "
                   f"p95 {q['marker_p95_mm']:.1f} mm", icon='CHECKMARK' if q.get("success", True) else 'ERROR')
    box.label(text=f"Prior weight {q['prior_weight']:g}; per-frame RMS: property '{fit_quality.RMS_PROP}' "
                   "(Graph Editor)")
    if "settings" in q:
        box.label(text=fit_quality.settings_text(q["settings"]))
    if "calibration_reused" in q:
        box.label(text="Calibration reused (take, model and placement unchanged)" if q["calibration_reused"] else
                  "Calibration stored: Calibrate & Fit again reuses it while take, model and placement are unchanged")
    frames, markers = list(q.get("flagged_frames", [])), list(q.get("flagged_markers", []))
    if frames or markers:
        box.label(text=f"Flagged frames: {', '.join(map(str, frames[:10]))}{' ...' if len(frames) > 10 else ''}",
                  icon='ERROR')
        box.label(text=f"Flagged markers: {', '.join(markers[:10])}{' ...' if len(markers) > 10 else ''}",
                  icon='ERROR')


class LENGTHS_ANGLES_PT_live_mix(_ShapeKeysSubpanel, bpy.types.Panel):
    """Live mixing: state (live, stale, out of range), build time, Rebuild, quality, Disable."""
    bl_label = "Lengths & Angles: Live Mixing"

    def draw(self, context):
        layout = self.layout
        mesh = context.object.data
        state = live_mix.status(mesh)
        row = layout.row(align=True)
        row.operator_context = 'INVOKE_DEFAULT'
        row.operator(live_ops.LENGTHS_ANGLES_OT_live_mix_enable.bl_idname,
                     text="Enable Live Mixing" if state is None else "Rebuild", icon='SHAPEKEY_DATA')
        if state is not None:
            row.operator(live_ops.LENGTHS_ANGLES_OT_live_mix_disable.bl_idname, text="", icon='X')
        layout.prop(mesh, live_ops.REDUCED_SIZE_PROP, text="Quality (reduced size, 0 = auto)")
        layout.prop(mesh, live_ops.MAX_KEYS_PROP, text=f"Most Keys (0 = {MixerOptions().max_keys})")
        layout.prop(mesh, live_mix.EXACT_RENDERS_PROP)
        active = context.object.active_shape_key
        if (mesh.shape_keys is not None and active is not None and active != mesh.shape_keys.reference_key
                and not is_own_key(active.name)):  # the active key's choice: mixed live or kept linear
            kept = active.name in live_mix.linear_choice(mesh)
            row = layout.row(align=True)
            row.label(text=f"'{active.name}': {'kept linear' if kept else 'mixed live'}")
            row.operator(live_ops.LENGTHS_ANGLES_OT_live_mix_keep_linear.bl_idname,
                         text="Mix Live" if kept else "Keep Linear").linear = not kept
        if state is None:
            layout.label(text="Blender mixes the keys linearly", icon='INFO')
            return
        col = layout.column(align=True)
        if state["stale"]:
            col.label(text=f"Stale: {state['stale']}", icon='ERROR')
            if state["override"]:  # an override's mixer is the library's (Rebuild is refused here)
                col.label(text=f"Showing Blender's linear mix: Rebuild in '{state['override']}'")
            elif not state["linked"]:  # a linked mesh's mix key is the library's (Rebuild is refused)
                col.label(text="Showing Blender's linear mix: Rebuild to mix live again")
        else:
            chosen = "" if state["reduced_size"] else " (auto)"
            col.label(text=f"Live: {len(state['keys'])} keys, reduced size {state['space_size']}{chosen}",
                      icon='CHECKMARK')
        exact = " (exact, a render's)" if state["polished"] else ""
        col.label(text=f"Built in {state['build_seconds']:.2f} s; last mix {1000 * state['mix_seconds']:.1f} ms{exact}")
        if not state["in_range"]:
            col.label(text=state["message"] or "weights outside the mixer's accurate range", icon='ERROR')
        if state["kept_linear_mixed"]:
            col.label(text="Rebuild to keep linear: " + ", ".join(state["kept_linear_mixed"]), icon='INFO')
        if state["linear"]:
            col.label(text="Mixed linearly: " + ", ".join(f"{name} ({why})"
                                                          for name, why in state["linear_reasons"].items()),
                      icon='INFO')
        active = context.object.active_shape_key
        if active is not None and active.name == LIVE_MIX_KEY:  # Edit Mode and the pin show the active key alone
            col.label(text=f"'{LIVE_MIX_KEY}' is the correction to the linear mix, not a shape: Edit Mode and "
                           "Shape Key Lock show it as one; select another key", icon='ERROR')


classes = (LENGTHS_ANGLES_PT_shape_keys, LENGTHS_ANGLES_PT_live_mix, LENGTHS_ANGLES_PT_mocap)
