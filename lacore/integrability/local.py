"""The integrability conditions at every interior vertex (thesis section 3.2, appendix A.2).

The frames and transition rotations are those of :mod:`.transitions`; the ring
products are evaluated by the kernels of :mod:`.ring_products` (quaternions,
blocks of vertex rings, prefix products for the Jacobian).

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
(:mod:`lacore.geometry.trigonometry`); :func:`integrability_violation` reports such
vertices as ``invalid`` (default ``inf``), mirroring ``I_v = diag(inf)`` of (3.11).

The map depends on the lengths only through the interior angles: lengths
outside ``2^-100 .. 2^100`` are scaled by an exact power of two first
(:func:`lacore.geometry.lengths_angles.safe_scaled`), so the results are the same for
a mesh and its scaled copy.
"""


import math

import numpy as np
import scipy.sparse as sp

from ..cache import carve, scratch
from ..errors import LengthsAnglesError
from ..geometry.lengths_angles import safe_scaled, split_z

from .ring_products import (EULER_KEYS, block_ring_products, block_sizes, corner_half_angles, euler_from_entries,
                            half_angle_table, holonomies, ring_blocks, rotation_entries)

__all__ = [
    "integrability_map",
    "euler_integrability_map",
    "euler_integrability_jacobian",
    "integrability_violation",
]

def integrability_map(z, topology, gamma=None):
    """Holonomy ``I_v(z)`` (3.11) of every interior vertex, ``(V_int, 3, 3)``.

    Ordered like ``topology.interior_vertices``; the identity for admissible ``z``.

    Examples
    --------
    The lengths and angles of a mesh are admissible: every holonomy is the identity.

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1); topo = MeshTopology.from_faces(faces)   # a closed box bar
    >>> from lacore import integrability_map
    >>> z = lengths_and_angles(bar_pose(X, 0.5, 0.2), topo)
    >>> I = integrability_map(z, topo)
    >>> I.shape == (len(topo.interior_vertices), 3, 3)
    True
    >>> bool(np.abs(I - np.eye(3)).max() < 1e-12)
    True
    """
    q, _ = holonomies(z, topology, gamma)
    out = np.empty((q.shape[1], 3, 3))
    for key, value in rotation_entries(q).items():
        out[:, int(key[0]), int(key[1])] = value
    return out


def _finite_z(z, topology):
    """``z`` as float64 ``(2E,)``, or :class:`~lacore.errors.LengthsAnglesError` for another shape or NaN/inf
    entries (non-positive lengths are allowed: their vertices count as invalid)."""
    z = np.asarray(z, float)
    if z.shape != (2 * topology.n_edges,):
        raise LengthsAnglesError(f"z must have shape ({2 * topology.n_edges},) = 2 x {topology.n_edges} edges, got "
                                 f"{z.shape}")
    if not np.isfinite(np.add.reduce(z)) and not np.all(np.isfinite(z)):
        raise LengthsAnglesError(f"z has NaN or infinite entries ({int(np.sum(~np.isfinite(z)))})")
    return z


def euler_integrability_map(z, topology):
    """Modified integrability map (3.13), ``(3 V_int,)``; zero for admissible ``z``.

    Entries ``3 r .. 3 r + 2`` belong to vertex ``topology.interior_vertices[r]``.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1); topo = MeshTopology.from_faces(faces)   # a closed box bar
    >>> from lacore import euler_integrability_map
    >>> z = lengths_and_angles(bar_pose(X, 0.5, 0.2), topo)
    >>> bool(np.abs(euler_integrability_map(z, topo)).max() < 1e-12)
    True
    >>> z[topo.n_edges + 3] += 0.1                  # bend one edge more: no mesh has these angles
    >>> round(float(np.abs(euler_integrability_map(z, topo)).max()), 3)
    0.1
    """
    q, _ = holonomies(_finite_z(z, topology), topology)
    return euler_from_entries(rotation_entries(q, EULER_KEYS), np.empty((3, q.shape[1]))).T.ravel()


