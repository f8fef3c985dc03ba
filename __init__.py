# SPDX-License-Identifier: GPL-3.0-or-later
"""Lengths & Angles: Blender extension entry point.

This file only forwards to :mod:`.addon`; the mathematics lives in :mod:`.lacore`.
"""

if __package__:  # pytest imports this file standalone when the checkout's folder name is no identifier
    from .addon import register, unregister

__all__ = ["register", "unregister"]
