"""Admissibility of lengths and angles (thesis section 3.2, appendix A.2).

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

Implementation
--------------
The ring products are evaluated with unit quaternions.  The factor
``Rz(gamma) Rx(-theta)`` is ``q = (cz ct, -cz st, -sz st, sz ct)`` with
``cz, sz = cos, sin(gamma / 2)`` and ``ct, st = cos, sin(theta / 2)``; the
half-angle cosine and sine of ``gamma`` come straight from Kahan's factors
(``tan(gamma / 2) = sqrt(num / den)``), so no interior angle is ever formed.
Multiplying a quaternion by ``q`` takes 24 flops (:func:`_ring_step`).

Interior vertices are processed in blocks of consecutive rows; inside a block
they are sorted by valence (descending) and the ring entries stored
position-major, so the vertices still active at ring position ``k`` are a
prefix of the block and each position is one vectorized step on contiguous
slices.  All z-independent index arrays (and the Jacobian's CSR pattern) are
cached on the topology; the temporaries of a block live in a reused scratch
buffer.

For the Jacobian, the derivative of a ring product with respect to one factor
is a rotation about a world axis: with the prefix ``P_k = q_0 ... q_{k-1}``,
``d I / d gamma_k = [R(P_k) e_z]_x I`` and ``d I / d theta_{e_{k+1}} = -[R(P_{k+1}) e_x]_x I``.
The Euler chart turns an infinitesimal rotation ``[w]_x I`` into
``(w1 (I10 w0 - I00 w1), (I00 w0 + I10 w1) / d2, w2 - I20 (I00 w0 + I10 w1) / d3)``
(``w1 = 1 / sqrt(1 - I20^2)``, ``d2 = I21^2 + I22^2``, ``d3 = I10^2 + I00^2``).
Only prefix products are needed (no suffix products), and the chain rule
through the interior angles uses Kahan's area (A.1).

Transcendental functions are applied to C-contiguous arrays only: numpy's
vectorized ``arcsin``/``arctan2`` can round differently (by an ulp) when writing
to strided outputs, depending on memory alignment, which would make results
irreproducible (the Jacobian's ``return_value`` equals the map bitwise).
"""

import math

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..cache import carve, scratch
from ..geometry.lengths_angles import safe_scaled, split_z
from ..geometry.trigonometry import kahan_angle_factors, kahan_area_rows, margin_rows, interior_angles

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

#: Ring entries (vertex-face corners) per block of interior vertices.  A block's temporaries
#: (about 45 doubles per entry for the Jacobian, ~6 MB) live in a scratch buffer that is
#: cached on the topology, per thread, and reused by every call.
RING_BLOCK_ENTRIES = 16384


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
    ca, sa = _cos_sin(phi.take(corner[0]), np.empty(len(ie)), np.empty(len(ie)))        # alpha_left
    cb, sb = _cos_sin(phi.take(corner[1]), np.empty(len(ie)), np.empty(len(ie)))        # alpha_right - pi
    np.negative(cb, out=cb)                                                            # cos, sin(alpha_right)
    np.negative(sb, out=sb)
    ct, st = _cos_sin(theta.take(ie), np.empty(len(ie)), np.empty(len(ie)))
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


