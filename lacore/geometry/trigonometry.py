"""Triangle areas and interior angles from edge lengths (thesis section 3.1, appendix A.1).

All functions take ``L`` of shape ``(F, 3)`` with ``L[f, i]`` the length of the
edge of face ``f`` opposite its local vertex ``i`` (see :mod:`lacore.geometry.topology`),
so interior angle ``i`` is the angle *at* vertex ``i``, opposite ``L[f, i]``.

Formulas are Kahan's numerically stable versions (A.2), (A.6); they stay
accurate for needle-like triangles.  Triangles violating the strict triangle
inequality (``T_f <= 0``, eq. 3.6) get area 0 and interior angles 0, the
convention of the remark after Algorithm 2 ("interior angles 0, visited last");
their derivatives are set to 0.

Lengths outside ``2^-100 .. 2^100`` are first scaled by an exact power of two
(:func:`lacore.geometry.lengths_angles.safe_scaled`; the formulas multiply lengths),
the results scaled back by their degree (angles 0, areas 2): a mesh and its
scaled copy give the same angles.

Implementation
--------------
The functions work on the three length columns as contiguous rows
(``L.T``), with elementwise ``minimum``/``maximum`` instead of sorting or
branching; the results are bitwise those of the textbook formulas.
Transcendental functions are only applied to C-contiguous arrays: with
strided outputs numpy 1.26 can round differently (by an ulp) depending on
memory alignment, which would make results irreproducible.  The
row-level building blocks :func:`kahan_angle_factors`, :func:`kahan_area_rows`
and :func:`margin_rows` are public: :mod:`lacore.integrability.local` evaluates the
same formulas on its own (blocked) corner lists.
"""

import numpy as np

from .lengths_angles import safe_scaled

__all__ = [
    "face_edge_lengths",
    "triangle_inequality_margin",
    "triangle_areas",
    "triangle_area_gradient",
    "interior_angles",
    "interior_angle_jacobian",
    "kahan_angle_factors",
    "kahan_area_rows",
    "margin_rows",
]


def face_edge_lengths(lengths, topology):
    """Gather per-face edge lengths ``L (F, 3)`` from per-edge lengths ``(E,)``."""
    return np.asarray(lengths, float).take(topology.face_edges)


def _rows(L):
    """The three length columns of ``L (F, 3)`` as a contiguous ``(3, F)`` array."""
    return np.ascontiguousarray(np.asarray(L, float).T)


def _scaled_rows(L):
    """``(_rows(L 2^-k), k)``: lengths moved into the safe range by an exact power of two (products of lengths
    neither overflow nor underflow; :func:`lacore.geometry.lengths_angles.safe_scaled`)."""
    R, k = safe_scaled(np.asarray(L, float))
    return _rows(R), k


def margin_rows(l0, l1, l2, out=None):
    """``T = (l0 + l1) + l2 - 2 max(l0, l1, l2)`` (the summation order of ``L.sum(1)``)."""
    out = np.add(l0, l1, out=out)
    out += l2
    m = np.maximum(l0, l1)
    np.maximum(m, l2, out=m)
    m *= 2.0
    out -= m
    return out


def _sort3(l0, l1, l2):
    """Elementwise descending sort of three arrays: ``(a, b, c)`` with ``a >= b >= c``."""
    hi, lo = np.maximum(l0, l1), np.minimum(l0, l1)
    a = np.maximum(hi, l2)
    c = np.minimum(lo, l2)
    np.minimum(hi, l2, out=hi)
    b = np.maximum(lo, hi, out=lo)
    return a, b, c


def kahan_area_rows(l0, l1, l2):
    """Kahan's stable Heron formula (A.2) on length rows; 0 where the triangle inequality fails."""
    a, b, c = _sort3(l0, l1, l2)
    amb = a - b
    prod = np.add(b, c)
    prod += a                                   # a + (b + c)
    prod *= np.subtract(c, amb)                 # c - (a - b)
    prod *= np.add(c, amb, out=amb)             # c + (a - b)
    np.subtract(b, c, out=c)
    c += a                                      # a + (b - c)
    prod *= c
    np.maximum(prod, 0.0, out=prod)
    np.sqrt(prod, out=prod)
    prod *= 0.25
    return prod


def kahan_angle_factors(c, p, q, out):
    """Kahan's factors (A.6) of the angle opposite side ``c`` between sides ``p`` and ``q``.

    With ``a = max(p, q)``, ``b = min(p, q)`` and
    ``mu = c - (a - b)`` if ``b >= c`` else ``b - (a - c)`` (computed branch-free
    as ``min(b, c) - (a - max(b, c))``, which is the same floating-point
    expression in either case)::

        num = ((a - b) + c) mu,   den = S D,   S = a + (b + c),   D = (a - c) + b

    The angle is ``2 atan2(sqrt(num), sqrt(den))``, ``num + den = 4 p q`` and
    ``num den = 16 A^2``.  For a valid triangle ``mu`` and ``D`` are accurate
    approximations of the triangle-inequality margins ``b + c - a`` and
    ``a + b - c``.  Not clipped: ``num`` or ``den`` is negative for a triangle
    violating the triangle inequality.

    Parameters
    ----------
    c, p, q : ndarray
        Side lengths, all of one shape.
    out : ndarray, shape ``(4,) + c.shape``
        Scratch that receives the results (must not alias the inputs).

    Returns
    -------
    num, den, S, D : views into ``out``
    """
    num, o1, o2, o3 = out
    a, b = o2, o3
    np.maximum(p, q, out=a)
    np.minimum(p, q, out=b)
    np.maximum(b, c, out=num)
    np.subtract(a, num, out=num)                # a - max(b, c)
    np.minimum(b, c, out=o1)
    np.subtract(o1, num, out=num)               # mu
    np.subtract(a, b, out=o1)
    o1 += c                                     # (a - b) + c
    num *= o1
    np.add(b, c, out=o1)
    o1 += a                                     # S = a + (b + c)
    a -= c
    a += b                                      # D = (a - c) + b   (in o2)
    np.multiply(o1, a, out=o3)                  # den = S D         (in o3)
    return num, o3, o1, o2


