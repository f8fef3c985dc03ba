"""Second derivatives of the lengths-and-angles map: per-edge Hessians of edge lengths and dihedral angles.

``Z[X]`` (thesis 3.1, eq. 3.5; :mod:`lacore.geometry.lengths_angles`) has one length row
per edge and one angle row per interior edge.  Each row depends on the
vertices of its *stencil* only: ``x0, x1`` (the edge) for a length, ``x0, x1,
x2, x3`` (the edge, the opposite vertex of the left face, the opposite vertex
of the right face) for an angle, so its Hessian is a small dense block:

* length ``l = |e|``, ``e = x1 - x0``, ``u = e / l``::

      d2 l / dx dx = [[K, -K], [-K, K]],   K = (I - u u^T) / l          (6 x 6)

* dihedral angle ``theta`` (12 x 12).  With ``e = x1 - x0``, ``a = x2 - x0``,
  ``b = x3 - x0``, ``n0 = e x a``, ``n1 = b x e`` and the gradients of
  :func:`lacore.geometry.lengths_angles.lengths_and_angles_jacobian`
  (``G_a = -l n0 / |n0|^2``, ``G_b = -l n1 / |n1|^2``,
  ``G_e = -t2 G_a - t3 G_b``, ``t2 = <a, e> / l^2``, ``t3 = <b, e> / l^2``),
  the Hessian in the variables ``(e, a, b)`` has the blocks (rows: gradient
  component, columns: variable; ``[v]`` the cross-product matrix of ``v``,
  ``P_i = I - 2 n_i n_i^T / |n_i|^2``)::

      d G_a / d a = -(l / |n0|^2) P0 [e]          d G_a / d e = -n0 u^T / |n0|^2 + (l / |n0|^2) P0 [a]
      d G_b / d b =  (l / |n1|^2) P1 [e]          d G_b / d e = -n1 u^T / |n1|^2 - (l / |n1|^2) P1 [b]
      d G_e / d a = -G_a e^T / l^2 - t2 dG_a/da   d G_e / d b = -G_b e^T / l^2 - t3 dG_b/db
      d G_e / d e = -G_a (a - 2 t2 e)^T / l^2 - t2 dG_a/de - G_b (b - 2 t3 e)^T / l^2 - t3 dG_b/de

  (``dG_a/db = dG_b/da = 0``), and ``x1 -> e``, ``x2 -> a``, ``x3 -> b``,
  ``x0 -> -(e + a + b)`` map it to the vertices.  The blocks are symmetrized
  (``(H + H^T) / 2``), which only removes round-off.

Used by the Newton steps of the Gauss-Newton reconstruction
(:class:`lacore.reconstruction.objectives.QuadraticObjective`, option
``newton``): the Hessian of ``W_q = sum_j w_j (Z_j - z*_j)^2`` is
``2 J^T W J + 2 sum_j w_j r_j d2 Z_j``; the second term, which Gauss-Newton
drops, matters when the target is far from admissible (large residuals ``r``).
Checked against finite differences of the analytic Jacobian in
``tests/test_hessians.py``.
"""

import numpy as np

from ..cache import scratch
from .lengths_angles import _block_geometry, _coordinates, _edge_blocks
from .topology import check_vertices

__all__ = ["length_hessians", "dihedral_angle_hessians", "residual_curvature_values", "LENGTH_PAIRS",
           "ANGLE_PAIRS"]

#: Upper-triangle index pairs ``(i, j)``, ``i <= j``, of the 6 local coordinates of a length row
#: (``x0.xyz, x1.xyz``) and of the 12 of an angle row (``x0..x3``, xyz each): the order of the
#: ``(21, E)`` and ``(78, E_int)`` value layout of :func:`residual_curvature_values`, which is the
#: layout of the Gauss-Newton assembly (:func:`lacore.reconstruction.assembly.gauss_newton_pattern`).
LENGTH_PAIRS = np.triu_indices(6)
ANGLE_PAIRS = np.triu_indices(12)