def integrability_violation(z, topology, invalid=np.inf):
    """Scalar violation ``|tr I_v(z) - 3|`` per vertex, ``(V,)`` (used for the weights 3.30).

    Boundary vertices get 0.  Vertices with a triangle in their ring that
    violates the triangle inequality get ``invalid``.  This is the local part of
    Theorem 3.2; :func:`lacore.integrability.check_integrability` adds the
    conditions around holes and handles and gives one verdict.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1); topo = MeshTopology.from_faces(faces)   # a closed box bar
    >>> from lacore import integrability_violation
    >>> z = lengths_and_angles(X, topo)
    >>> bool(integrability_violation(z, topo).max() < 1e-12)
    True
    >>> z[topo.n_edges + 3] += 0.1
    >>> print(np.flatnonzero(integrability_violation(z, topo) > 1e-6))   # the edge's end vertices
    [0 5]
    >>> topo.edges[3].tolist()
    [0, 5]
    """
    q, invalid_rows = holonomies(_finite_z(z, topology), topology)
    w, x, y, zz = q
    v = x * x
    v += y * y
    v += zz * zz
    n = w * w
    n += v
    v *= 4.0
    v /= n                                       # |tr I - 3| = 4 (x^2 + y^2 + z^2) / |q|^2
    out = np.zeros(topology.n_vertices)
    inner = topology.interior_vertices
    out[inner] = v
    if invalid_rows.size:
        out[inner[invalid_rows]] = invalid
    return out


# --------------------------------------------------------------------------- Jacobian
def _euler_jacobian_pattern(topology):
    """Cached CSR pattern of the Euler Jacobian and, per ring block, its data gather.

    Row ``3 r + j`` (Euler angle ``j`` of interior vertex ``r``) has one entry
    per column of the vertex's ring: the lengths of the rim edges and spokes and
    the angles of the spokes, ``3 n`` in all, sorted.  A block's rows are
    consecutive, so its part of the CSR data is the range ``ranges[b]``; there
    it is ``V.ravel()[gathers[b]]`` for the block's vertex-major value array
    ``V`` ``(3 rows, 3 kinds, n)`` (kinds: spoke angle, rim length, spoke length).
    """
    def compute():
        E = topology.n_edges
        ncols = 2 * E
        nv = len(topology.interior_vertices)
        indices, gathers, ranges = [], [], []
        row_counts = np.zeros(3 * nv, np.int64)
        pos = 0
        for blk in ring_blocks(topology):
            n = blk["n"]
            edges = blk["edges"][:, blk["to_position"]]                              # vertex-major
            rows = 3 * np.repeat(blk["r0"] + np.arange(len(blk["valence"])), blk["valence"])
            cols = np.stack([edges[3], edges[0], edges[2]])                           # kinds (3, n)
            row = rows[None, None, :] + np.arange(3)[:, None, None]                   # (3, 1, n)
            keys = (row * ncols + cols[None, :, :]).ravel()                           # (3, 3, n)
            order = np.argsort(keys, kind="stable")
            if np.any(np.diff(keys[order]) == 0):
                raise RuntimeError("a vertex ring references an edge twice (invalid topology)")
            indices.append(keys[order] % ncols)
            gathers.append(order)
            ranges.append(slice(pos, pos + 9 * n))
            pos += 9 * n
            row_counts[3 * blk["r0"]:3 * blk["r1"]] = np.repeat(3 * blk["valence"], 3)
        indptr = np.r_[0, np.cumsum(row_counts)]
        out = {"indices": (np.concatenate(indices) if indices else np.zeros(0, np.int64)).astype(np.int32),
               "indptr": indptr.astype(np.int32), "shape": (3 * nv, ncols), "gathers": gathers, "ranges": ranges}
        for a in [out["indices"], out["indptr"], *gathers]:
            a.setflags(write=False)
        return out
    return topology.cache.get((__name__, "euler_jacobian_pattern_blocks"), compute)


