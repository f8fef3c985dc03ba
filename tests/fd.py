"""Finite-difference checks shared by the derivative tests.

``directional_fd`` uses central differences with one Richardson extrapolation
step (error O(h^4)), so that tolerances can be tight without choosing h per
mesh.
"""

import numpy as np


def directional_fd(f, x, d, h):
    """Derivative of ``f`` at ``x`` in direction ``d`` by Richardson-extrapolated central differences."""
    def central(step):
        return (np.asarray(f(x + step * d)) - np.asarray(f(x - step * d))) / (2 * step)
    return (4 * central(h / 2) - central(h)) / 3


def relative_error(a, b):
    """``max|a - b| / max|b|``."""
    return np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max()
