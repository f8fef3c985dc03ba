# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender glue of Lengths & Angles: operators, panels, mesh access.

All mathematics lives in the sibling package ``lacore`` (imported relatively).
"""

import bpy

from . import (operators, operators_calibrate, operators_fit, operators_interpolate, operators_live_mix,
               operators_markers, operators_pins, panels, runs)

classes = (*operators.classes, *operators_interpolate.classes, *operators_markers.classes,
           *operators_fit.classes, *operators_calibrate.classes, *operators_pins.classes,
           *operators_live_mix.classes, *panels.classes)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    operators_fit.register_properties()
    operators_pins.register_properties()
    operators_live_mix.register_properties()  # and the live-mixing handlers
    # Shape Keys specials menu (next to the key list): In-betweens, Bake, Clear Bake, Encode, Remove Data
    bpy.types.MESH_MT_shape_key_context_menu.append(panels.draw_shape_key_menu)
    operators_markers.register_menu()


def unregister():
    operators_markers.unregister_menu()
    bpy.types.MESH_MT_shape_key_context_menu.remove(panels.draw_shape_key_menu)
    runs.shutdown()
    operators_live_mix.unregister_properties()
    operators_pins.unregister_properties()
    operators_fit.unregister_properties()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
