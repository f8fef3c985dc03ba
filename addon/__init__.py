# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender glue of Lengths & Angles: operators, panels, mesh access.

All mathematics lives in the sibling package ``lacore`` (imported relatively).
"""

import bpy

from . import operators, operators_interpolate, operators_markers, panels

classes = (*operators.classes, *operators_interpolate.classes, *operators_markers.classes, *panels.classes)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    operators_markers.register_menu()


def unregister():
    operators_markers.unregister_menu()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