def _angle_derivatives(factors, out, tmp, scale=1.0):
    """Derivatives of the corner angles by their sides (appendix A.1), times ``scale``, into ``out`` (3, n).

    Rows: ``d gamma / d c = c / (2A)`` (rim), ``d gamma / d q`` (spoke
    ``{v, a_k}``) and ``d gamma / d p`` (spoke ``e_{k+1}``), where
    ``d gamma / d p = -(c^2 + p^2 - q^2) / (2A) / (2 p)`` and
    ``2A = sqrt(num den) / 2``.  Zero for corners of triangles with zero Kahan area.  ``tmp`` is (3, n) scratch;
    ``factors["num"], ["den"]`` are overwritten.
    """
    c, q, p = factors["lens"]
    num, den = factors["num"], factors["den"]
    inv_a = np.multiply(num, den, out=num)       # 16 A^2
    np.sqrt(inv_a, out=inv_a)
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(2.0 * scale, inv_a, out=inv_a)         # scale / (2A)
    if factors["zero_derivative"].size:
        inv_a[factors["zero_derivative"]] = 0.0
    c2, q2, p2 = tmp
    np.multiply(c, c, out=c2)
    np.multiply(q, q, out=q2)
    np.multiply(p, p, out=p2)
    gc, gq, gp = out
    np.multiply(c, inv_a, out=gc)
    for g, near, far, side in ((gp, p2, q2, p), (gq, q2, p2, q)):
        np.add(c2, near, out=g)
        g -= far
        np.negative(g, out=g)
        g *= inv_a
        g /= np.multiply(side, 2.0, out=den)
    return out


def _half_frame_columns(Q, h0, h2, t):
    """Halves of the first and third columns of the rotations of unit quaternions ``Q`` (4, n).

    ``h0 = (1/2 - (y^2 + z^2), xy + wz, xz - wy)``, ``h2 = (xz + wy, yz - wx, 1/2 - (x^2 + y^2))``
    into ``h0, h2`` (3, n); ``t`` is (n,) scratch.
    """
    w, x, y, z = Q
    np.multiply(x, z, out=h2[0])
    np.multiply(w, y, out=t)
    np.subtract(h2[0], t, out=h0[2])
    h2[0] += t
    np.multiply(y, z, out=h2[1])
    h2[1] -= np.multiply(w, x, out=t)
    np.multiply(x, y, out=h0[1])
    h0[1] += np.multiply(w, z, out=t)
    np.multiply(y, y, out=t)
    np.multiply(x, x, out=h2[2])
    h2[2] += t
    np.subtract(0.5, h2[2], out=h2[2])
    np.multiply(z, z, out=h0[0])
    h0[0] += t
    np.subtract(0.5, h0[0], out=h0[0])
    return h0, h2


def _chart_coefficients(I, out):
    """Linear map ``w -> d euler`` of an infinitesimal rotation ``[w]_x I``, as 6 coefficients (6, m).

    ``d e0 = c0 w0 + c1 w1``, ``d e1 = c2 w0 + c3 w1``, ``d e2 = w2 + c4 w0 + c5 w1``,
    with ``c0 = I10 / cos e0``, ``c1 = -I00 / cos e0``, ``c2 = I00 / d2``, ``c3 = I10 / d2``,
    ``c4 = -I20 I00 / d3``, ``c5 = -I20 I10 / d3`` (``d2 = I21^2 + I22^2``,
    ``d3 = I10^2 + I00^2``; rotation-matrix identities simplify the general chart
    derivative of the thesis).
    """
    i00, i10, i20 = I["00"], I["10"], I["20"]
    t = np.multiply(i20, i20)
    np.subtract(1.0, t, out=t)
    np.maximum(t, 1e-300, out=t)
    np.sqrt(t, out=t)
    np.divide(i10, t, out=out[0])
    np.divide(i00, t, out=out[1])
    np.negative(out[1], out=out[1])
    np.multiply(I["21"], I["21"], out=t)
    t += I["22"] * I["22"]
    np.divide(i00, t, out=out[2])
    np.divide(i10, t, out=out[3])
    np.multiply(i10, i10, out=t)
    t += i00 * i00
    np.divide(i20, t, out=t)
    np.negative(t, out=t)
    np.multiply(t, i00, out=out[4])
    np.multiply(t, i10, out=out[5])
    return out


