"""Admissibility of lengths and angles (thesis section 3.2, appendix A.2).

Frames and transition rotations
-------------------------------
A frame on face ``f = (p0, p1, p2)`` is a rotation matrix ``F_f = [b1 | b2 | N_f]``
(columns).  The *standard frame* used here has ``b1`` along the half-edge
``p0 -> p1`` and ``b2 = N_f x b1``.  For an interior edge with left face ``i`` and
right face ``j`` (see :mod:`lacore.topology`) the induced transition rotation
(3.10) is the change of basis ``F_j = F_i R_ij``::

    R_ij = Rz(alpha_i) Rx(theta_e) Rz(-alpha_j)

where ``alpha_f`` is the angle of the edge direction ``X_b - X_a`` in frame
``F_f``; it is a function of the interior angles only (:func:`edge_frame_angles`).

Integrability map
-----------------
Following the remark after (3.13), every interior vertex ``v`` uses its own
frames: in the k-th face of its counter-clockwise loop, ``f_k = (v, a_k, b_k)``,
the first frame vector points along ``a_k - v``.  Then
``R_{k,k+1} = Rz(gamma_k) Rx(-theta_{e_{k+1}})`` with ``gamma_k`` the interior angle of
``f_k`` at ``v`` and ``e_{k+1} = {v, b_k}`` the edge shared with ``f_{k+1}``, and::

    I_v(z) = R_{0,1} R_{1,2} ... R_{n-1,0}                  (3.11)

equals the identity for admissible ``z``.  The Euler-angle map (3.13) is
``(arcsin I[2,0], atan2(I[2,1], I[2,2]), atan2(I[1,0], I[0,0]))`` per interior
vertex, stacked as ``(3 V_int,)`` in the order of ``topology.interior_vertices``.

Triangles that violate the triangle inequality get interior angles 0
(:mod:`lacore.trigonometry`); :func:`integrability_violation` reports such
vertices as ``invalid`` (default ``inf``), mirroring ``I_v = diag(inf)`` of (3.11).

All computations are vectorized over vertices, with a loop over the (few)
distinct valences and the positions within a ring.
"""

import numpy as np
import scipy.sparse as sp

from .lengths_angles import split_z
from .trigonometry import (interior_angle_jacobian, interior_angles, triangle_areas,
                           triangle_inequality_margin)

__all__ = [
    "rotation_x",
    "rotation_z",
    "standard_frames",
    "edge_frame_angles",
    "transition_rotations",
    "triangle_inequality_map",
    "triangle_inequality_jacobian",
    "integrability_map",
    "euler_integrability_map",
    "euler_integrability_jacobian",
    "integrability_violation",
]


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


