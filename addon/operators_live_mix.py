# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators of live nonlinear mixing (glue: :mod:`.live_mix` does the work, lacore the mathematics).

``lengths_angles.live_mix_enable``
    Builds the mixer of the active mesh's keys (:class:`lacore.shapes.ShapeMixer`) through the one
    run mechanism (:mod:`.runs`: modal with progress and Esc from the UI, at once from scripts and in
    background mode) and makes the mesh show the lengths-and-angles mix of its keys' values.  On a
    mesh that already mixes live it rebuilds (the panel's Rebuild).  The quality is the mesh's
    ``lengths_angles_live_mix_reduced_size`` (0: automatic), the most keys it mixes the mesh's
    ``lengths_angles_live_mix_max_keys`` (0: :attr:`lacore.shapes.MixerOptions.max_keys`); with the mesh's
    ``lengths_angles_live_mix_exact_renders`` on, renders show the exact mix (:mod:`.live_mix`).
``lengths_angles.live_mix_disable``
    Back to Blender's linear mixing, exactly: the mix key and the stored mixer are removed.
``lengths_angles.live_mix_keep_linear``
    Keeps the active shape key in Blender's linear mix (``linear`` False: mixes it live again), from the next Enable
    or Rebuild on (:func:`.live_mix.set_linear_choice`): a mixer takes at most
    :attr:`lacore.shapes.MixerOptions.max_keys` keys.
"""

import bpy
from bpy.props import BoolProperty, IntProperty

from ..lacore.errors import InputError
from ..lacore.shapes import MixerOptions
from . import live_mix
from .mesh_access import object_mode
from .runs import RunOperator, error_text

__all__ = ["LENGTHS_ANGLES_OT_live_mix_enable", "LENGTHS_ANGLES_OT_live_mix_disable",
           "LENGTHS_ANGLES_OT_live_mix_keep_linear", "classes",
           "register_properties", "unregister_properties", "REDUCED_SIZE_PROP", "MAX_KEYS_PROP"]

REDUCED_SIZE_PROP = "lengths_angles_live_mix_reduced_size"
MAX_KEYS_PROP = "lengths_angles_live_mix_max_keys"


class LENGTHS_ANGLES_OT_live_mix_enable(RunOperator, bpy.types.Operator):
    """Mix the shape keys in lengths and angles live: the mesh follows its keys' sliders, drivers and
    keyframes with the nonlinear mix (builds the mixer; on a live mesh: rebuilds it)"""
    bl_idname = "lengths_angles.live_mix_enable"
    bl_label = "Live Mixing"
    bl_description = ("Mix the shape keys in lengths and angles live: the mesh follows its keys' sliders, drivers "
                      "and keyframes with the nonlinear mix (builds the mixer; on a live mesh, rebuilds it)")
    bl_options = {'REGISTER', 'UNDO'}

    def invoke(self, context, event):
        self.interactive = True
        return self.execute(context)

    def execute(self, context):
        def make(context):
            obj = context.active_object
            mesh = obj.data if obj is not None and obj.type == 'MESH' else None
            return live_mix.enable_run(obj, getattr(mesh, REDUCED_SIZE_PROP, 0), getattr(mesh, MAX_KEYS_PROP, 0))
        return self.start_run(context, make)


class LENGTHS_ANGLES_OT_live_mix_disable(bpy.types.Operator):
    """Stop live mixing: Blender mixes the shape keys linearly again (the mixer and its key are removed;
    your keys were never changed)"""
    bl_idname = "lengths_angles.live_mix_disable"
    bl_label = "Disable Live Mixing"
    bl_description = ("Stop live mixing: Blender mixes the shape keys linearly again (the mixer and its key are "
                      "removed; your keys were never changed)")
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        obj = context.active_object
        try:
            live_mix.require_live(obj)
        except InputError as exc:
            self.report({'ERROR'}, error_text(exc))
            return {'CANCELLED'}
        with object_mode(obj):  # a key removed in Edit Mode would come back on leaving it
            live_mix.disable(obj)
        self.report({'INFO'}, f"'{obj.name}': Blender's linear shape-key mixing again")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_live_mix_keep_linear(bpy.types.Operator):
    """Keep the active shape key in Blender's linear mix (small local shapes such as faces and correctives), or mix it
    live again; applies at the next Enable or Rebuild"""
    bl_idname = "lengths_angles.live_mix_keep_linear"
    bl_label = "Keep Linear"
    bl_description = ("Keep the active shape key in Blender's linear mix (small local shapes such as faces and "
                      "correctives), or mix it live again; applies at the next Enable or Rebuild")
    bl_options = {'REGISTER', 'UNDO'}

    linear: BoolProperty(name="Linear", default=True,
                         description="Keep the key linear (off: mix it live again)")

    def execute(self, context):
        try:
            message = live_mix.keep_linear(context.active_object, self.linear)
        except InputError as exc:
            self.report({'ERROR'}, error_text(exc))
            return {'CANCELLED'}
        self.report({'INFO'}, message)
        return {'FINISHED'}


classes = (LENGTHS_ANGLES_OT_live_mix_enable, LENGTHS_ANGLES_OT_live_mix_disable,
           LENGTHS_ANGLES_OT_live_mix_keep_linear)


def register_properties():
    setattr(bpy.types.Mesh, REDUCED_SIZE_PROP, IntProperty(
        name="Reduced Size", default=0, min=0, soft_max=200,
        description="Quality of live mixing: the size of the mixer's reduced space (0: chosen automatically); "
                    "larger follows the exact lengths-and-angles blend more closely and costs more per update. "
                    "Applies at the next Rebuild"))
    setattr(bpy.types.Mesh, MAX_KEYS_PROP, IntProperty(
        name="Most Keys", default=0, min=0, soft_max=12,
        description=f"Most shape keys mixed live (0: {MixerOptions().max_keys}); each further key takes about twice "
                    "the build time and memory (6 keys on a 13,000-vertex body: 44 s, 2.2 GB). Applies at the next "
                    "Rebuild"))
    setattr(bpy.types.Mesh, live_mix.EXACT_RENDERS_PROP, BoolProperty(
        name="Exact in Renders", default=False,
        description="Renders (F12, animation, command line) show the exact lengths-and-angles mix: each rendered "
                    "frame is finished by a full Gauss-Newton projection (about a second per frame at 13,000 "
                    "vertices, longer on larger meshes); the viewport stays real-time"))
    live_mix.register_handlers()


def unregister_properties():
    live_mix.unregister_handlers()
    delattr(bpy.types.Mesh, live_mix.EXACT_RENDERS_PROP)
    delattr(bpy.types.Mesh, MAX_KEYS_PROP)
    delattr(bpy.types.Mesh, REDUCED_SIZE_PROP)
