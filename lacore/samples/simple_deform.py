"""Generated shapes with known deformations, for tests, benchmarks and examples.

:func:`box_bar`
    A closed, triangulated box bar (sphere topology) of regular grids.
:func:`simple_deform_bend`
    Blender's Simple Deform 'BEND' applied analytically: an exact pure bend,
    the reference for interpolating a straight bar and a bent one in lengths
    and angles (``tests/test_interpolation.py``, ``benchmarks/bench_interpolation.py``).
"""

import numpy as np

from ..errors import InputError

__all__ = ["box_bar", "simple_deform_bend"]


def box_bar(n_length=16, n_width=4, length=4.0, width=1.0):
    """Closed, outward-oriented triangulated surface of the box ``[0, length] x [-w/2, w/2]^2``.

    Every side is a regular grid (``n_length`` cells along x, ``n_width`` across),
    each grid square split into two triangles along the same diagonal; the sides
    share their boundary vertices (sphere topology, ``V - E + F = 2``).  The
    vertex count is ``(n_l + 1)(n_w + 1)^2 - (n_l - 1)(n_w - 1)^2``.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    """
    nx, nw = int(n_length), int(n_width)
    if nx < 1 or nw < 1:
        raise InputError("n_length and n_width must be >= 1")
    n = (nx, nw, nw)
    sides = []
    # (fixed axis, u axis, v axis) with u x v the outward normal of the '+' side
    for axis, u, v in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        for value, (a, b) in ((n[axis], (u, v)), (0, (v, u))):
            I, J = np.meshgrid(np.arange(n[a] + 1), np.arange(n[b] + 1), indexing="ij")
            lattice = np.zeros(I.shape + (3,), np.int64)
            lattice[..., axis] = value
            lattice[..., a] = I
            lattice[..., b] = J
            p00, p10, p11, p01 = lattice[:-1, :-1], lattice[1:, :-1], lattice[1:, 1:], lattice[:-1, 1:]
            sides.append(np.stack([p00, p10, p11], -2).reshape(-1, 3, 3))
            sides.append(np.stack([p00, p11, p01], -2).reshape(-1, 3, 3))
    corners = np.concatenate(sides).reshape(-1, 3)  # integer lattice points of all triangle corners
    keys, inverse = np.unique(corners, axis=0, return_inverse=True)
    faces = inverse.reshape(-1, 3).astype(np.int64)
    vertices = keys * np.array([length / nx, width / nw, width / nw]) - np.array([0.0, width / 2, width / 2])
    return vertices, faces


def simple_deform_bend(vertices, angle):
    """Blender's Simple Deform modifier, mode 'BEND', deform axis Z, applied analytically.

    Blender (``MOD_simpledeform.cc``, ``simpleDeform_bend``) bends the x axis
    into a circle about an axis parallel to z through ``(0, 1/k)``::

        k = angle / (x_max - x_min)           (full limits [0, 1])
        theta = k x
        x' = -(y - 1/k) sin(theta)
        y' =  (y - 1/k) cos(theta) + 1/k
        z' = z

    Points at ``x = 0`` stay fixed; the fibre ``y = 0`` keeps its length and a
    fibre at height ``y`` is scaled by ``1 - k y`` (pure bending of a beam).

    Parameters
    ----------
    vertices : (V, 3) array_like
        In object coordinates (origin at the fixed end).
    angle : float
        Total bend angle in radians (non-zero).
    """
    X = np.asarray(vertices, float)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    k = angle / (x.max() - x.min())
    theta = k * x
    r = 1.0 / k
    return np.stack([-(y - r) * np.sin(theta), (y - r) * np.cos(theta) + r, z], axis=1)