def _rz_rx(gamma, phi):
    """``Rz(gamma) @ Rx(phi)`` in closed form, ``(..., 3, 3)``."""
    cg, sg, cp, sp_ = np.cos(gamma), np.sin(gamma), np.cos(phi), np.sin(phi)
    R = np.empty(np.shape(gamma) + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = cg, -sg * cp, sg * sp_
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = sg, cg * cp, -cg * sp_
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = 0.0, sp_, cp
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
    """
    lengths, theta = split_z(z, topology)
    if gamma is None:
        gamma = interior_angles(lengths[topology.face_edges])
    phi = edge_frame_angles(gamma)
    ie = topology.interior_edges
    ef = topology.edge_faces[ie]
    li = topology.edge_local_index[ie]
    a_left = phi[ef[:, 0], li[:, 0]]
    a_right = phi[ef[:, 1], li[:, 1]] + np.pi
    return rotation_z(a_left) @ rotation_x(theta[ie]) @ rotation_z(-a_right)


# --------------------------------------------------------------------------- triangle inequality
def triangle_inequality_map(z, topology):
    """Vector triangle-inequality map (3.7), ``(F, 3)``: ``T[f, i] = l_j + l_k - l_i``.

    ``z`` satisfies (T) iff every entry is positive.
    """
    lengths, _ = split_z(z, topology)
    L = lengths[topology.face_edges]
    return L.sum(1, keepdims=True) - 2.0 * L


def triangle_inequality_jacobian(topology):
    """Constant Jacobian of :func:`triangle_inequality_map` (flattened row-major), ``(3F, 2E)`` CSR."""
    F, E = topology.n_faces, topology.n_edges
    rows = np.repeat(np.arange(3 * F), 3)
    cols = np.repeat(topology.face_edges, 3, axis=0).ravel()
    vals = np.tile(np.array([[-1.0, 1, 1], [1, -1, 1], [1, 1, -1]]).ravel(), F)
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * F, 2 * E))


# --------------------------------------------------------------------------- integrability
def _ring_data(topology):
    """Per valence group: vertices, ring faces, local indices, edges e_{k+1}."""
    def compute():
        groups = []
        row = np.full(topology.n_vertices, -1, np.int64)
        row[topology.interior_vertices] = np.arange(len(topology.interior_vertices))
        for n, (verts, corners) in sorted(topology.vertex_rings().items()):
            f, i = corners // 3, corners % 3
            e_next = topology.face_edges[f, (i + 1) % 3]
            groups.append({"n": n, "vertices": verts, "rows": row[verts], "faces": f,
                           "local": i, "e_next": e_next})
        return groups
    return topology._cached("integrability_rings", compute)


def _ring_rotations(gamma_ring, theta_ring):
    return _rz_rx(gamma_ring, -theta_ring)


def integrability_map(z, topology, gamma=None):
    """Holonomy ``I_v(z)`` (3.11) of every interior vertex, ``(V_int, 3, 3)``.

    Ordered like ``topology.interior_vertices``; the identity for admissible ``z``.
    """
    lengths, theta = split_z(z, topology)
    if gamma is None:
        gamma = interior_angles(lengths[topology.face_edges])
    out = np.empty((len(topology.interior_vertices), 3, 3))
    for g in _ring_data(topology):
        R = _ring_rotations(gamma[g["faces"], g["local"]], theta[g["e_next"]])
        acc = R[:, 0]
        for k in range(1, g["n"]):
            acc = acc @ R[:, k]
        out[g["rows"]] = acc
    return out


def _euler_angles(I):
    """Euler-angle chart (3.12) of rotation matrices ``(..., 3, 3)`` -> ``(..., 3)``."""
    return np.stack([np.arcsin(np.clip(I[..., 2, 0], -1.0, 1.0)),
                     np.arctan2(I[..., 2, 1], I[..., 2, 2]),
                     np.arctan2(I[..., 1, 0], I[..., 0, 0])], axis=-1)


def euler_integrability_map(z, topology):
    """Modified integrability map (3.13), ``(3 V_int,)``; zero for admissible ``z``.

    Entries ``3 r .. 3 r + 2`` belong to vertex ``topology.interior_vertices[r]``.
    """
    return _euler_angles(integrability_map(z, topology)).ravel()


def integrability_violation(z, topology, invalid=np.inf):
    """Scalar violation ``|tr I_v(z) - 3|`` per vertex, ``(V,)`` (used for the weights 3.30).

    Boundary vertices get 0.  Vertices with a triangle in their ring that
    violates the triangle inequality get ``invalid``.
    """
    lengths, _ = split_z(z, topology)
    L = lengths[topology.face_edges]
    I = integrability_map(z, topology, gamma=interior_angles(L))
    out = np.zeros(topology.n_vertices)
    inner = topology.interior_vertices
    out[inner] = np.abs(np.trace(I, axis1=1, axis2=2) - 3.0)
    bad_face = triangle_inequality_margin(L) <= 0
    if np.any(bad_face):
        bad_v = np.zeros(topology.n_vertices, bool)
        bad_v[topology.faces[bad_face].ravel()] = True
        out[bad_v & ~topology.is_boundary_vertex] = invalid
    return out


def _euler_jacobian_pattern(topology):
    def compute():
        E = topology.n_edges
        ncols = 2 * E
        keys = []
        for g in _ring_data(topology):
            n, m = g["n"], len(g["vertices"])
            rows = 3 * g["rows"][:, None, None] + np.arange(3)[None, :, None]          # (m, 3, 1)
            theta_cols = E + g["e_next"]                                               # (m, n)
            len_cols = topology.face_edges[g["faces"]].reshape(m, 3 * n)               # (m, 3n)
            cols = np.concatenate([theta_cols, len_cols], axis=1)[:, None, :]          # (m, 1, 4n)
            keys.append((rows * ncols + cols).ravel())
        keys = np.concatenate(keys) if keys else np.zeros(0, np.int64)
        ukeys, slot = np.unique(keys, return_inverse=True)
        nrows = 3 * len(topology.interior_vertices)
        indptr = np.r_[0, np.cumsum(np.bincount(ukeys // ncols, minlength=nrows))]
        return {"slot": slot, "indices": (ukeys % ncols).astype(np.int32),
                "indptr": indptr.astype(np.int32), "shape": (nrows, ncols)}
    return topology._cached("euler_jacobian_pattern", compute)


def euler_integrability_jacobian(z, topology, return_value=False):
    """Analytic Jacobian of :func:`euler_integrability_map`, ``(3 V_int, 2E)`` CSR.

    Product rule over the ring (A.14) with prefix/suffix products, the local
    derivatives of ``Rz(gamma) Rx(-theta)``, the Euler-chart derivative and the
    interior-angle derivatives of appendix A.1.  The sparsity pattern is cached
    on the topology.

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    return_value : bool
        Also return the map's value (computed from the same products).
    """
    lengths, theta = split_z(z, topology)
    L = lengths[topology.face_edges]
    areas = triangle_areas(L)
    gamma = interior_angles(L)
    dgamma = interior_angle_jacobian(L, areas)
    pat = _euler_jacobian_pattern(topology)
    values = []
    euler = np.empty((len(topology.interior_vertices), 3))
    for g in _ring_data(topology):
        n = g["n"]
        f, i = g["faces"], g["local"]
        gam, th = gamma[f, i], theta[g["e_next"]]
        cg, sg, ct, st = np.cos(gam), np.sin(gam), np.cos(th), np.sin(th)
        R = _rz_rx(gam, -th)                                   # (m, n, 3, 3)
        m = R.shape[0]
        # derivatives of Rz(g) Rx(-t) with respect to g and t
        dRg = np.zeros_like(R)
        dRg[..., 0, 0], dRg[..., 0, 1], dRg[..., 0, 2] = -sg, -cg * ct, -cg * st
        dRg[..., 1, 0], dRg[..., 1, 1], dRg[..., 1, 2] = cg, -sg * ct, -sg * st
        dRt = np.zeros_like(R)
        dRt[..., 0, 1], dRt[..., 0, 2] = sg * st, -sg * ct
        dRt[..., 1, 1], dRt[..., 1, 2] = -cg * st, cg * ct
        dRt[..., 2, 1], dRt[..., 2, 2] = -ct, -st
        # prefix P_k = R_0..R_{k-1}, suffix S_k = R_{k+1}..R_{n-1}
        P = np.empty((m, n + 1, 3, 3))
        P[:, 0] = np.eye(3)
        for k in range(n):
            P[:, k + 1] = P[:, k] @ R[:, k]
        S = np.empty((m, n, 3, 3))
        S[:, n - 1] = np.eye(3)
        for k in range(n - 2, -1, -1):
            S[:, k] = R[:, k + 1] @ S[:, k + 1]
        I = P[:, n]
        dI_g = P[:, :n] @ dRg @ S                              # (m, n, 3, 3)
        dI_t = P[:, :n] @ dRt @ S
        # Euler chart derivative
        i20, i21, i22, i10, i00 = I[:, 2, 0], I[:, 2, 1], I[:, 2, 2], I[:, 1, 0], I[:, 0, 0]
        w1 = 1.0 / np.sqrt(np.maximum(1.0 - i20 * i20, 1e-300))
        d2 = i21 * i21 + i22 * i22
        d3 = i10 * i10 + i00 * i00

        def chart(dI):
            return np.stack([w1[:, None] * dI[..., 2, 0],
                             (i22[:, None] * dI[..., 2, 1] - i21[:, None] * dI[..., 2, 2]) / d2[:, None],
                             (i00[:, None] * dI[..., 1, 0] - i10[:, None] * dI[..., 0, 0]) / d3[:, None]],
                            axis=1)                             # (m, 3, n)
        dE_theta = chart(dI_t)
        dE_gamma = chart(dI_g)
        # chain rule gamma_k -> three edge lengths of f_k
        dg = dgamma[f, i]                                       # (m, n, 3)
        dE_len = (dE_gamma[:, :, :, None] * dg[:, None, :, :]).reshape(m, 3, 3 * n)
        values.append(np.concatenate([dE_theta, dE_len], axis=2).ravel())
        euler[g["rows"]] = _euler_angles(I)
    vals = np.concatenate(values) if values else np.zeros(0)
    data = np.bincount(pat["slot"], weights=vals, minlength=len(pat["indices"]))
    J = sp.csr_matrix((data, pat["indices"], pat["indptr"]), shape=pat["shape"])
    if return_value:
        return J, euler.ravel()
    return J
