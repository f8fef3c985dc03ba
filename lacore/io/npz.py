"""Reading ``.npz`` archives of plain arrays with one-line errors that name the file.

Every lacore reader of ``.npz`` files (shape models, coarsening records,
marker arrays, ``lacore encode`` targets) opens them here: without pickles
(``allow_pickle=False``: an object array is refused, never executed), and
every problem -- a folder, a text file, a damaged archive, a single ``.npy``
array, an object array, a missing key -- raises the caller's
:class:`~lacore.errors.InputError` subclass naming the file and what to do.

Usage::

    with open_npz(path, "shape model", ShapeModelError) as npz:
        modes = read_array(npz, "modes", path, "shape model", ShapeModelError, kind="f", ndim=2)
"""

import os
import zipfile

import numpy as np

from ..errors import InputError

__all__ = ["open_npz", "read_array"]

_KINDS = {"f": "real numbers", "i": "integers", "U": "a string"}


def open_npz(path, what, error=InputError):
    """``numpy.load(path, allow_pickle=False)`` of an ``.npz`` archive, or ``error`` naming the file.

    Parameters
    ----------
    path : str, os.PathLike or file-like
    what : str
        What the file should hold, for messages (``"shape model"``).
    error : type
        The :class:`~lacore.errors.InputError` subclass to raise.

    Returns
    -------
    numpy.lib.npyio.NpzFile
        Use it as a context manager.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    error
        A folder, not an ``.npz`` archive, or a damaged one.
    """
    if isinstance(path, (str, os.PathLike)):
        name = os.fspath(path)
        if os.path.isdir(name):
            raise error(f"{name} is a folder, not a {what} file")
        if not os.path.exists(name):
            raise FileNotFoundError(f"{name}: no such {what} file")
    try:
        npz = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such {what} file") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise error(f"{path} is not a readable .npz {what} file ({_short(exc)})") from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise error(f"{path} is not a .npz {what} file (it holds a single array)")
    return npz


def read_array(npz, key, path, what, error=InputError, kind=None, ndim=None):
    """One array of an open archive, checked; ``error`` naming the file and the key if it is missing or bad.

    Parameters
    ----------
    npz : NpzFile or mapping
    key : str
    path, what, error
        As for :func:`open_npz` (for messages).
    kind : {"f", "i", "U"}, optional
        Required type: real numbers (floats or integers), integers, a string.
    ndim : int, optional
        Required number of dimensions.

    Returns
    -------
    ndarray
        Floats (``kind="f"``) as float64, integers as int64.
    """
    if key not in npz:
        raise error(f"{path} is not a {what} file: it has no '{key}' array")
    try:
        a = np.asarray(npz[key])
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise error(f"{path}: cannot read '{key}' ({_short(exc)})") from None
    allowed = {"f": "fiu", "i": "iu", "U": "U"}.get(kind)
    if allowed is not None and a.dtype.kind not in allowed:
        raise error(f"{path}: '{key}' must hold {_KINDS[kind]}, got {a.dtype} values")
    if ndim is not None and a.ndim != ndim:
        raise error(f"{path}: '{key}' must be a {ndim}-d array, got shape {a.shape}")
    if kind == "f":
        return a.astype(np.float64)
    if kind == "i":
        return a.astype(np.int64)
    return a


def _short(exc):
    return " ".join(str(exc).split()) or type(exc).__name__