def _skew(v):
    """Cross-product matrices ``[v]`` of component rows ``v`` (3, n): ``(3, 3, n)``, ``[v] w = v x w``."""
    z = np.zeros_like(v[0])
    return np.array([[z, -v[2], v[1]], [v[2], z, -v[0]], [-v[1], v[0], z]])


def _cross(u, v):
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def _outer(u, v):
    return u[:, None] * v[None, :]


def _length_blocks(e, lengths):
    """``K = (I - u u^T) / l`` of every edge, ``(3, 3, n)``."""
    inv_l = 1.0 / lengths
    u = e * inv_l
    K = -_outer(u, u)
    for i in range(3):
        K[i, i] += 1.0
    return K * inv_l


def _vertex_length_blocks(K):
    """Length blocks ``K`` ``(3, 3, n)`` -> vertex Hessians ``(6, 6, n)`` (``x0, x1``): ``[[K, -K], [-K, K]]``."""
    L = np.empty((2, 2) + K.shape)
    L[0, 0] = L[1, 1] = K
    L[0, 1] = L[1, 0] = -K
    return L.transpose(0, 2, 1, 3, 4).reshape((6, 6) + K.shape[2:])


def _angle_blocks(e, a, b, n0, n1, lengths):
    """Dihedral-angle Hessians of a block of edges in the variables ``(e, a, b)``: ``(3, 3, 3, 3, n)``.

    ``H[p, q]`` (``p, q`` in e, a, b = 0, 1, 2) is the 3x3 block ``d G_p / d q``.
    """
    l2 = lengths * lengths
    N0 = np.einsum("in,in->n", n0, n0)
    N1 = np.einsum("in,in->n", n1, n1)
    u = e / lengths
    Ga = -(lengths / N0) * n0
    Gb = -(lengths / N1) * n1
    t2 = np.einsum("in,in->n", a, e) / l2
    t3 = np.einsum("in,in->n", b, e) / l2
    # P0 [v] = [v] - (2 / |n0|^2) n0 (n0 x v)^T, likewise P1
    P0e = _skew(e) - (2.0 / N0) * _outer(n0, _cross(n0, e))
    P0a = _skew(a) - (2.0 / N0) * _outer(n0, _cross(n0, a))
    P1e = _skew(e) - (2.0 / N1) * _outer(n1, _cross(n1, e))
    P1b = _skew(b) - (2.0 / N1) * _outer(n1, _cross(n1, b))
    Haa = -(lengths / N0) * P0e
    Hae = -_outer(n0, u) / N0 + (lengths / N0) * P0a
    Hbb = (lengths / N1) * P1e
    Hbe = -_outer(n1, u) / N1 - (lengths / N1) * P1b
    Hea = -_outer(Ga, e) / l2 - t2 * Haa
    Heb = -_outer(Gb, e) / l2 - t3 * Hbb
    Hee = (-_outer(Ga, a - 2.0 * t2 * e) / l2 - t2 * Hae
           - _outer(Gb, b - 2.0 * t3 * e) / l2 - t3 * Hbe)
    H = np.zeros((3, 3) + Haa.shape)
    H[0, 0], H[0, 1], H[0, 2] = Hee, Hea, Heb
    H[1, 0], H[1, 1] = Hae, Haa
    H[2, 0], H[2, 2] = Hbe, Hbb
    return H


def _vertex_angle_blocks(H):
    """``(e, a, b)`` Hessian blocks ``(3, 3, 3, 3, n)`` -> symmetric vertex Hessian ``(12, 12, n)`` (x0..x3)."""
    n = H.shape[-1]
    Hx = np.empty((4, 4, 3, 3, n))
    Hx[1:, 1:] = H
    Hx[0, 1:] = -H.sum(axis=0)
    Hx[1:, 0] = -H.sum(axis=1)
    Hx[0, 0] = H.sum(axis=(0, 1))
    Hx = Hx.transpose(0, 2, 1, 3, 4).reshape(12, 12, n)
    return 0.5 * (Hx + Hx.transpose(1, 0, 2))


def _check(vertices, topology):
    return check_vertices(vertices, topology.n_vertices)


