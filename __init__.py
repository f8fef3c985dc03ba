# SPDX-License-Identifier: GPL-3.0-or-later
"""Lengths & Angles: Blender extension entry point.

This file only forwards to :mod:`.addon`; the mathematics lives in :mod:`.lacore`.
The add-on is imported when Blender calls :func:`register`, not when this file is
imported: pytest imports it as a package ``__init__`` (when the checkout's folder name
is an identifier) in interpreters that have no ``bpy``.
"""


def register():
    from .addon import register as register_addon

    register_addon()


def unregister():
    from .addon import unregister as unregister_addon

    unregister_addon()


__all__ = ["register", "unregister"]