def _jacobian_workspace(topology, blocks):
    """Scratch views used by :func:`_block_euler_jacobian` (sized for the largest block).

    ``V`` (``9 n``) overlaps ``angles, Qp, Gp``, which are free once the entries are permuted.
    """
    N, m = block_sizes(blocks)
    shapes = {"ring": (9 * N,), "angles": (2, N), "Qp": (4, N), "Gp": (3, N), "Q": (4, N), "G": (3, N),
              "h0": (3, N), "h2": (3, N), "Cb": (3, N), "Ca_next": (3, N), "t": (N,), "coef_e": (6, N),
              "tmp": (5, m), "coef": (6, m), "euler": (3, m)}
    size = sum(math.prod(v) for v in shapes.values())
    buf = scratch(topology, "ring_jacobian", size)
    ws = dict(zip(shapes, carve(buf, *shapes.values()), strict=True))
    ws["V"] = buf[9 * N:18 * N]
    return ws


def _apply_chart(coef, h, out, t):
    """``out = C h`` for chart coefficients ``coef`` (6, n) and vectors ``h`` (3, n) (:func:`_chart_coefficients`).

    ``t`` is (n,) scratch; ``out`` (3, n) must not alias ``h``.
    """
    np.multiply(coef[0], h[0], out=out[0])
    out[0] += np.multiply(coef[1], h[1], out=t)
    np.multiply(coef[2], h[0], out=out[1])
    out[1] += np.multiply(coef[3], h[1], out=t)
    np.multiply(coef[4], h[0], out=out[2])
    out[2] += np.multiply(coef[5], h[1], out=t)
    out[2] += h[2]
    return out


def _block_euler_jacobian(lengths, cs, topology, blk, ws, euler_out):
    """Euler angles and Jacobian values of one ring block.

    Writes the Euler angles of the block's vertices to ``euler_out`` (its rows
    ``r0 .. r1``) and returns the vertex-major values ``V`` ``(3, 3, n)``:
    ``V[j, kind, e]`` is the derivative of Euler angle ``j`` of the entry's
    vertex by the entry's spoke angle (kind 0), rim length (1) or spoke length
    (2), where the spoke is ``e_{k+1}``.  Views into the workspace ``ws``
    (:func:`_jacobian_workspace`).

    With the chart map ``C`` of the vertex and the halved rotation axes
    ``a_k = R(P_k) e_z / 2``, ``b_k = R(P_{k+1}) e_x / 2``:
    ``V[:, 0] = -2 C b_k``, ``V[:, 1] = 2 g_c C a_k`` and
    ``V[:, 2] = 2 g_p C a_k + 2 g_q' C a_{k+1}``, where ``g`` are the corner
    angle's derivatives by its sides and ``g_q'`` that of the next corner (whose
    side ``q`` is the same spoke).  ``C a_{k+1}`` is ``C h2`` of this entry (``C e_z / 2``
    at the end of the ring) and ``C a_k`` the same shifted by one entry.
    """
    n, m = blk["n"], len(blk["order"])
    # position-major: ring factors, prefix products P_{k+1}, twice the angle derivatives
    cz, sz, factors = corner_half_angles(lengths, topology, blk, ws["ring"])
    ct, st = np.take(cs, blk["edges"][2:], out=ws["angles"][:, :n], mode="wrap")
    Qp, Gp = ws["Qp"][:, :n], ws["Gp"][:, :n]
    block_ring_products(blk, cz, sz, ct, st, ws["tmp"], store=Qp)
    _angle_derivatives(factors, Gp, ws["h0"][:, :n], scale=2.0)
    # vertex-major from here on: rings are contiguous, rows in order
    Q, G = ws["Q"][:, :n], ws["G"][:, :n]
    np.take(Qp, blk["to_position"], axis=1, out=Q, mode="wrap")
    np.take(Gp, blk["to_position"], axis=1, out=G, mode="wrap")
    first, last = blk["first"], blk["last"]
    I = rotation_entries(np.take(Q, last, axis=1), EULER_KEYS)
    euler_out[blk["r0"]:blk["r1"]] = euler_from_entries(I, ws["euler"][:, :m]).T
    coef = _chart_coefficients(I, ws["coef"][:, :m])
    coef_e = np.take(coef, blk["ring_vertex"], axis=1, out=ws["coef_e"][:, :n], mode="wrap")
    # halved frame columns b = h0, h2 (= a_{k+1}) and their images under the chart
    h0, h2, t = ws["h0"][:, :n], ws["h2"][:, :n], ws["t"][:n]
    _half_frame_columns(Q, h0, h2, t)
    V = ws["V"][:9 * n].reshape(3, 3, n)
    Cb, Ca_next, Ca = ws["Cb"][:, :n], ws["Ca_next"][:, :n], V[:, 1]
    _apply_chart(coef_e, h0, Cb, t)
    _apply_chart(coef_e, h2, Ca_next, t)
    np.copyto(Ca[:, 1:], Ca_next[:, :-1])                   # C a_k (C e_z / 2 = (0, 0, 1/2) at k = 0)
    for i, value in enumerate((0.0, 0.0, 0.5)):
        Ca[i, first] = value
        Ca_next[i, last] = value
    gc, gq, gp = G
    np.multiply(Ca, gp, out=V[:, 2])
    gq_next = t
    gq_next[:-1] = gq[1:]
    gq_next[last] = gq[first]
    Ca_next *= gq_next
    V[:, 2] += Ca_next
    V[:, 1] *= gc
    np.multiply(Cb, -2.0, out=V[:, 0])
    return V


