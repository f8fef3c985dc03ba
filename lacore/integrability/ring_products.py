"""Ring products of the integrability map: the per-block kernels behind :mod:`.local`.

Every interior vertex multiplies the transition rotations of its ring (3.11); these kernels
evaluate all rings at once, block by block, and the prefix products the Jacobian needs.

Implementation
--------------
The ring products are evaluated with unit quaternions.  The factor
``Rz(gamma) Rx(-theta)`` is ``q = (cz ct, -cz st, -sz st, sz ct)`` with
``cz, sz = cos, sin(gamma / 2)`` and ``ct, st = cos, sin(theta / 2)``; the
half-angle cosine and sine of ``gamma`` come straight from Kahan's factors
(``tan(gamma / 2) = sqrt(num / den)``), so no interior angle is ever formed.
Multiplying a quaternion by ``q`` takes 24 flops (:func:`ring_step`).

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

from ..errors import InputError
from ..cache import carve, scratch
from ..geometry.lengths_angles import safe_scaled, split_z
from ..geometry.trigonometry import kahan_angle_factors, kahan_area_rows, margin_rows


__all__ = ["RING_BLOCK_ENTRIES", "EULER_KEYS", "ring_blocks", "block_sizes", "cos_sin", "half_angle_table",
           "corner_half_angles", "ring_step", "block_ring_products", "holonomies", "rotation_entries",
           "euler_from_entries"]

#: Ring entries (vertex-face corners) per block of interior vertices.  A block's temporaries
#: (about 45 doubles per entry for the Jacobian, ~6 MB) live in a scratch buffer that is
#: cached on the topology, per thread, and reused by every call.
RING_BLOCK_ENTRIES = 16384


# --------------------------------------------------------------------------- ring layout
def ring_blocks(topology):
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


def block_sizes(blocks):
    """``(N, m)``: the largest block's entry count and vertex count (scratch buffers are sized by them)."""
    return (max((b["n"] for b in blocks), default=0), max((len(b["order"]) for b in blocks), default=0))


# --------------------------------------------------------------------------- per-block kernels
def cos_sin(x, c, s):
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


def half_angle_table(theta, topology):
    """``[cos(theta / 2) | sin(theta / 2)]`` of all edges as one ``(2E,)`` scratch array (see :func:`cos_sin`)."""
    E = len(theta)
    cs = scratch(topology, "half_angles", 2 * E)
    c, s = cs[:E], cs[E:]
    np.multiply(theta, 0.5, out=s)
    cos_sin(s, c, s)
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


def corner_half_angles(lengths, topology, blk, buf, gamma=None):
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
        cos_sin(sz, cz, sz)
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


def ring_step(w, x, y, z, cz, sz, ct, st, out, tmp):
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


def block_ring_products(blk, cz, sz, ct, st, tmp, state=None, store=None):
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
            ring_step(src[0], src[1], src[2], src[3], cz[e], sz[e], ct[e], st[e], dst, tmp[:, :m])
    return state if store is None else store


def _block_holonomies(lengths, cs, topology, blk, ws, gamma=None):
    """Holonomy quaternions of a block's vertices (sorted order) in ``ws["state"]``.

    Returns ``(q (4, m), zero_angle)``, the entries with a triangle-inequality
    violation (see :func:`corner_half_angles`).
    """
    n, m = blk["n"], len(blk["order"])
    cz, sz, factors = corner_half_angles(lengths, topology, blk, ws["ring"], gamma)
    ct, st = np.take(cs, blk["edges"][2:], out=ws["angles"][:, :n], mode="wrap")
    q = ws["state"][:, :m]
    block_ring_products(blk, cz, sz, ct, st, ws["tmp"], state=q)
    return q, (factors["zero_angle"] if factors is not None else _NO_ENTRIES)


def _map_workspace(topology, blocks):
    """Scratch views for :func:`_block_holonomies`."""
    N, m = block_sizes(blocks)
    shapes = {"ring": (9 * N,), "angles": (2, N), "state": (4, m), "tmp": (5, m)}
    buf = scratch(topology, "ring_map", sum(math.prod(v) for v in shapes.values()))
    return dict(zip(shapes, carve(buf, *shapes.values()), strict=True))


def holonomies(z, topology, gamma=None):
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
    blocks = ring_blocks(topology)
    q = np.empty((4, len(topology.interior_vertices)))
    invalid = []
    if blocks:
        cs = half_angle_table(theta, topology)
        ws = _map_workspace(topology, blocks)
        for blk in blocks:
            qb, zero_angle = _block_holonomies(lengths, cs, topology, blk, ws, gamma)
            rows = blk["rows"]
            for i in range(4):
                q[i, rows] = qb[i]
            if zero_angle.size:
                invalid.append(rows[blk["vertex"][zero_angle]])
    return q, (np.unique(np.concatenate(invalid)) if invalid else _NO_ENTRIES)


def rotation_entries(q, keys=("00", "01", "02", "10", "11", "12", "20", "21", "22")):
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


EULER_KEYS = ("00", "10", "20", "21", "22")


def euler_from_entries(I, out):
    """Euler-angle chart (3.12) from rotation entries into ``out`` (3, m), which must be C-contiguous.

    (numpy's vectorized ``arcsin``/``arctan2`` can round differently when writing to
    strided outputs, depending on memory alignment; contiguous rows keep results reproducible.)
    """
    np.arcsin(np.clip(I["20"], -1.0, 1.0), out=out[0])
    np.arctan2(I["21"], I["22"], out=out[1])
    np.arctan2(I["10"], I["00"], out=out[2])
    return out
