"""Frames, transition rotations and the triangle inequalities (thesis 3.2, (3.7), (3.10)).

Frames and transition rotations
-------------------------------
A frame on face ``f = (p0, p1, p2)`` is a rotation matrix ``F_f = [b1 | b2 | N_f]``
(columns).  The *standard frame* used here has ``b1`` along the half-edge
``p0 -> p1`` and ``b2 = N_f x b1``.  For an interior edge with left face ``i`` and
right face ``j`` (see :mod:`lacore.geometry.topology`) the induced transition rotation
(3.10) is the change of basis ``F_j = F_i R_ij``::

    R_ij = Rz(alpha_i) Rx(theta_e) Rz(-alpha_j)

where ``alpha_f`` is the angle of the edge direction ``X_b - X_a`` in frame
``F_f``; it is a function of the interior angles only (:func:`edge_frame_angles`).

Triangle inequalities
---------------------
:func:`triangle_inequality_map` ``T[f, i] = l_j + l_k - l_i`` (3.7) is positive for
lengths that make triangles; its Jacobian is constant.
"""



import numpy as np
import scipy.sparse as sp

from ..geometry.lengths_angles import split_z
from ..geometry.trigonometry import interior_angles

from .ring_products import cos_sin

__all__ = ["rotation_x", "rotation_z", "standard_frames", "edge_frame_angles", "transition_rotations",
           "triangle_inequality_map", "triangle_inequality_jacobian"]


def rotation_x(angle):
    """Rotations about the x axis, ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(np.shape(angle) + (3, 3))
    R[..., 0, 0] = 1.0
    R[..., 1, 1], R[..., 1, 2] = c, -s
    R[..., 2, 1], R[..., 2, 2] = s, c
    return R


def rotation_z(angle):
    """Rotations about the z axis, ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(np.shape(angle) + (3, 3))
    R[..., 2, 2] = 1.0
    R[..., 0, 0], R[..., 0, 1] = c, -s
    R[..., 1, 0], R[..., 1, 1] = s, c
    return R


def standard_frames(vertices, faces):
    """Standard frames ``[b1 | N x b1 | N]`` of all faces, ``(F, 3, 3)`` (columns are the frame vectors)."""
    X = np.asarray(vertices, float)
    p0, p1, p2 = X[faces[:, 0]], X[faces[:, 1]], X[faces[:, 2]]
    b1 = p1 - p0
    b1 /= np.linalg.norm(b1, axis=1)[:, None]
    n = np.cross(b1, p2 - p0)
    n /= np.linalg.norm(n, axis=1)[:, None]
    return np.stack([b1, np.cross(n, b1), n], axis=2)


def edge_frame_angles(gamma):
    """Direction angle of each half-edge in its face's standard frame, ``(F, 3)``.

    Half-edge ``i`` runs from local vertex ``i+1`` to ``i+2``; its angle to ``b1``
    (measured counter-clockwise about the normal) is ``pi - gamma_1`` for ``i = 0``,
    ``pi + gamma_0`` for ``i = 1`` and ``0`` for ``i = 2``.
    """
    gamma = np.asarray(gamma, float)
    out = np.zeros_like(gamma)
    out[:, 0] = np.pi - gamma[:, 1]
    out[:, 1] = np.pi + gamma[:, 0]
    return out


def transition_rotations(z, topology, gamma=None):
    """Induced transition rotations (3.10) across all interior edges, ``(E_int, 3, 3)``.

    Row ``k`` belongs to edge ``topology.interior_edges[k]`` and maps the standard
    frame of its left face to that of its right face: ``F_right = F_left @ R``.
    (``R.T`` goes the other way.)

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    gamma : (F, 3) array_like, optional
        Interior angles if already computed.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1); topo = MeshTopology.from_faces(faces)   # a closed box bar
    >>> from lacore import transition_rotations
    >>> R = transition_rotations(lengths_and_angles(X, topo), topo)
    >>> R.shape == (len(topo.interior_edges), 3, 3)
    True
    >>> bool(np.allclose(R @ R.transpose(0, 2, 1), np.eye(3)))
    True
    """
    lengths, theta = split_z(z, topology)
    if gamma is None:
        gamma = interior_angles(lengths.take(topology.face_edges))
    phi = edge_frame_angles(gamma).ravel()
    ie = topology.interior_edges
    corner = _cached_transition_corners(topology)
    ca, sa = cos_sin(phi.take(corner[0]), np.empty(len(ie)), np.empty(len(ie)))        # alpha_left
    cb, sb = cos_sin(phi.take(corner[1]), np.empty(len(ie)), np.empty(len(ie)))        # alpha_right - pi
    np.negative(cb, out=cb)                                                            # cos, sin(alpha_right)
    np.negative(sb, out=sb)
    ct, st = cos_sin(theta.take(ie), np.empty(len(ie)), np.empty(len(ie)))
    # M = Rz(alpha) Rx(theta) has columns m0 = (ca, sa, 0), m1 = (-sa ct, ca ct, st), m2 = (sa st, -ca st, ct);
    # R = M Rz(-beta) = [m0 cb - m1 sb | m0 sb + m1 cb | m2]
    R = np.empty((len(ie), 3, 3))
    m1x, m1y = -sa * ct, ca * ct
    R[:, 0, 0] = ca * cb - m1x * sb
    R[:, 1, 0] = sa * cb - m1y * sb
    R[:, 2, 0] = -st * sb
    R[:, 0, 1] = ca * sb + m1x * cb
    R[:, 1, 1] = sa * sb + m1y * cb
    R[:, 2, 1] = st * cb
    R[:, 0, 2] = sa * st
    R[:, 1, 2] = -ca * st
    R[:, 2, 2] = ct
    return R


def _cached_transition_corners(topology):
    """Flat ``(F, 3)`` indices of the left and right half-edges of the interior edges, ``(2, E_int)``."""
    def compute():
        ie = topology.interior_edges
        ef = topology.edge_faces[ie]
        li = topology.edge_local_index[ie]
        return np.stack([3 * ef[:, 0] + li[:, 0], 3 * ef[:, 1] + li[:, 1]])
    return topology.cache.get((__name__, "transition_corners"), compute)


# --------------------------------------------------------------------------- triangle inequality
def triangle_inequality_map(z, topology):
    """Vector triangle-inequality map (3.7), ``(F, 3)``: ``T[f, i] = l_j + l_k - l_i``.

    ``z`` satisfies (T) iff every entry is positive.

    Examples
    --------
    >>> from lacore import MeshTopology, lengths_and_angles, triangle_inequality_map
    >>> topo = MeshTopology.from_faces([[0, 1, 2]])
    >>> z = lengths_and_angles([[0, 0, 0], [3, 0, 0], [0, 4, 0]], topo)
    >>> print(triangle_inequality_map(z, topo))
    [[2. 4. 6.]]
    """
    lengths, _ = split_z(z, topology)
    L = lengths.take(topology.face_edges)
    return L.sum(1, keepdims=True) - 2.0 * L


def triangle_inequality_jacobian(topology):
    """Constant Jacobian of :func:`triangle_inequality_map` (flattened row-major), ``(3F, 2E)`` CSR."""
    F, E = topology.n_faces, topology.n_edges
    rows = np.repeat(np.arange(3 * F), 3)
    cols = np.repeat(topology.face_edges, 3, axis=0).ravel()
    vals = np.tile(np.array([[-1.0, 1, 1], [1, -1, 1], [1, 1, -1]]).ravel(), F)
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * F, 2 * E))
