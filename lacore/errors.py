"""Exceptions raised by lacore.

All errors caused by bad input derive from :class:`ValueError`, so callers that
do not care about the precise reason can catch ``ValueError``.
"""

__all__ = ["MeshError", "LengthsAnglesError", "format_indices"]


class MeshError(ValueError):
    """The mesh (connectivity or coordinates) is not valid for lacore.

    The message names the offending elements (edges, vertices or faces).
    """


class LengthsAnglesError(ValueError):
    """A lengths-and-angles vector ``z`` does not fit the mesh or is not finite."""


def format_indices(indices, limit=8):
    """Format up to ``limit`` indices (or index tuples) for an error message."""
    items = [tuple(int(v) for v in i) if hasattr(i, "__len__") else int(i) for i in indices]
    shown = ", ".join(str(i) for i in items[:limit])
    more = len(items) - limit
    return shown + (f" (and {more} more)" if more > 0 else "")
