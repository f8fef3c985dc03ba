"""Exceptions raised by lacore.

Every error caused by bad input derives from :class:`InputError` (itself a
:class:`ValueError`).  The CLI and the Blender add-on catch ``InputError`` and
show its message; any other exception is a bug and shows as one (traceback).
"""

__all__ = ["InputError", "MeshError", "LengthsAnglesError", "format_indices"]


class InputError(ValueError):
    """Bad input from the user: a file, an array, an option.  The message says what and where."""


class MeshError(InputError):
    """The mesh (connectivity or coordinates) is not valid for lacore.

    The message names the offending elements (edges, vertices or faces).
    """


class LengthsAnglesError(InputError):
    """A lengths-and-angles vector ``z`` does not fit the mesh or is not finite."""


def format_indices(indices, limit=8):
    """Format up to ``limit`` indices (or index tuples) for an error message."""
    items = [tuple(int(v) for v in i) if hasattr(i, "__len__") else int(i) for i in indices]
    shown = ", ".join(str(i) for i in items[:limit])
    more = len(items) - limit
    return shown + (f" (and {more} more)" if more > 0 else "")
