"""Triangle areas and interior angles from edge lengths (thesis section 3.1, appendix A.1).

All functions take ``L`` of shape ``(F, 3)`` with ``L[f, i]`` the length of the
edge of face ``f`` opposite its local vertex ``i`` (see :mod:`lacore.topology`),
so interior angle ``i`` is the angle *at* vertex ``i``, opposite ``L[f, i]``.

Formulas are Kahan's numerically stable versions (A.2), (A.6); they stay
accurate for needle-like triangles.  Triangles violating the strict triangle
inequality (``T_f <= 0``, eq. 3.6) get area 0 and interior angles 0, the
convention of the remark after Algorithm 2 ("interior angles 0, visited last");
their derivatives are set to 0.
"""

import numpy as np

__all__ = [
    "face_edge_lengths",
    "triangle_inequality_margin",
    "triangle_areas",
    "triangle_area_gradient",
    "interior_angles",
    "interior_angle_jacobian",
]


def face_edge_lengths(lengths, topology):
    """Gather per-face edge lengths ``L (F, 3)`` from per-edge lengths ``(E,)``."""
    return np.asarray(lengths, float)[topology.face_edges]


def triangle_inequality_margin(L):
    """Scalar triangle-inequality map ``T_f = l_i + l_j + l_k - 2 max`` (3.6), shape ``(F,)``."""
    L = np.asarray(L, float)
    return L.sum(1) - 2.0 * L.max(1)


def triangle_areas(L):
    """Areas from edge lengths by Kahan's stable Heron formula (A.2).

    Parameters
    ----------
    L : (F, 3) array_like

    Returns
    -------
    (F,) ndarray
        Areas; 0 where the triangle inequality is violated.
    """
    s = -np.sort(-np.asarray(L, float), axis=1)  # a >= b >= c
    a, b, c = s[:, 0], s[:, 1], s[:, 2]
    prod = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * np.sqrt(np.maximum(prod, 0.0))


def triangle_area_gradient(L, areas=None):
    """Derivative of the area with respect to the three edge lengths, ``(F, 3)``.

    ``dA/dl_i = l_i (l_j^2 + l_k^2 - l_i^2) / (8 A)`` (appendix A.1); 0 for invalid triangles.
    """
    L = np.asarray(L, float)
    A = triangle_areas(L) if areas is None else np.asarray(areas, float)
    sq = L * L
    tot = sq.sum(1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = L * (tot - 2.0 * sq) / (8.0 * A[:, None])
    g[~(A > 0)] = 0.0
    return g


def interior_angles(L):
    """Interior angles from edge lengths by Kahan's stable formula (A.5), (A.6).

    Parameters
    ----------
    L : (F, 3) array_like

    Returns
    -------
    (F, 3) ndarray
        ``gamma[f, i]``, the angle at local vertex ``i`` (opposite ``L[f, i]``);
        all three are 0 for a triangle with ``T_f <= 0``.
    """
    L = np.asarray(L, float)
    out = np.empty_like(L)
    for i in range(3):
        c = L[:, i]
        p, q = L[:, (i + 1) % 3], L[:, (i + 2) % 3]
        a, b = np.maximum(p, q), np.minimum(p, q)
        mu = np.where(b >= c, c - (a - b), b - (a - c))
        num = ((a - b) + c) * mu
        den = (a + (b + c)) * ((a - c) + b)
        out[:, i] = 2.0 * np.arctan2(np.sqrt(np.maximum(num, 0.0)), np.sqrt(np.maximum(den, 0.0)))
    out[triangle_inequality_margin(L) <= 0] = 0.0
    return out


def interior_angle_jacobian(L, areas=None):
    """Jacobian of the interior angles with respect to the edge lengths, ``(F, 3, 3)``.

    ``J[f, i, j] = d gamma_i / d l_j``:  ``l_i / (2A)`` for ``j == i`` and
    ``-(l_i^2 + l_j^2 - l_k^2) / (4 l_j A)`` otherwise, ``k`` the third index
    (appendix A.1).  Zero for invalid triangles.
    """
    L = np.asarray(L, float)
    A = triangle_areas(L) if areas is None else np.asarray(areas, float)
    sq = L * L
    J = np.empty(L.shape + (3,))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv2A = 1.0 / (2.0 * A)
        for i in range(3):
            for j in range(3):
                if i == j:
                    J[:, i, j] = L[:, i] * inv2A
                else:
                    k = 3 - i - j
                    J[:, i, j] = -(sq[:, i] + sq[:, j] - sq[:, k]) * inv2A / (2.0 * L[:, j])
    J[~(A > 0)] = 0.0
    return J