# --------------------------------------------------------------------------- ring layout
def _ring_blocks(topology):
    """Cached block layout of the vertex rings (see the module docstring).

    Every block covers the interior-vertex rows ``[r0, r1)``; ``order`` lists
    them (as offsets from ``r0``) by valence, descending, ``rows`` are the
    sorted vertices' rows.  The block's ``n`` ring entries are stored
    *position-major*: position ``k`` holds the ``counts[k]`` first sorted
    vertices at entries ``starts[k] .. starts[k] + counts[k] - 1``.  Per entry
    (corner of ``v`` in ``f_k = (v, a_k, b_k)``), ``edges`` ``(4, n)`` holds the
    rim edge ``{a_k, b_k}`` (opposite ``v``), the spoke ``{v, a_k}``, the spoke
    ``e_{k+1} = {v, b_k}`` and ``E + e_{k+1}`` (the index of its angle in
    ``z``); ``faces`` and ``corners`` (``3 f + i``, an index into a raveled
    ``(F, 3)`` array) are ``(n,)``, ``vertex`` is the entry's sorted vertex.

    For the Jacobian the entries are also used *vertex-major* (row by row, each
    ring in order): ``to_position[e]`` is the position-major index of
    vertex-major entry ``e``; ``first``, ``last`` (``(m,)``, row order) are the
    vertex-major indices of every ring's first and last entry and ``valence``
    the ring sizes in row order, ``ring_vertex`` the vertex (offset from ``r0``)
    of every vertex-major entry.
    """
    def compute():
        E = topology.n_edges
        inner = topology.interior_vertices
        rings = topology.vertex_rings()
        nv = len(inner)
        valence = np.zeros(nv, np.int64)
        row = np.full(topology.n_vertices, -1, np.int64)
        row[inner] = np.arange(nv)
        ring = np.zeros((nv, max(rings) if rings else 0), np.int64)
        for n, (verts, corners) in rings.items():
            valence[row[verts]] = n
            ring[row[verts], :n] = corners
        # blocks of consecutive rows with about RING_BLOCK_ENTRIES entries
        cum = np.r_[0, np.cumsum(valence)]
        n_blocks = max(1, -(-int(cum[-1]) // RING_BLOCK_ENTRIES)) if nv else 0
        bounds = np.unique(np.r_[0, np.searchsorted(cum, np.arange(1, n_blocks) * cum[-1] / n_blocks), nv])
        fe = topology.face_edges
        blocks = []
        for r0, r1 in zip(bounds[:-1], bounds[1:], strict=True):
            val = valence[r0:r1]
            order = np.argsort(-val, kind="stable")
            sval = val[order]
            counts = [int(np.count_nonzero(sval > k)) for k in range(int(sval[0]))]
            starts = [int(x) for x in np.r_[0, np.cumsum(counts)[:-1]]]
            corners = np.concatenate([ring[r0 + order[:m], k] for k, m in enumerate(counts)])
            f, i = corners // 3, corners % 3
            edges = np.stack([fe[f, i], fe[f, (i + 2) % 3], fe[f, (i + 1) % 3], E + fe[f, (i + 1) % 3]])
            vertex = np.concatenate([np.arange(m) for m in counts])
            rank = np.empty_like(order)
            rank[order] = np.arange(len(order))                     # sorted index of every row of the block
            first = np.r_[0, np.cumsum(val)[:-1]]
            k_of = np.arange(len(corners)) - np.repeat(first, val)  # ring position of every vertex-major entry
            to_position = np.asarray(starts)[k_of] + np.repeat(rank, val)
            blk = {"r0": int(r0), "r1": int(r1), "order": order, "rows": r0 + order, "counts": counts,
                   "starts": starts, "n": len(corners), "edges": edges, "faces": f, "corners": corners,
                   "vertex": vertex, "to_position": to_position, "first": first, "last": first + val - 1,
                   "valence": val, "ring_vertex": np.repeat(np.arange(len(val)), val)}
            for key in ("order", "rows", "edges", "faces", "corners", "vertex", "to_position", "first", "last",
                        "valence", "ring_vertex"):
                blk[key].setflags(write=False)
            blocks.append(blk)
        return blocks
    return topology.cache.get((__name__, "ring_blocks"), compute)


def _block_sizes(blocks):
    """``(N, m)``: the largest block's entry count and vertex count (scratch buffers are sized by them)."""
    return (max((b["n"] for b in blocks), default=0), max((len(b["order"]) for b in blocks), default=0))


# --------------------------------------------------------------------------- per-block kernels
def _cos_sin(x, c, s):
    """``c, s = cos(x), sin(x)`` (arrays of one shape) from ``t = tan(x / 2)``.

    ``cos = (1 - t^2) / (1 + t^2)``, ``sin = 2 t / (1 + t^2)``: numpy's vectorized
    ``tan`` is several times faster than ``sin`` and ``cos`` together.  Angles
    outside ``[-pi, pi]`` are first reduced by multiples of ``2 pi``.  ``x`` may
    alias ``s``.
    """
    if x.size and not (x.min() >= -np.pi and x.max() <= np.pi):
        np.subtract(x, np.rint(x / (2.0 * np.pi)) * (2.0 * np.pi), out=s)
        x = s
    np.multiply(x, 0.5, out=s)
    np.tan(s, out=s)                            # t
    np.multiply(s, s, out=c)                    # t^2
    s += s                                      # 2 t
    np.subtract(1.0, c, out=c)                  # 1 - t^2
    r = np.subtract(2.0, c)                     # 1 + t^2
    np.divide(1.0, r, out=r)
    c *= r
    s *= r
    return c, s


def _half_angle_table(theta, topology):
    """``[cos(theta / 2) | sin(theta / 2)]`` of all edges as one ``(2E,)`` scratch array (see :func:`_cos_sin`)."""
    E = len(theta)
    cs = scratch(topology, "half_angles", 2 * E)
    c, s = cs[:E], cs[E:]
    np.multiply(theta, 0.5, out=s)
    _cos_sin(s, c, s)
    return cs


def _doubtful_corners(lengths, topology, faces, num, den, S):
    """Exact triangle-inequality treatment of corners whose validity the fast test could not prove.

    Clips ``num, den`` of those corners at 0 (as :func:`~lacore.geometry.trigonometry.interior_angles`)
    and returns ``(zero_angle, zero_derivative)``: entry indices whose face has
    ``T_f <= 0`` (angle 0) resp. Kahan area ``<= 0`` (derivatives 0), computed
    exactly as :func:`~lacore.geometry.trigonometry.triangle_inequality_margin` and
    :func:`~lacore.geometry.trigonometry.triangle_areas` do.
    """
    tol = 1e-14 * S * S
    doubt = np.flatnonzero(~((num > tol) & (den > tol)))
    num[doubt] = np.maximum(num[doubt], 0.0)
    den[doubt] = np.maximum(den[doubt], 0.0)
    L = lengths.take(topology.face_edges[faces[doubt]]).T
    zero_angle = doubt[margin_rows(L[0], L[1], L[2]) <= 0]
    zero_derivative = doubt[~(kahan_area_rows(L[0], L[1], L[2]) > 0)]
    return zero_angle, zero_derivative


_NO_ENTRIES = np.zeros(0, np.int64)


def _corner_half_angles(lengths, topology, blk, buf, gamma=None):
    """Half-angle cosines and sines of the block's corner angles ``gamma_k``.

    Computed from Kahan's factors: ``cos(gamma / 2) = sqrt(den / (num + den))``,
    ``sin(gamma / 2) = sqrt(num / (num + den))`` (angle 0 where ``T_f <= 0``), or
    from given interior angles ``gamma`` (``(F, 3)`` float64).  The corners' validity is
    proven at once when ``min(num, den) > 1e-14 max(S)^2`` (then both Kahan
    margins exceed ``1e-14 S``, far above their rounding errors, so
    ``T_f > 0``); otherwise the doubtful corners are checked exactly
    (:func:`_doubtful_corners`).

    Returns
    -------
    cz, sz : (n,) views into ``buf`` (>= 9 n)
    factors : dict or None
        ``num, den`` (clipped), side lengths ``lens`` ``(3, n)`` (rim ``c``,
        spoke ``q = {v, a_k}``, spoke ``p = e_{k+1}``) and ``zero_angle``,
        ``zero_derivative`` (entry indices, possibly empty); None if ``gamma`` is given.
    """
    n = blk["n"]
    cz, sz, lens, K = carve(buf, (n,), (n,), (3, n), (4, n))
    if gamma is not None:
        np.multiply(gamma.take(blk["corners"]), 0.5, out=sz)
        _cos_sin(sz, cz, sz)
        return cz, sz, None
    np.take(lengths, blk["edges"][:3], out=lens, mode="wrap")
    num, den, S, _ = kahan_angle_factors(lens[0], lens[1], lens[2], K)
    zero_angle = zero_derivative = _NO_ENTRIES
    if n and not min(num.min(), den.min()) > 1e-14 * S.max() ** 2:
        zero_angle, zero_derivative = _doubtful_corners(lengths, topology, blk["faces"], num, den, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.add(num, den, out=S)
        np.divide(den, r, out=cz)
        np.sqrt(cz, out=cz)
        np.divide(num, r, out=sz)
        np.sqrt(sz, out=sz)
    if zero_angle.size:
        cz[zero_angle] = 1.0
        sz[zero_angle] = 0.0
    return cz, sz, {"num": num, "den": den, "lens": lens, "zero_angle": zero_angle,
                    "zero_derivative": zero_derivative}


def _ring_step(w, x, y, z, cz, sz, ct, st, out, tmp):
    """Quaternion product ``out = (w, x, y, z) * q`` with ``q = Rz(gamma) Rx(-theta)`` as quaternion.

    ``q = (cz ct, -cz st, -sz st, sz ct)``; multiplying by its z-part mixes
    ``(w, z)`` and ``(x, y)``, its x-part then acts as phases ``(ct -+ i st)`` on
    ``w + i x`` and ``y + i z``: 24 flops.  ``out`` (4, m) may alias the input;
    ``tmp`` is (5, m) scratch.
    """
    a, b, c, d, t = tmp
    np.multiply(cz, w, out=a)
    a -= np.multiply(sz, z, out=t)
    np.multiply(cz, x, out=b)
    b += np.multiply(sz, y, out=t)
    np.multiply(cz, y, out=c)
    c -= np.multiply(sz, x, out=t)
    np.multiply(cz, z, out=d)
    d += np.multiply(sz, w, out=t)
    np.multiply(a, ct, out=out[0])
    out[0] += np.multiply(b, st, out=t)
    np.multiply(b, ct, out=out[1])
    out[1] -= np.multiply(a, st, out=t)
    np.multiply(c, ct, out=out[2])
    out[2] -= np.multiply(d, st, out=t)
    np.multiply(d, ct, out=out[3])
    out[3] += np.multiply(c, st, out=t)
    return out


def _ring_first(cz, sz, ct, st, out):
    """The first ring factor as quaternion, ``(cz ct, -cz st, -sz st, sz ct)`` into ``out`` (4, m)."""
    np.multiply(cz, ct, out=out[0])
    np.multiply(cz, st, out=out[1])
    np.negative(out[1], out=out[1])
    np.multiply(sz, st, out=out[2])
    np.negative(out[2], out=out[2])
    np.multiply(sz, ct, out=out[3])
    return out


def _ring_products(blk, cz, sz, ct, st, tmp, state=None, store=None):
    """Ring products of a block, position by position (position-major entries).

    With ``state`` (4, m): the final products ``I_v`` of the block's sorted
    vertices, accumulated in place.  With ``store`` (4, n): every prefix product
    ``P_{k+1} = q_0 ... q_k`` at its ring entry.  ``tmp`` is (5, m) scratch.
    Both variants do the same floating-point operations.
    """
    starts = blk["starts"]
    for k, m in enumerate(blk["counts"]):
        e = slice(starts[k], starts[k] + m)
        if store is not None:
            dst = store[:, e]
            src = store[:, starts[k - 1]:starts[k - 1] + m] if k else None
        else:
            dst = src = state[:, :m]
        if k == 0:
            _ring_first(cz[e], sz[e], ct[e], st[e], dst)
        else:
            _ring_step(src[0], src[1], src[2], src[3], cz[e], sz[e], ct[e], st[e], dst, tmp[:, :m])
    return state if store is None else store


def _block_holonomies(lengths, cs, topology, blk, ws, gamma=None):
    """Holonomy quaternions of a block's vertices (sorted order) in ``ws["state"]``.

    Returns ``(q (4, m), zero_angle)``, the entries with a triangle-inequality
    violation (see :func:`_corner_half_angles`).
    """
    n, m = blk["n"], len(blk["order"])
    cz, sz, factors = _corner_half_angles(lengths, topology, blk, ws["ring"], gamma)
    ct, st = np.take(cs, blk["edges"][2:], out=ws["angles"][:, :n], mode="wrap")
    q = ws["state"][:, :m]
    _ring_products(blk, cz, sz, ct, st, ws["tmp"], state=q)
    return q, (factors["zero_angle"] if factors is not None else _NO_ENTRIES)


def _map_workspace(topology, blocks):
    """Scratch views for :func:`_block_holonomies`."""
    N, m = _block_sizes(blocks)
    shapes = {"ring": (9 * N,), "angles": (2, N), "state": (4, m), "tmp": (5, m)}
    buf = scratch(topology, "ring_map", sum(math.prod(v) for v in shapes.values()))
    return dict(zip(shapes, carve(buf, *shapes.values()), strict=True))


def _holonomies(z, topology, gamma=None):
    """Holonomy quaternions of all interior vertices.

    Returns
    -------
    q : (4, V_int) ndarray
        Ordered like ``topology.interior_vertices``; ``+-`` the quaternion of ``I_v``.
    invalid_rows : (k,) int ndarray
        Rows of vertices with a face violating the triangle inequality in their ring.
    """
    lengths, theta = split_z(z, topology)
    lengths, _ = safe_scaled(lengths)  # scale-invariant; Kahan's factors multiply lengths
    if gamma is not None:
        gamma = np.asarray(gamma, float)
        if gamma.shape != (topology.n_faces, 3):
            raise InputError(f"gamma must have shape ({topology.n_faces}, 3), got {gamma.shape}")
    blocks = _ring_blocks(topology)
    q = np.empty((4, len(topology.interior_vertices)))
    invalid = []
    if blocks:
        cs = _half_angle_table(theta, topology)
        ws = _map_workspace(topology, blocks)
        for blk in blocks:
            qb, zero_angle = _block_holonomies(lengths, cs, topology, blk, ws, gamma)
            rows = blk["rows"]
            for i in range(4):
                q[i, rows] = qb[i]
            if zero_angle.size:
                invalid.append(rows[blk["vertex"][zero_angle]])
    return q, (np.unique(np.concatenate(invalid)) if invalid else _NO_ENTRIES)


def _rotation_entries(q, keys=("00", "01", "02", "10", "11", "12", "20", "21", "22")):
    """Entries of the rotation matrices of quaternions ``q`` (4, m) as a dict ``{"00": ..., ...}``.

    Uses ``s = 2 / |q|^2``, so slightly non-unit quaternions still give orthogonal matrices.
    """
    w, x, y, z = q
    s = w * w
    s += x * x
    s += y * y
    s += z * z
    np.divide(2.0, s, out=s)
    xs, ys, zs = x * s, y * s, z * s
    xx, yy, zz = x * xs, y * ys, z * zs
    formulas = {
        "00": lambda: np.subtract(1.0, np.add(yy, zz)), "11": lambda: np.subtract(1.0, np.add(xx, zz)),
        "22": lambda: np.subtract(1.0, np.add(xx, yy)),
        "01": lambda: x * ys - w * zs, "10": lambda: x * ys + w * zs,
        "02": lambda: x * zs + w * ys, "20": lambda: x * zs - w * ys,
        "12": lambda: y * zs - w * xs, "21": lambda: y * zs + w * xs,
    }
    return {key: formulas[key]() for key in keys}


_EULER_KEYS = ("00", "10", "20", "21", "22")


def _euler_from_entries(I, out):
    """Euler-angle chart (3.12) from rotation entries into ``out`` (3, m), which must be C-contiguous.

    (numpy's vectorized ``arcsin``/``arctan2`` can round differently when writing to
    strided outputs, depending on memory alignment; contiguous rows keep results reproducible.)
    """
    np.arcsin(np.clip(I["20"], -1.0, 1.0), out=out[0])
    np.arctan2(I["21"], I["22"], out=out[1])
    np.arctan2(I["10"], I["00"], out=out[2])
    return out


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
    q, _ = _holonomies(z, topology, gamma)
    out = np.empty((q.shape[1], 3, 3))
    for key, value in _rotation_entries(q).items():
        out[:, int(key[0]), int(key[1])] = value
    return out


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
    q, _ = _holonomies(z, topology)
    return _euler_from_entries(_rotation_entries(q, _EULER_KEYS), np.empty((3, q.shape[1]))).T.ravel()


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
    q, invalid_rows = _holonomies(z, topology)
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
        for blk in _ring_blocks(topology):
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
    N, m = _block_sizes(blocks)
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
    cz, sz, factors = _corner_half_angles(lengths, topology, blk, ws["ring"])
    ct, st = np.take(cs, blk["edges"][2:], out=ws["angles"][:, :n], mode="wrap")
    Qp, Gp = ws["Qp"][:, :n], ws["Gp"][:, :n]
    _ring_products(blk, cz, sz, ct, st, ws["tmp"], store=Qp)
    _angle_derivatives(factors, Gp, ws["h0"][:, :n], scale=2.0)
    # vertex-major from here on: rings are contiguous, rows in order
    Q, G = ws["Q"][:, :n], ws["G"][:, :n]
    np.take(Qp, blk["to_position"], axis=1, out=Q, mode="wrap")
    np.take(Gp, blk["to_position"], axis=1, out=G, mode="wrap")
    first, last = blk["first"], blk["last"]
    I = _rotation_entries(np.take(Q, last, axis=1), _EULER_KEYS)
    euler_out[blk["r0"]:blk["r1"]] = _euler_from_entries(I, ws["euler"][:, :m]).T
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
    blocks = _ring_blocks(topology)
    data = np.empty(len(pat["indices"]))
    euler = np.empty((len(topology.interior_vertices), 3))
    if blocks:
        cs = _half_angle_table(theta, topology)
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
