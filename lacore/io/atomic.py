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
subcommands, shape models, marker files, point caches) goes through these two
functions.  A failed write raises an :class:`OSError` whose message names the
file that was asked for (never the temporary file) and what to do, e.g.
``cannot write out/x.ply: permission denied: choose a folder you can write to``.
"""

import contextlib
import errno
import os
import secrets
import tempfile
import zipfile

import numpy as np

__all__ = ["atomic_write", "save_npz_atomic", "npz_path", "check_writable", "write_error"]

#: What a failed write means for the user, by ``errno``.
_WRITE_REASONS = {
    errno.ENOENT: "its folder does not exist",
    errno.ENOTDIR: "a part of its folder path is not a folder",
    errno.EACCES: "permission denied: choose a folder you can write to",
    errno.EPERM: "permission denied: choose a folder you can write to",
    errno.EROFS: "the file system is read-only: choose another folder",
    errno.ENOSPC: "No space left on device: free some space or write elsewhere",
    errno.EDQUOT: "disk quota exceeded: free some space or write elsewhere",
    errno.EISDIR: "it is a folder: give a file name",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EFBIG: "the file is too large for this file system",
}


def write_error(exc, path):
    """``exc`` (an OSError of a failed write) as an OSError of the same type whose message names ``path``.

    The message is ``cannot write <path>: <reason>`` (the reason says what to
    do where it can); ``errno`` is kept.
    """
    reason = _WRITE_REASONS.get(exc.errno) or exc.strerror or str(exc)
    if exc.errno == errno.ENOENT and os.path.isdir(os.path.dirname(os.path.abspath(os.fspath(path)))):
        reason = "its folder takes no new files (a special file system?): choose another folder"
    out = type(exc)(f"cannot write {os.fspath(path)}: {reason}")
    out.errno = exc.errno
    return out


def check_writable(path):
    """Raise the OSError of :func:`write_error` unless a file can be written at ``path``.

    Checks, without touching an existing file, that ``path`` is not a folder
    and that its folder exists and takes a new file (one is created and
    removed).  For commands that compute before they write: fail first.
    """
    path = os.fspath(path)
    if not os.path.basename(path) or os.path.isdir(path):
        raise write_error(IsADirectoryError(errno.EISDIR, "Is a directory"), path)
    directory = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".lacore-check.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise write_error(exc, path) from None
    os.close(fd)
    os.unlink(tmp)


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
        The directory is missing or not writable, ``path`` is a folder, or
        writing failed (the target is unchanged and no temporary file is
        left); the message names ``path`` (:func:`write_error`).

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
    if not os.path.basename(path) or os.path.isdir(path):
        raise write_error(IsADirectoryError(errno.EISDIR, "Is a directory"), path)
    directory = os.path.dirname(os.path.abspath(path))
    # the temporary file's name is known before it exists, so the cleanup below removes it even when an interrupt
    # (Ctrl-C) lands between its creation and the first statement that would have learnt its name
    tmp = os.path.join(directory, f".{os.path.basename(path)[:64]}.{secrets.token_hex(8)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
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
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise write_error(exc, path) from None
        raise


def npz_path(path):
    """The path :func:`numpy.savez` writes for ``path``: ``.npz`` appended unless it ends so (in any case).

    A path that names a folder (an existing one, or ending in a separator)
    raises the OSError of :func:`write_error` instead of becoming ``folder/.npz``.
    """
    path = os.fspath(path)
    if not os.path.basename(path) or os.path.isdir(path):
        raise write_error(IsADirectoryError(errno.EISDIR, "Is a directory"), path)
    return path if path.lower().endswith(".npz") else path + ".npz"


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
