"""Exceptions raised by lacore.

Every error caused by bad input derives from :class:`InputError` (itself a
:class:`ValueError`).  The CLI and the Blender add-on catch ``InputError`` and
show its message; any other exception is a bug and shows as one (traceback).
"""

import numbers

import numpy as np

__all__ = ["InputError", "MeshError", "LengthsAnglesError", "ReconstructionWarning", "format_indices",
           "check_integer", "check_weight", "MAX_WEIGHT", "as_float_array"]


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


def check_integer(value, name, minimum=0):
    """``value`` as an ``int >= minimum``, or an :class:`InputError` naming ``name``.

    Integers of any type are taken, floats only when integral (``4.0``); booleans, fractions, strings and None
    are rejected with a message, never with Python's own ``TypeError`` or ``ValueError``.

    Examples
    --------
    >>> from lacore.errors import InputError, check_integer
    >>> check_integer(4.0, "n_steps", 1)
    4
    >>> try:
    ...     check_integer(None, "n_steps", 1)
    ... except InputError as exc:
    ...     print(exc)
    n_steps must be a positive integer, got None
    """
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if ok:
        ok = bool(np.isfinite(value)) and int(value) == value and int(value) >= minimum
    if not ok:
        kind = {0: "a non-negative integer", 1: "a positive integer"}.get(minimum, f"an integer >= {minimum}")
        raise InputError(f"{name} must be {kind}, got {value!r}")
    return int(value)


#: Largest scale-free energy weight a setting takes (the marker fit's prior, temporal, penetration ... weights; the
#: CLI's options): the defaults are 1e-3 to 10, fits change no more above 1e6, and far larger ones make the linear
#: systems unsolvable.  Weights with a unit (the bending weight of unit-dependent energies, eta s^2 at scale s) have
#: no such bound.
MAX_WEIGHT = 1e6


def check_weight(value, name, positive=False):
    """``value`` as a float in ``[0, MAX_WEIGHT]`` (``(0, MAX_WEIGHT]`` with ``positive``), or an
    :class:`InputError` naming ``name`` and the range.

    Examples
    --------
    >>> from lacore.errors import InputError, check_weight
    >>> check_weight(2, "temporal_weight")
    2.0
    >>> try:
    ...     check_weight(1e308, "prior_weight", positive=True)
    ... except InputError as exc:
    ...     print(exc)
    prior_weight must be a number in (0, 1e+06], got 1e+308
    """
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    v = float(value) if ok else np.nan
    if not (np.isfinite(v) and (v > 0 if positive else v >= 0) and v <= MAX_WEIGHT):
        raise InputError(f"{name} must be a number in {'(' if positive else '['}0, {MAX_WEIGHT:g}], got "
                         f"{_short_repr(value) if not ok else format(v, 'g')}")
    return v


def as_float_array(value, name, error=InputError):
    """``np.asarray(value, dtype=float)``, or an ``error`` (an :class:`InputError` class) naming ``name``.

    Ragged nested sequences (e.g. meshes of different vertex counts in one list) and entries that are no numbers
    raise ``error`` with a message that says so, instead of NumPy's conversion error.

    Examples
    --------
    >>> from lacore.errors import InputError, as_float_array
    >>> as_float_array([0, 1], "factors").dtype
    dtype('float64')
    >>> try:
    ...     as_float_array([[0.0, 1.0], [2.0]], "shapes")
    ... except InputError as exc:
    ...     print(exc)
    shapes must be an array of numbers (items of equal shape), got a ragged sequence (inhomogeneous shape)
    """
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        what = ("a ragged sequence (inhomogeneous shape)" if "inhomogeneous" in str(exc)
                else f"{type(value).__name__} {_short_repr(value)}")
        raise error(f"{name} must be an array of numbers (items of equal shape), got {what}") from None


def _short_repr(value, limit=40):
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."
