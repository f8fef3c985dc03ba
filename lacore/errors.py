"""Exceptions raised by lacore.

Every error caused by bad input derives from :class:`InputError` (itself a
:class:`ValueError`).  The CLI and the Blender add-on catch ``InputError`` and
show its message; any other exception is a bug and shows as one (traceback).
"""

__all__ = ["InputError", "MeshError", "LengthsAnglesError", "ReconstructionWarning", "format_indices"]


class InputError(ValueError):
    """Bad input from the user: a file, an array, an option.  The message says what and where.

    Examples
    --------
    Every error of bad input is an InputError; its message says what to do:

    >>> from lacore import InputError, ReconstructionSettings
    >>> try:
    ...     ReconstructionSettings(energy="elastic")
    ... except InputError as exc:
    ...     print(exc)
    unknown energy 'elastic'; use 'quadratic' or 'shells'
    >>> from lacore import MeshTopology
    >>> try:
    ...     MeshTopology.from_faces([[0, 1, 1]])
    ... except InputError as exc:
    ...     print(type(exc).__name__, "is an InputError:", isinstance(exc, InputError))
    MeshError is an InputError: True
    """


class MeshError(InputError):
    """The mesh (connectivity or coordinates) is not valid for lacore.

    The message names the offending elements (edges, vertices or faces).

    Examples
    --------
    >>> from lacore import MeshError, check_vertices
    >>> try:
    ...     check_vertices([[0.0, 0.0, float("nan")]], 1)
    ... except MeshError as exc:
    ...     print(exc)
    vertices has NaN or infinite coordinates at vertices 0
    """


class LengthsAnglesError(InputError):
    """A lengths-and-angles vector ``z`` does not fit the mesh or is not finite.

    Examples
    --------
    >>> from lacore import LengthsAnglesError, MeshTopology, reconstruct
    >>> topo = MeshTopology.from_faces([[0, 1, 2]])
    >>> try:
    ...     reconstruct([1.0, 1.0], topo, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    ... except LengthsAnglesError as exc:
    ...     print(exc)
    target z must have shape (6,) = 2 x 3 edges, got (2,)
    """


class ReconstructionWarning(UserWarning):
    """A function that returns vertices alone returned some that failed their reconstruction's checks.

    Functions that can also return their :class:`~lacore.reconstruction.ReconstructionResult` objects
    (``return_results=True``) warn only when they are not asked for them: the caller who has the results
    decides.  Turn the warning into an error with ``warnings.simplefilter("error", ReconstructionWarning)``.

    Examples
    --------
    >>> import warnings
    >>> from lacore import ReconstructionWarning
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     warnings.warn("pose 1 of 1 failed its checks", ReconstructionWarning)
    >>> caught[0].category.__name__, issubclass(ReconstructionWarning, UserWarning)
    ('ReconstructionWarning', True)
    """


def format_indices(indices, limit=8):
    """Format up to ``limit`` indices (or index tuples) for an error message."""
    items = [tuple(int(v) for v in i) if hasattr(i, "__len__") else int(i) for i in indices]
    shown = ", ".join(str(i) for i in items[:limit])
    more = len(items) - limit
    return shown + (f" (and {more} more)" if more > 0 else "")
