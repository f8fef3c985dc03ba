"""Atomic file output: every file lacore writes appears complete or not at all.

:func:`atomic_write` opens a temporary file in the target's directory (same
file system, so the final :func:`os.replace` is an atomic rename) and replaces
the target only when the block finished without an exception.  On any error --
a full disk, a signal turned into an exception, a bug in the writer -- the
temporary file is removed and an existing file at the target path is left
untouched.

Usage::

    with atomic_write("out.ply") as fh:        # binary by default
        fh.write(data)
    save_npz_atomic("out.npz", z=z, faces=F)   # numpy.savez, atomically

Every writer of the package (:func:`lacore.io.meshes.save_mesh`, the ``lacore``
subcommands) goes through these two functions.
"""

import contextlib
import os
import tempfile
import zipfile

import numpy as np

__all__ = ["atomic_write", "save_npz_atomic", "npz_path"]


@contextlib.contextmanager
def atomic_write(path, mode="wb", encoding=None):
    """Context manager yielding a file object whose content replaces ``path`` atomically on success.

    Parameters
    ----------
    path : str or os.PathLike
        Final path.  Its directory must exist.
    mode : {"wb", "w"}
        Binary or text.
    encoding : str, optional
        Text encoding (``mode="w"``; default UTF-8).

    Raises
    ------
    OSError
        The directory is missing or not writable, or writing failed (the
        target is unchanged and no temporary file is left).

    Examples
    --------
    >>> import os, tempfile
    >>> from lacore.io.atomic import atomic_write
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> with atomic_write(path, "w") as fh:
    ...     _ = fh.write("complete")
    >>> try:
    ...     with atomic_write(path, "w") as fh:
    ...         _ = fh.write("half")
    ...         raise RuntimeError("failed mid-write")
    ... except RuntimeError:
    ...     pass
    >>> open(path).read(), os.listdir(os.path.dirname(path))    # the old file, no temporary file
    ('complete', ['out.txt'])
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=directory)
    try:
        kw = {} if mode == "wb" else {"encoding": encoding or "utf-8", "newline": ""}
        with os.fdopen(fd, mode, **kw) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        try:  # keep the permissions an ordinary open() would give (mkstemp makes 0600)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        except OSError:
            pass
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def npz_path(path):
    """The path :func:`numpy.savez` writes for ``path``: ``.npz`` appended unless it ends so."""
    path = os.fspath(path)
    return path if path.endswith(".npz") else path + ".npz"


def save_npz_atomic(path, compressed=False, **arrays):
    """:func:`numpy.savez` (or ``savez_compressed``) of ``arrays`` to ``path``, atomically.

    ``.npz`` is appended to ``path`` unless it ends so, as NumPy does; the path
    actually written is returned (report that one to the user).
    """
    out = npz_path(path)
    compression = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with atomic_write(out, "wb") as fh:
        # numpy.savez's own ZipFile is not closed when a write fails, and its __del__ then prints a
        # traceback ("Exception ignored in ZipFile.__del__"); this one is always closed or discarded
        zf = zipfile.ZipFile(fh, mode="w", compression=compression, allowZip64=True)
        try:
            for name, value in arrays.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
            zf.close()
        except BaseException:
            zf.fp = None  # discard: nothing more is written to the (temporary) file
            raise
    return out