def euler_integrability_jacobian(z, topology, return_value=False):
    """Analytic Jacobian of :func:`euler_integrability_map`, ``(3 V_int, 2E)`` CSR.

    Product rule over the ring (A.14), the local derivatives of
    ``Rz(gamma) Rx(-theta)``, the Euler-chart derivative and the interior-angle
    derivatives of appendix A.1 (see the module docstring for the quaternion
    form used).  The sparsity pattern is cached on the topology, and the
    returned matrices share its (read-only) index arrays.

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    return_value : bool
        Also return the map's value (computed from the same products).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1); topo = MeshTopology.from_faces(faces)   # a closed box bar
    >>> from lacore import euler_integrability_jacobian, euler_integrability_map
    >>> z = lengths_and_angles(X, topo)
    >>> A = euler_integrability_jacobian(z, topo)
    >>> A.shape == (3 * len(topo.interior_vertices), 2 * topo.n_edges)
    True
    >>> dz = 1e-7 * np.random.default_rng(0).standard_normal(z.shape)
    >>> change = euler_integrability_map(z + dz, topo) - euler_integrability_map(z, topo)
    >>> bool(np.abs(A @ dz - change).max() < 1e-12)
    True
    """
    lengths, theta = split_z(z, topology)
    lengths, k = safe_scaled(lengths)  # the map is scale-invariant, its length derivatives scale by 2^-k
    pat = _euler_jacobian_pattern(topology)
    blocks = ring_blocks(topology)
    data = np.empty(len(pat["indices"]))
    euler = np.empty((len(topology.interior_vertices), 3))
    if blocks:
        cs = half_angle_table(theta, topology)
        ws = _jacobian_workspace(topology, blocks)
        for blk, gather, rng in zip(blocks, pat["gathers"], pat["ranges"], strict=True):
            V = _block_euler_jacobian(lengths, cs, topology, blk, ws, euler)
            np.take(V.reshape(-1), gather, out=data[rng], mode="wrap")
    if k:
        length_entries = pat["indices"] < topology.n_edges
        data[length_entries] = np.ldexp(data[length_entries], -k)
    J = sp.csr_matrix((data, pat["indices"], pat["indptr"]), shape=pat["shape"])
    J.has_canonical_format = True
    if return_value:
        return J, euler.ravel()
    return J