def _angle_rows(num, den, out):
    """``2 atan2(sqrt(max(num, 0)), sqrt(max(den, 0)))`` into ``out``; ``num, den`` are overwritten.

    All three must be C-contiguous: numpy's vectorized transcendental functions
    can round differently (by an ulp) when writing to strided outputs, depending
    on the memory alignment, which would make results irreproducible.
    """
    np.maximum(num, 0.0, out=num)
    np.sqrt(num, out=num)
    np.maximum(den, 0.0, out=den)
    np.sqrt(den, out=den)
    np.arctan2(num, den, out=out)
    out *= 2.0
    return out


def _rolled_rows(R):
    """Rows ``[0, 1, 2, 0, 1]`` of a ``(3, F)`` array: ``R5[i:i + 3]`` is ``R`` rolled by ``i``."""
    R5 = np.empty((5,) + R.shape[1:])
    R5[:3] = R
    R5[3:] = R[:2]
    return R5


def triangle_inequality_margin(L):
    """Scalar triangle-inequality map ``T_f = l_i + l_j + l_k - 2 max`` (3.6), shape ``(F,)``."""
    R = _rows(L)
    return margin_rows(R[0], R[1], R[2])


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
    R, k = _scaled_rows(L)
    A = kahan_area_rows(R[0], R[1], R[2])
    return np.ldexp(A, 2 * k) if k else A


def triangle_area_gradient(L, areas=None):
    """Derivative of the area with respect to the three edge lengths, ``(F, 3)``.

    ``dA/dl_i = l_i (l_j^2 + l_k^2 - l_i^2) / (8 A)`` (appendix A.1); 0 for invalid triangles.
    """
    R, k = _scaled_rows(L)
    if areas is None:
        A = kahan_area_rows(R[0], R[1], R[2])
    else:
        A = np.asarray(areas, float)
        A = np.ldexp(A, -2 * k) if k else A
    sq = R * R
    tot = sq[0] + sq[1]
    tot += sq[2]
    g = np.empty((R.shape[1], 3))
    gt = g.T
    np.multiply(sq, 2.0, out=gt)
    np.subtract(tot, gt, out=gt)
    gt *= R
    with np.errstate(divide="ignore", invalid="ignore"):
        gt /= 8.0 * A
    g[~(A > 0)] = 0.0
    return np.ldexp(g, k) if k else g


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
    R5 = _rolled_rows(_scaled_rows(L)[0])   # scale-invariant
    F = R5.shape[1]
    num, den, _, _ = kahan_angle_factors(R5[0:3], R5[1:4], R5[2:5], np.empty((4, 3, F)))
    out = _angle_rows(num, den, np.empty((3, F))).T.copy()
    out[margin_rows(R5[0], R5[1], R5[2]) <= 0] = 0.0
    return out


def interior_angle_jacobian(L, areas=None):
    """Jacobian of the interior angles with respect to the edge lengths, ``(F, 3, 3)``.

    ``J[f, i, j] = d gamma_i / d l_j``:  ``l_i / (2A)`` for ``j == i`` and
    ``-(l_i^2 + l_j^2 - l_k^2) / (4 l_j A)`` otherwise, ``k`` the third index
    (appendix A.1).  Zero for invalid triangles.
    """
    R, k = _scaled_rows(L)   # derivatives of scale-invariant angles scale by 2^-k
    F = R.shape[1]
    if areas is None:
        A = kahan_area_rows(R[0], R[1], R[2])
    else:
        A = np.asarray(areas, float)
        A = np.ldexp(A, -2 * k) if k else A
    R5 = _rolled_rows(R)
    S5 = R5 * R5
    J = np.empty((F, 3, 3))
    J9 = J.reshape(F, 9).T                       # (9, F) rows: entry (i, j) is row 3 i + j
    t = np.empty((3, F))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv2A = 1.0 / (2.0 * A)
        np.multiply(R, inv2A, out=t)
        J9[[0, 4, 8]] = t
        for shift, rows in ((1, [1, 5, 6]), (2, [2, 3, 7])):   # j = i + shift, k = the third index
            np.add(S5[0:3], S5[shift:shift + 3], out=t)
            t -= S5[3 - shift:6 - shift]
            np.negative(t, out=t)
            t *= inv2A
            t /= 2.0 * R5[shift:shift + 3]
            J9[rows] = t
    J[~(A > 0)] = 0.0
    return np.ldexp(J, -k) if k else J
