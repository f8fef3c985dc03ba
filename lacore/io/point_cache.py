"""PC2 point caches: vertex positions per frame, the format Blender's Mesh Cache modifier plays.

Layout (little endian), as written by 3ds Max / Blender's PC2 exporter::

    char[12]  "POINTCACHE2\\0"
    int32     version (1)
    int32     number of points V
    float32   start frame
    float32   sample rate (frames between samples)
    int32     number of samples T
    float32   T x V x 3 positions, sample by sample

i.e. a 32-byte header and 12 bytes per vertex per frame.
"""

import os

import numpy as np

from ..errors import InputError
from .atomic import atomic_write

__all__ = ["PointCacheError", "HEADER_BYTES", "write_pc2", "read_pc2"]

_MAGIC = b"POINTCACHE2\0"
_HEADER = np.dtype([("magic", "S12"), ("version", "<i4"), ("points", "<i4"), ("start", "<f4"),
                    ("sampling", "<f4"), ("samples", "<i4")])
HEADER_BYTES = _HEADER.itemsize  # 32


class PointCacheError(InputError):
    """A point cache that cannot be written or read (shape, header, truncated file)."""


def write_pc2(path, vertices, start=0.0, sampling=1.0):
    """Write vertex positions per frame as a PC2 file, atomically (:func:`lacore.io.atomic.atomic_write`).

    Parameters
    ----------
    path : str or path-like
    vertices : (T, V, 3) array_like
        Positions per sample; stored as float32.
    start, sampling : float
        Header fields: frame of the first sample and frames between samples.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from lacore.io.point_cache import read_pc2, write_pc2
    >>> frames = np.zeros((3, 4, 3)); frames[:, :, 0] = np.arange(3)[:, None]
    >>> path = os.path.join(tempfile.mkdtemp(), "take.pc2")
    >>> write_pc2(path, frames, start=10.0)
    >>> vertices, start, sampling = read_pc2(path)      # stored as float32
    >>> vertices[:, 0, 0].tolist(), start, sampling
    ([0.0, 1.0, 2.0], 10.0, 1.0)
    """
    X = np.asarray(vertices, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] < 1 or X.shape[1] < 1:
        raise PointCacheError(f"point cache: vertices must have shape (T >= 1, V >= 1, 3), got {X.shape}")
    if not np.all(np.isfinite(X)):
        t = int(np.flatnonzero(~np.isfinite(X).all(axis=(1, 2)))[0])
        raise PointCacheError(f"point cache: frame {t} has non-finite positions")
    peak = float(np.abs(X).max())
    if peak > float(np.finfo(np.float32).max):
        raise PointCacheError(f"point cache: positions up to {peak:.3g} do not fit the float32 numbers of a PC2 file "
                              f"(at most {np.finfo(np.float32).max:.3g}): scale the mesh down")
    header = np.zeros(1, _HEADER)
    header[0] = (_MAGIC, 1, X.shape[1], start, sampling, X.shape[0])
    with atomic_write(path, "wb") as fh:
        fh.write(header.tobytes())
        fh.write(X.astype("<f4").tobytes())


def read_pc2(path):
    """Read a PC2 file.

    Returns
    -------
    vertices : (T, V, 3) float32 ndarray
    start, sampling : float
        Header fields.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from lacore.io.point_cache import read_pc2, write_pc2
    >>> path = os.path.join(tempfile.mkdtemp(), "take.pc2")
    >>> write_pc2(path, np.ones((2, 5, 3)))
    >>> vertices, start, sampling = read_pc2(path)
    >>> vertices.shape, vertices.dtype, start, sampling
    ((2, 5, 3), dtype('float32'), 0.0, 1.0)
    """
    with open(path, "rb") as fh:
        raw = fh.read()
    if len(raw) < HEADER_BYTES or raw[:12] != _MAGIC:
        raise PointCacheError(f"{os.fspath(path)}: not a PC2 point cache (no POINTCACHE2 header)")
    h = np.frombuffer(raw[:HEADER_BYTES], _HEADER)[0]
    V, T = int(h["points"]), int(h["samples"])
    need = HEADER_BYTES + 12 * V * T
    if len(raw) != need:
        raise PointCacheError(f"{os.fspath(path)}: {len(raw)} bytes, the header ({T} samples of {V} points) "
                              f"needs {need}")
    X = np.frombuffer(raw[HEADER_BYTES:], "<f4").reshape(T, V, 3)
    return X, float(h["start"]), float(h["sampling"])
