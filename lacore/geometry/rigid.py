"""Rigid (Kabsch) fits: the one implementation used by lacore, the add-on, scripts and tests.

A rigid motion is ``x -> x @ R.T + t`` with ``R`` a rotation (det +1, no reflection).
"""

import numpy as np

from ..errors import InputError

__all__ = ["rigid_fit", "rigid_align", "apply_rigid", "rigid_rms"]


def rigid_fit(source, target, weights=None):
    """Rotation and translation that best move ``source`` onto ``target`` (Kabsch).

    Parameters
    ----------
    source, target : (N, 3) array_like
        Corresponding points.  Rows with a NaN in either array are ignored
        (occluded markers), as are rows of zero weight.
    weights : (N,) array_like, optional
        Non-negative weights of the points (default 1).

    Returns
    -------
    R : (3, 3) ndarray
        Rotation, ``det R = +1``.
    t : (3,) ndarray
        Translation; ``source @ R.T + t`` fits ``target`` in the weighted least-squares sense.

    Raises
    ------
    InputError
        Shapes differ, or fewer than one usable point.  With one or two usable
        points the rotation is not unique; the minimal-norm rotation given by
        the SVD is returned (exact fit of the points themselves).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import rigid_fit
    >>> P = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> Rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])   # a quarter turn about z
    >>> R, t = rigid_fit(P, P @ Rz.T + [1, 2, 3])
    >>> print(np.round(R, 6) + 0.0)
    [[ 0. -1.  0.]
     [ 1.  0.  0.]
     [ 0.  0.  1.]]
    >>> print(np.round(t, 6) + 0.0)
    [1. 2. 3.]
    """
    P = np.asarray(source, dtype=float)
    Q = np.asarray(target, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or P.shape != Q.shape:
        raise InputError(f"rigid_fit needs two (N, 3) arrays of equal shape, got {P.shape} and {Q.shape}")
    if weights is None and len(P) and np.isfinite(P.sum()) and np.isfinite(Q.sum()):
        cp, cq = P.mean(0), Q.mean(0)                         # every point, equal weights: no masks or copies
        return _kabsch((P - cp).T @ Q, cp, cq)             # the centred P makes centring Q unnecessary
    w = np.ones(len(P)) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (len(P),):
        raise InputError(f"weights must have shape ({len(P)},), got {w.shape}")
    use = np.isfinite(P).all(1) & np.isfinite(Q).all(1) & (w > 0)
    if not use.any():
        raise InputError("rigid_fit: no point with finite coordinates and positive weight")
    P, Q, w = P[use], Q[use], w[use]
    w = w / w.sum()
    cp, cq = w @ P, w @ Q
    return _kabsch((P - cp).T @ ((Q - cq) * w[:, None]), cp, cq)


def _kabsch(H, cp, cq):
    """The rotation maximizing ``trace(R H)`` (no reflection) and the translation moving ``cp`` onto ``cq``."""
    U, _s, Vt = np.linalg.svd(H)
    d = 1.0 if np.linalg.det(Vt.T @ U.T) >= 0 else -1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cq - cp @ R.T


def apply_rigid(points, R, t):
    """``points @ R.T + t`` for points of shape (..., 3)."""
    return np.asarray(points, dtype=float) @ np.asarray(R).T + np.asarray(t)


def rigid_align(source, target, weights=None):
    """``source`` moved by :func:`rigid_fit` onto ``target``; shape (N, 3).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import rigid_align
    >>> P = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> Q = P @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + [1, 2, 3]
    >>> bool(np.allclose(rigid_align(P, Q), Q))
    True
    """
    R, t = rigid_fit(source, target, weights)
    return apply_rigid(source, R, t)


def rigid_rms(source, target):
    """RMS distance between ``target`` and ``source`` after the best rigid motion of ``source``."""
    Y = rigid_align(source, target)
    return float(np.sqrt(np.mean(np.sum((Y - np.asarray(target, dtype=float)) ** 2, axis=1))))
