"""A closed box bar bent and twisted by known angles: a shape family of known dimension (2).

Sample data for tests, benchmarks and demos of :mod:`lacore.models.shape_model`: every
pose of :func:`bar_pose` shares the faces of :func:`bar_mesh`, so a grid of
``(bend, twist)`` angles is a training set whose lengths and angles lie on a
two-dimensional surface of ``R^{2E}``.
"""

import numpy as np

__all__ = ["bar_mesh", "bar_pose", "bar_family", "articulated_bar_pose"]


def bar_mesh(n_along=24, n_side=2, length=6.0, width=1.0):
    """Rest pose of a closed box bar along x: ``(vertices (V, 3), faces (F, 3))``.

    The square cross-section (side ``width``, ``n_side`` segments per side,
    ``4 n_side`` vertices per ring) is swept over ``n_along`` segments from
    ``x = 0`` to ``x = length``; each end is closed by a fan around a centre
    vertex.  ``V = 4 n_side (n_along + 1) + 2``; closed, genus 0, outward
    oriented.

    Examples
    --------
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> X.shape, faces.shape, MeshTopology.from_faces(faces).is_closed
    ((22, 3), (40, 3), True)
    """
    n_ring = 4 * n_side
    s = np.linspace(-0.5, 0.5, n_side + 1)[:-1] * width
    h = 0.5 * width
    # counter-clockwise square (seen from +x) in (y, z)
    ring = np.concatenate([np.column_stack([s, np.full(n_side, -h)]),
                           np.column_stack([np.full(n_side, h), s]),
                           np.column_stack([-s, np.full(n_side, h)]),
                           np.column_stack([np.full(n_side, -h), -s])])
    x = np.linspace(0.0, length, n_along + 1)
    X = np.zeros((n_along + 1, n_ring, 3))
    X[:, :, 0] = x[:, None]
    X[:, :, 1:] = ring[None]
    X = X.reshape(-1, 3)
    caps = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])
    X = np.vstack([X, caps])
    i = np.arange(n_along)[:, None]
    j = np.arange(n_ring)[None, :]
    a = i * n_ring + j
    b = i * n_ring + (j + 1) % n_ring
    c, d = a + n_ring, b + n_ring
    side = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    c0, c1 = len(X) - 2, len(X) - 1
    jj = np.arange(n_ring)
    cap0 = np.column_stack([np.full(n_ring, c0), (jj + 1) % n_ring, jj])
    last = n_along * n_ring
    cap1 = np.column_stack([np.full(n_ring, c1), last + jj, last + (jj + 1) % n_ring])
    return X, np.concatenate([side, cap0, cap1]).astype(np.int64)


def bar_pose(vertices, bend, twist, length=None):
    """The bar bent by ``bend`` radians (in the x-z plane) and twisted by ``twist`` radians about its axis.

    The cross-section at ``x`` is first rotated about the x axis by
    ``twist * x / length``, then the axis is wrapped isometrically onto a
    circular arc of total angle ``bend`` (the axis keeps its length; the sides
    stretch and compress like an elastic bar).

    Parameters
    ----------
    vertices : (V, 3) array_like
        Rest pose from :func:`bar_mesh` (axis along x from 0 to ``length``).
    bend, twist : float
        Radians.
    length : float, optional
        Bar length, default ``vertices[:, 0].max()``.

    Returns
    -------
    (V, 3) ndarray

    Examples
    --------
    The axis keeps its length:

    >>> import numpy as np
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> bent = bar_pose(X, np.pi, 0.0)               # a half circle
    >>> ends = bent[-2:]                              # the centres of the two end caps
    >>> round(float(np.linalg.norm(ends[1] - ends[0])), 6), round(6.0 * 2 / np.pi, 6)
    (3.819719, 3.819719)
    """
    X = np.asarray(vertices, float)
    L = float(X[:, 0].max()) if length is None else float(length)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    phi = twist * x / L
    c, s = np.cos(phi), np.sin(phi)
    y, z = c * y - s * z, s * y + c * z
    if abs(bend) < 1e-12:
        return np.column_stack([x, y, z])
    R = L / bend
    psi = x / R
    # arc in x-z; the section's z offset lies along the arc's inward normal
    px, pz = R * np.sin(psi), R * (1.0 - np.cos(psi))
    nx, nz = -np.sin(psi), np.cos(psi)
    return np.column_stack([px + z * nx, y, pz + z * nz])


def bar_family(bends, twists, n_along=24, n_side=2):
    """Poses of the bar on the grid ``bends x twists``.

    Returns
    -------
    poses : (len(bends) * len(twists), V, 3) ndarray
        Bend-major order.
    faces : (F, 3) ndarray
    params : (N, 2) ndarray
        ``(bend, twist)`` of every pose.
    """
    X0, faces = bar_mesh(n_along, n_side)
    params = np.array([(a, b) for a in bends for b in twists], float).reshape(-1, 2)
    poses = np.stack([bar_pose(X0, a, b) for a, b in params])
    return poses, faces, params


def articulated_bar_pose(vertices, angles, joints=(2.0, 4.0), width=0.6):
    """The bar bent at several joints (about the y axis), linear-blend skinned: a family with local modes.

    Segment ``k`` (between joints ``k - 1`` and ``k``) is rotated by
    ``angles[0] + ... + angles[k-1]`` about the joints' axes, chained like a
    finger; skinning weights blend neighbouring segments with a smoothstep of
    ``width`` around each joint.  Each angle changes lengths and angles only
    near its joint.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Rest pose from :func:`bar_mesh`.
    angles : (n_joints,) array_like
        Radians.
    joints : sequence of float
        x positions of the joints (increasing).
    width : float
        Width of the blend zone.

    Returns
    -------
    (V, 3) ndarray
    """
    X = np.asarray(vertices, float)
    joints = np.asarray(joints, float)
    angles = np.asarray(angles, float)
    x = X[:, 0]
    # cumulative rigid transforms of the segments
    n = len(joints)
    Rs, ts = [np.eye(3)], [np.zeros(3)]
    for k in range(n):
        c, s_ = np.cos(angles[k]), np.sin(angles[k])
        Rk = np.array([[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]])
        p = np.array([joints[k], 0.0, 0.0])
        R = Rs[-1] @ Rk
        t = Rs[-1] @ (p - Rk @ p) + ts[-1]
        Rs.append(R)
        ts.append(t)
    # weights: smoothstep partition of unity along x
    u = np.clip((x[:, None] - joints[None, :]) / width + 0.5, 0.0, 1.0)
    step = u * u * (3 - 2 * u)  # (V, n)
    w = np.empty((len(X), n + 1))
    w[:, 0] = 1 - step[:, 0]
    for k in range(1, n):
        w[:, k] = step[:, k - 1] - step[:, k]
    w[:, n] = step[:, n - 1]
    out = np.zeros_like(X)
    for k in range(n + 1):  # a few segments
        out += w[:, k:k + 1] * (X @ Rs[k].T + ts[k])
    return out