def length_hessians(vertices, topology):
    """Hessians of the edge lengths, ``(E, 6, 6)`` in the local order ``x0.xyz, x1.xyz`` (``topology.edges``).

    Parameters
    ----------
    vertices : (V, 3) array_like
    topology : MeshTopology

    Returns
    -------
    (E, 6, 6) ndarray
        ``d2 l_e / dx dx`` with ``x0, x1 = edges[e]``.
    """
    X = _check(vertices, topology)
    e = (X[topology.edges[:, 1]] - X[topology.edges[:, 0]]).T
    K = _length_blocks(e, np.sqrt(np.einsum("in,in->n", e, e)))
    return np.ascontiguousarray(_vertex_length_blocks(K).transpose(2, 0, 1))


def dihedral_angle_hessians(vertices, topology):
    """Hessians of the dihedral angles of the interior edges, ``(E_int, 12, 12)``.

    Parameters
    ----------
    vertices : (V, 3) array_like
    topology : MeshTopology

    Returns
    -------
    (E_int, 12, 12) ndarray
        ``d2 theta_e / dx dx`` for ``e`` in ``topology.interior_edges``, local
        order ``x0, x1, x2, x3`` (edge end points, opposite vertex of the left
        face, of the right face; xyz each), the stencil of
        :func:`lacore.geometry.lengths_angles.jacobian_pattern` (``quad``).
    """
    X = _check(vertices, topology)
    ie = topology.interior_edges
    opp = topology.edge_opposite_vertices[ie]
    x0, x1 = X[topology.edges[ie, 0]], X[topology.edges[ie, 1]]
    e, a, b = (x1 - x0).T, (X[opp[:, 0]] - x0).T, (X[opp[:, 1]] - x0).T
    lengths = np.sqrt(np.einsum("in,in->n", e, e))
    H = _angle_blocks(e, a, b, _cross(e, a), _cross(b, e), lengths)
    return _vertex_angle_blocks(H).transpose(2, 0, 1)


def residual_curvature_values(vertices, topology, length_coefficients, angle_coefficients):
    """Upper triangles of ``c_e d2 l_e`` and ``c_e d2 theta_e`` in the Gauss-Newton assembly layout.

    The second-order part ``sum_j c_j d2 Z_j`` of a Hessian (Newton: ``c = 2 w r``),
    per element, ready to be added to the outer products of the Gauss-Newton
    assembly and summed into the pattern's slots.

    Parameters
    ----------
    vertices : (V, 3) ndarray
    topology : MeshTopology
    length_coefficients : (E,) ndarray
    angle_coefficients : (E_int,) ndarray
        One per interior edge (``topology.interior_edges`` order).

    Returns
    -------
    lengths : (21, E) ndarray
        Pairs :data:`LENGTH_PAIRS` of the local coordinates ``x0.xyz, x1.xyz``.
    angles : (78, E_int) ndarray
        Pairs :data:`ANGLE_PAIRS` of ``x0..x3``.
    """
    X = np.asarray(vertices, float)
    E = topology.n_edges
    blocks = _edge_blocks(topology)
    interior = ~topology.is_boundary_edge
    out_len = np.empty((21, E))
    out_ang = np.empty((78, len(topology.interior_edges)))
    buf = scratch(topology, "hessian", 26 * blocks["width"])
    Xc = _coordinates(X)
    il, jl = LENGTH_PAIRS
    ia, ja = ANGLE_PAIRS
    for (s0, s1), k0 in zip(blocks["ranges"], blocks["interior_before"], strict=True):
        e, a, b, n0, n1, lengths, _ = _block_geometry(Xc, blocks["stencil"][4 * s0:4 * s1], buf)
        K = _length_blocks(e, lengths) * length_coefficients[s0:s1]
        out_len[:, s0:s1] = _vertex_length_blocks(K)[il, jl]
        keep = interior[s0:s1]
        k1 = k0 + int(np.count_nonzero(keep))
        if k1 == k0:
            continue
        sel = (slice(None), keep)
        H = _angle_blocks(e[sel], a[sel], b[sel], n0[sel], n1[sel], lengths[keep])
        Hx = _vertex_angle_blocks(H)
        out_ang[:, k0:k1] = Hx[ia, ja] * angle_coefficients[k0:k1]
    return out_len, out_ang
