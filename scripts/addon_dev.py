# SPDX-License-Identifier: GPL-3.0-or-later
"""Use the add-on straight from the source tree (no extension install), for the demo and scripts.

``load_addon()`` imports the repository root as the package ``lengths_angles``
(so ``lengths_angles.addon`` and ``lengths_angles.lacore`` resolve exactly as in
the installed extension) and registers it until the interpreter exits.  Needs ``bpy``.
"""

import atexit
import importlib.util
import os
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = "lengths_angles"


def load_addon(register=True):
    """Import (once) and optionally register the add-on from the source tree; returns the package."""
    if PACKAGE in sys.modules:
        pkg = sys.modules[PACKAGE]
    else:
        spec = importlib.util.spec_from_file_location(PACKAGE, os.path.join(REPO, "__init__.py"),
                                                      submodule_search_locations=[REPO])
        pkg = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = pkg
        spec.loader.exec_module(pkg)
    importlib.import_module(PACKAGE + ".addon")  # the root imports it only in register(): pkg.addon without it
    if register:
        import bpy

        if not hasattr(bpy.types, "LENGTHS_ANGLES_OT_encode"):
            pkg.register()
            # bpy 4.2 as a module frees its space types (with the panels registered on them) in a C++ exit
            # handler that runs after Python is finalized, and crashes there (exit code -11, after the script's
            # work is done) while a panel is still registered; unregistered at exit, it leaves cleanly.
            atexit.register(_unregister, pkg)
    return pkg


def _unregister(pkg):
    """Unregister the add-on if it still is (the script may have done so itself)."""
    import bpy

    if hasattr(bpy.types, "LENGTHS_ANGLES_OT_encode"):
        pkg.unregister()
