# SPDX-License-Identifier: GPL-3.0-or-later
"""Lengths & Angles: Blender extension entry point.

This file only forwards to :mod:`.addon`; the mathematics lives in :mod:`.lacore`.
"""

from .addon import register, unregister

__all__ = ["register", "unregister"]
