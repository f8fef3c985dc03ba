"""The map X -> z = (edge lengths, signed dihedral angles) and its Jacobian (thesis 3.1, eq. 3.5).

Conventions
-----------
``z`` has shape ``(2E,)``: ``z[:E]`` are the edge lengths ``l_e`` and ``z[E:]`` the
dihedral angles ``theta_e`` in radians, ordered like ``topology.edges``.

The dihedral angle of an interior edge ``e = (a, b)`` (oriented as in
:mod:`lacore.geometry.topology`, left face ``f0`` traversing it from ``a`` to ``b``) is the
signed angle that rotates the left normal ``N0`` onto the right normal ``N1``
about the edge direction ``(X_b - X_a) / l_e``::

    theta_e = atan2(<N0 x N1, X_b - X_a> / l_e, <N0, N1>)   in (-pi, pi]

It is 0 for a flat edge, positive where the surface is convex (folds away from
its normals, like the edges of a cube with outward normals) and negative where
it is concave.  The value does not depend on the edge's orientation.  Boundary
edges get ``theta_e = 0`` and a zero row in the Jacobian.  Using ``atan2`` keeps
near-flat angles accurate to machine precision (no ``acos``).

The vertex vector is ``X.ravel()`` of a ``(V, 3)`` array, so the Jacobian's
column ``3 v + c`` is coordinate ``c`` of vertex ``v``.

Implementation
--------------
Every edge is evaluated on its *stencil* ``x0 = X_a, x1 = X_b`` (the edge),
``x2`` (opposite vertex in the left face) and ``x3`` (opposite vertex in the
right face; ``x2`` again on boundary edges, whose angle is then reset to 0).
The index arrays are cached on the topology; a call gathers the coordinates
once, component by component (1-d ``take`` is far cheaper than fancy indexing of
``(N, 3)`` rows), and works on contiguous component arrays.  With
``e = x1 - x0``, ``a = x2 - x0``, ``b = x3 - x0`` the unnormalized normals are
``n0 = e x a`` and ``n1 = b x e``, and ``<n0 x n1, e> / l = -l <n0, b>`` (a vector
identity), which saves a cross product.  The Jacobian's values are written into
one ``(18, E)`` buffer that a cached permutation turns into the CSR data.
"""


import numpy as np
import scipy.sparse as sp

from ..cache import carve, scratch
from ..errors import LengthsAnglesError, MeshError, format_indices
from .topology import check_vertices

__all__ = [
    "face_normals",
    "face_areas",
    "cross_rows",
    "dot_rows",
    "edge_lengths",
    "dihedral_angles",
    "wrap_angle",
    "lengths_and_angles",
    "lengths_and_angles_jacobian",
    "split_z",
    "check_z",
    "check_nondegenerate",
    "check_float_range",
    "degenerate_faces",
    "DEGENERACY_RTOL",
    "safe_scale_exponent",
    "safe_scaled",
    "jacobian_pattern",
]


# --------------------------------------------------------------------------- small helpers
def _cross_rows(u, v, out, tmp):
    """Cross product of component-row arrays: ``out[i] = (u x v)[i]`` for ``u, v, out`` of shape (3, N).

    ``tmp`` is an (N,) scratch array.  Returns ``out``.
    """
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(u[j], v[k], out=out[i])
        out[i] -= np.multiply(u[k], v[j], out=tmp)
    return out


def _dot_rows(u, v, out):
    """Dot product of component-row arrays (3, N) into ``out`` (N,).  Returns ``out``."""
    np.multiply(u[0], v[0], out=out)
    out += u[1] * v[1]
    out += u[2] * v[2]
    return out


def cross_rows(u, v):
    """Cross products of component-row arrays ``u, v (3, N)``: ``(3, N)``, ``out[:, i] = u[:, i] x v[:, i]``.

    Cheaper than :func:`numpy.cross` on rows of this layout (coordinates first, every product over
    a contiguous row).

    Examples
    --------
    >>> import numpy as np
    >>> cross_rows(np.array([[1.0], [0.0], [0.0]]), np.array([[0.0], [1.0], [0.0]])).ravel()
    array([0., 0., 1.])
    """
    u, v = np.asarray(u, float), np.asarray(v, float)
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    return _cross_rows(u, v, out, np.empty(out.shape[1:]))


def dot_rows(u, v):
    """Dot products of component-row arrays ``u, v (3, N)``: ``(N,)``.

    Examples
    --------
    >>> import numpy as np
    >>> float(dot_rows(np.array([[1.0], [2.0], [3.0]]), np.array([[4.0], [5.0], [6.0]]))[0])
    32.0
    """
    u, v = np.asarray(u, float), np.asarray(v, float)
    return _dot_rows(u, v, np.empty(np.broadcast_shapes(u.shape, v.shape)[1:]))


def _as_vertices(vertices, n_vertices):
    """``check_vertices`` with a cheap fast path for valid input.

    A finite sum proves that all coordinates are finite; anything else (wrong
    shape, NaN/inf, or a sum that overflows) goes through :func:`check_vertices`,
    which raises the detailed error or accepts the input.
    """
    X = np.asarray(vertices, dtype=np.float64)
    if X.shape == (n_vertices, 3) and np.isfinite(np.add.reduce(X, axis=None)):
        return X
    return check_vertices(vertices, n_vertices)


def _face_corner_coordinates(X, faces):
    """Coordinates of the three corners of every face as ``(3 components, 3 corners, F)``."""
    ft = np.asarray(faces).T
    P = np.empty((3,) + ft.shape)
    for c in range(3):
        P[c] = X[:, c].take(ft)
    return P


def face_normals(vertices, faces, unit=True):
    """Face normals ``(X1 - X0) x (X2 - X0)`` (1.14), ``(F, 3)``; unnormalized (length ``2 a_f``) if ``unit=False``."""
    X = np.asarray(vertices, float)
    P = _face_corner_coordinates(X, faces)          # (3, 3, F)
    D = P[:, 1:] - P[:, :1]                         # (3 components, 2 vectors, F)
    F = D.shape[2]
    n = np.empty((F, 3))
    nt = n.T                                        # component rows (strided views)
    _cross_rows(D[:, 0], D[:, 1], nt, np.empty(F))
    if unit:
        n /= np.sqrt(_dot_rows(nt, nt, np.empty(F)))[:, None]
    return n


def face_areas(vertices, faces):
    """Triangle areas ``(F,)``."""
    n = face_normals(vertices, faces, unit=False).T
    out = _dot_rows(n, n, np.empty(n.shape[1]))
    np.sqrt(out, out=out)
    out *= 0.5
    return out


#: A triangle is numerically degenerate when its edge lengths (as computed, rounded to float64) satisfy the
#: triangle inequality with a relative margin ``(l_i + l_j + l_k - 2 max) / (l_i + l_j + l_k)`` of at most this:
#: its height is then determined by the lengths to no better than ``eps / margin`` (1e-4), and the angles of
#: the lengths-and-angles representation are meaningless.  A needle of height ``h`` over its longest edge
#: ``l`` has margin ``~ (h / l)^2``: the bound rejects ``h < 1e-6 l``; a thin right triangle of aspect 1e4
#: has margin 5e-5.
DEGENERACY_RTOL = 1e-12


def degenerate_faces(vertices, topology, rtol=DEGENERACY_RTOL):
    """Faces whose computed edge lengths (nearly) violate the triangle inequality; scale-free.

    Parameters
    ----------
    vertices : (V, 3) float64 array
    topology : MeshTopology
    rtol : float
        Relative margin (see :data:`DEGENERACY_RTOL`).

    Returns
    -------
    (k,) ndarray of int
        Face indices, ascending.
    """
    lengths = _z_of_vertices(np.asarray(vertices, float), topology, angles=False)
    L = lengths[topology.face_edges]
    perimeter = L.sum(axis=1)
    margin = perimeter - 2.0 * L.max(axis=1)
    return np.flatnonzero(~(margin > rtol * perimeter))


def check_float_range(vertices, topology):
    """:class:`~lacore.errors.MeshError` when float64 cannot represent the mesh's geometry.

    Every computation in lacore is scale-free (:func:`safe_scaled`), so any
    magnitude of coordinates works, except coordinates that are all subnormal
    (below 2.2e-308: they carry fewer than 53 significant bits, the shape was
    rounded when it was stored) and edges longer than the largest float64
    (1.8e308, between coordinates of opposite signs).
    """
    X = np.asarray(vertices, float)
    m = float(np.max(np.abs(X))) if X.size else 0.0
    tiny = np.finfo(float).tiny
    if 0.0 < m < tiny:
        bits = int(np.floor(np.log2(m))) + 1074
        raise MeshError(f"the coordinates are subnormal float64 numbers (largest |x| = {m:.3g}, below the normal "
                        f"range that starts at {tiny:.3g}): they keep only {bits} significant bits, so the shape "
                        "was rounded when it was stored; export the mesh in a smaller unit (scaled up)")
    with np.errstate(over="ignore"):
        overflow = m > 0.0 and not np.all(np.isfinite(edge_lengths(X, topology)))
    if overflow:
        raise MeshError(f"edge lengths exceed the largest float64 number (coordinates up to |x| = {m:.3g}): "
                        "export the mesh in a larger unit (scaled down)")


def check_nondegenerate(vertices, topology, rtol=DEGENERACY_RTOL):
    """Validated vertices; :class:`~lacore.errors.MeshError` naming (numerically) degenerate triangles.

    Scale-free: a triangle is degenerate when its edge lengths, as float64
    numbers, satisfy the triangle inequality with a relative margin of at most
    ``rtol`` (zero-area triangles, and needles so thin that rounding the
    lengths breaks the inequality), see :func:`degenerate_faces`.  The result
    is the same for the mesh scaled by any factor.  Coordinates that float64 cannot
    hold faithfully are named first (:func:`check_float_range`).
    """
    X = check_vertices(vertices, topology.n_vertices)
    check_float_range(X, topology)
    bad = degenerate_faces(X, topology, rtol)
    if bad.size:
        raise MeshError(f"degenerate triangles (zero area, or edge lengths violating the triangle inequality "
                        f"after rounding, relative margin <= {rtol:g}): faces {format_indices(bad)}")
    return X


# --------------------------------------------------------------------------- blocks and scratch memory
#: Edges per block.  A block's temporaries (26 doubles per edge for the map, 46 for the
#: Jacobian) stay in the CPU cache and come from one scratch buffer cached on the topology
#: per thread, reused by every call (no fresh, page-faulting memory).
BLOCK_SIZE = 8192


def _block_ranges(n, size=None):
    """Balanced blocks ``[(start, stop), ...]`` covering ``range(n)`` and their common width."""
    size = BLOCK_SIZE if size is None else size
    k = max(1, -(-n // size))
    width = max(1, -(-n // k))
    return [(s, min(s + width, n)) for s in range(0, n, width)], width


# --------------------------------------------------------------------------- edge stencils
def _edge_blocks(topology):
    """Cached block layout of the edges and their stencils.

    Returns a dict with ``ranges`` and ``width`` (see :func:`_block_ranges`),
    ``stencil`` (``(4 E,)``: block ``[s0, s1)`` holds the ``(4, s1 - s0)``
    vertex indices ``x0, x1, x2, x3`` of its edges at offset ``4 s0``; ``x3 = x2``
    on boundary edges) and ``interior_before`` (number of interior edges before
    each block's start).
    """
    def compute():
        E = topology.n_edges
        opp = topology.edge_opposite_vertices
        x3 = np.where(opp[:, 1] >= 0, opp[:, 1], opp[:, 0])
        quad = np.stack([topology.edges[:, 0], topology.edges[:, 1], opp[:, 0], x3])
        ranges, width = _block_ranges(E)
        stencil = np.concatenate([quad[:, s0:s1].ravel() for s0, s1 in ranges]) if E else np.zeros(0, np.int64)
        interior_before = np.searchsorted(topology.interior_edges, [s0 for s0, _ in ranges])
        stencil.setflags(write=False)
        return {"ranges": ranges, "width": width, "stencil": stencil, "interior_before": interior_before}
    return topology.cache.get((__name__, "edge_blocks"), compute)


def _block_vectors(Xc, stencil, out_P, out_D):
    """Stencil vectors of one block: ``out_D[c] = (e, a, b)`` components ``c`` (``(3, 3, n)``).

    ``Xc`` are the three coordinate arrays of the vertices, ``stencil`` the block's
    ``(4 n,)`` vertex indices, ``out_P`` a ``(4, n)`` scratch array.
    """
    flat = out_P.reshape(-1)
    for c in range(3):
        np.take(Xc[c], stencil, out=flat, mode="wrap")    # cached, valid indices: no bounds checks
        np.subtract(out_P[1:], out_P[0], out=out_D[c])
    return out_D


def _block_geometry(Xc, stencil, buf):
    """Stencil vectors, normals and lengths of one block of ``n`` edges, in the scratch ``buf`` (>= 26 n).

    Returns ``e, a, b, n0, n1`` (``(3, n)`` component rows; ``n0 = e x a``,
    ``n1 = b x e``), ``lengths`` (n,) and a free ``(n,)`` scratch row.
    """
    n = len(stencil) // 4
    P, D, n0, n1, lengths, tmp = carve(buf, (4, n), (3, 3, n), (3, n), (3, n), (n,), (n,))
    _block_vectors(Xc, stencil, P, D)
    e, a, b = D[:, 0], D[:, 1], D[:, 2]
    _cross_rows(e, a, n0, tmp)
    _cross_rows(b, e, n1, tmp)
    np.sqrt(_dot_rows(e, e, lengths), out=lengths)
    return e, a, b, n0, n1, lengths, tmp


def _dihedral_rows(b, n0, n1, lengths, out, tmp):
    """Signed dihedral angles into ``out``: ``atan2(-l <n0, b>, <n0, n1>)`` (boundary edges not yet zeroed)."""
    y = _dot_rows(n0, b, tmp)
    y *= lengths
    np.negative(y, out=y)
    return np.arctan2(y, _dot_rows(n0, n1, out), out=out)


def _coordinates(X):
    """The three coordinate arrays of ``(V, 3)`` vertices, as a contiguous ``(3, V)`` copy."""
    return np.ascontiguousarray(X.T)


def edge_lengths(vertices, topology):
    """Edge lengths ``(E,)``.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, edge_lengths
    >>> topo = MeshTopology.from_faces([[0, 1, 2], [2, 1, 3]])
    >>> X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    >>> print(np.round(edge_lengths(X, topo), 4))
    [1.     1.     1.4142 1.     1.    ]
    """
    X = np.asarray(vertices, float)
    return _z_of_vertices(X, topology, angles=False)


def dihedral_angles(vertices, topology):
    """Signed dihedral angles ``(E,)`` in radians (0 on boundary edges); see the module docstring.

    Examples
    --------
    Folding the second triangle of a unit square up by 90 degrees about the diagonal
    (angles are signed: this fold is negative):

    >>> import numpy as np
    >>> from lacore import MeshTopology, dihedral_angles
    >>> topo = MeshTopology.from_faces([[0, 1, 2], [2, 1, 3]])
    >>> X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0.5, np.sqrt(0.5)]])
    >>> theta = dihedral_angles(X, topo)
    >>> print(np.round(np.degrees(theta[topo.interior_edges]), 6))
    [-90.]
    >>> print(theta[topo.is_boundary_edge])          # boundary edges: 0 by convention
    [0. 0. 0. 0.]
    """
    X = np.asarray(vertices, float)
    return _z_of_vertices(X, topology)[topology.n_edges:]


def wrap_angle(a):
    """Angles (any shape) to ``(-pi, pi]``: differences of dihedral angles on the circle.

    Signed dihedral angles live on the circle: an edge folded to ``3.1`` and one folded to
    ``-3.1`` differ by ``0.08``, not ``6.2``.  Every difference of angles in lacore -- the
    residuals of ``W_q``, blends and interpolations of keys, the checks -- is taken through
    this function.  Angles in ``[-pi, pi]`` are returned as they are, bit for bit (the same array
    when all are).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.lengths_angles import wrap_angle
    >>> print(np.round(wrap_angle(np.array([3.1 - (-3.1), -4.0, 0.5, 2 * np.pi])), 6))
    [-0.083185  2.283185  0.5       0.      ]
    """
    a = np.asarray(a, float)
    inside = np.abs(a) <= np.pi
    if inside.all():
        return a
    return np.where(inside, a, np.pi - np.mod(np.pi - a, 2.0 * np.pi))


#: Coordinates with ``max |x|`` outside ``[2^-SAFE_EXPONENT, 2^SAFE_EXPONENT]`` (about 1e-30 .. 1e30) are scaled by a
#: power of two (exact) into that range before any computation that multiplies them: the lengths-and-angles
#: map and its Jacobian (products of three coordinates), interior angles and the integrability map (products of
#: lengths), and every reconstruction (:class:`lacore.reconstruction.ReconstructionContext`: weights ``1 /
#: l^2``, the thin shells energy's squared areas, products of eight coordinates) then neither overflow nor
#: become subnormal.
SAFE_EXPONENT = 100


def safe_scale_exponent(X):
    """``k`` with ``X * 2^-k`` in the safe range (0 when ``X`` already is); see :data:`SAFE_EXPONENT`.

    Angles are invariant under the scaling and lengths scale by exactly ``2^k``,
    so results inside the safe range are bit-identical to unscaled ones.
    """
    m = float(np.max(np.abs(X))) if X.size else 0.0
    if m == 0.0 or not np.isfinite(m) or 2.0**-SAFE_EXPONENT <= m <= 2.0**SAFE_EXPONENT:
        return 0
    return int(np.frexp(m)[1])


def safe_scaled(values):
    """``(values 2^-k, k)`` with ``k = safe_scale_exponent(values)``: the array itself when ``k = 0``.

    The one scaling of lacore's scale-free computations: angles (dihedral,
    interior) and the integrability map are invariant under it, lengths scale
    by exactly ``2^k``.

    Examples
    --------
    >>> import numpy as np
    >>> safe_scaled(np.array([1.0, 2.0]))[1], safe_scaled(np.array([1e-160, 3e-160]))[1]
    (0, -529)
    """
    k = safe_scale_exponent(values)
    return (np.ldexp(values, -k), k) if k else (values, 0)


def _z_of_vertices(X, topology, angles=True):
    """``z = (lengths, theta)`` of float64 ``(V, 3)`` vertices, ``(2E,)``; just the lengths ``(E,)`` if not angles."""
    k = safe_scale_exponent(X)
    if k:
        z = _z_of_vertices(np.ldexp(X, -k), topology, angles)
        z[:topology.n_edges] = np.ldexp(z[:topology.n_edges], k)
        return z
    E = topology.n_edges
    z = np.empty(2 * E if angles else E)
    blocks = _edge_blocks(topology)
    buf = scratch(topology, "z", 26 * blocks["width"])
    Xc = _coordinates(X)
    for s0, s1 in blocks["ranges"]:
        stencil = blocks["stencil"][4 * s0:4 * s1]
        if not angles:
            n = s1 - s0
            P, D = carve(buf, (4, n), (3, 1, n))
            e = _block_vectors(Xc, stencil[:2 * n], P[:2], D)[:, 0]
            np.sqrt(_dot_rows(e, e, z[s0:s1]), out=z[s0:s1])
            continue
        e, a, b, n0, n1, lengths, tmp = _block_geometry(Xc, stencil, buf)
        z[s0:s1] = lengths
        _dihedral_rows(b, n0, n1, lengths, z[E + s0:E + s1], tmp)
    bnd = topology.boundary_edges
    if angles and bnd.size:
        z[E + bnd] = 0.0
    return z


def lengths_and_angles(vertices, topology, check=True):
    """The lengths-and-angles map ``Z[X]`` (3.5).

    Parameters
    ----------
    vertices : (V, 3) array_like
    topology : MeshTopology
    check : bool
        Validate shape and finiteness of ``vertices`` (default True).

    Returns
    -------
    z : (2E,) ndarray
        ``(l_1..l_E, theta_1..theta_E)``.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> z = lengths_and_angles(X, topo)
    >>> z.shape == (2 * topo.n_edges,)
    True
    >>> lengths, angles = z[:topo.n_edges], z[topo.n_edges:]
    >>> round(float(lengths.min()), 4), round(float(np.degrees(angles).max()), 4)
    (0.7071, 90.0)
    """
    X = _as_vertices(vertices, topology.n_vertices) if check else np.asarray(vertices, float)
    return _z_of_vertices(X, topology)


def split_z(z, topology):
    """Split ``z`` into ``(lengths (E,), angles (E,))`` views after checking its size.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles, split_z
    >>> topo = MeshTopology.from_faces([[0, 1, 2]])
    >>> lengths, angles = split_z(lengths_and_angles([[0, 0, 0], [3, 0, 0], [0, 4, 0]], topo), topo)
    >>> print(np.sort(lengths), angles)
    [3. 4. 5.] [0. 0. 0.]
    """
    z = np.asarray(z, float)
    E = topology.n_edges
    if z.shape != (2 * E,):
        raise LengthsAnglesError(f"z must have shape ({2 * E},) = 2 x {E} edges, got {z.shape}")
    return z[:E], z[E:]


def check_z(z, topology, name="z"):
    """Validate a lengths-and-angles vector: right size, finite, positive lengths.

    Returns the vector as float64 ``(2E,)``.
    """
    z = np.asarray(z, float)
    E = topology.n_edges
    if z.shape != (2 * E,):
        raise LengthsAnglesError(f"{name} must have shape ({2 * E},) = 2 x {E} edges, got {z.shape}")
    bad = np.flatnonzero(~np.isfinite(z))
    if bad.size:
        where = [f"{'length' if i < E else 'angle'} of edge {i % E}" for i in bad[:5]]
        raise LengthsAnglesError(f"{name} has NaN or infinite entries ({bad.size}): " + ", ".join(where))
    bad = np.flatnonzero(z[:E] <= 0)
    if bad.size:
        raise LengthsAnglesError(f"{name} has non-positive edge lengths at edges {format_indices(bad)}")
    return z


# --------------------------------------------------------------------------- Jacobian
def jacobian_pattern(topology):
    """Fixed CSR sparsity pattern of dZ/dX, computed once per topology.

    Keys: ``indices, indptr, shape`` (the CSR structure; rows sorted by column;
    read-only, shared by all returned matrices); ``order`` (the CSR data is
    ``concatenate([length gradients (E, 6), angle gradients (E_int, 12)]).ravel()[order]``,
    the local gradients in stencil order ``x0, x1`` resp. ``x0, x1, x2, x3``);
    ``quad`` (``(E_int, 4)`` stencil vertices of the interior edges);
    ``gather`` (per edge block of :func:`_edge_blocks`: the block's CSR data as
    positions in its ``(18, width)`` value buffer, see
    :func:`lengths_and_angles_jacobian`) and ``slices`` (the block's two ranges
    of the CSR data: length rows, angle rows).
    """
    def compute():
        E = topology.n_edges
        edges = topology.edges
        xyz = np.arange(3)
        len_rows = np.repeat(np.arange(E), 6)
        len_cols = (3 * edges[:, [0, 0, 0, 1, 1, 1]] + np.tile(xyz, 2)).ravel()
        ie = topology.interior_edges
        opp = topology.edge_opposite_vertices[ie]
        quad = np.stack([edges[ie, 0], edges[ie, 1], opp[:, 0], opp[:, 1]], 1)  # x0 x1 x2 x3
        ang_rows = np.repeat(E + ie, 12)
        ang_cols = (3 * np.repeat(quad, 3, axis=1) + np.tile(xyz, 4)).ravel()
        rows = np.r_[len_rows, ang_rows]
        cols = np.r_[len_cols, ang_cols]
        # rows are already ascending (lengths by edge, then angles by interior edge): sort within each row only
        order = np.r_[(np.argsort(len_cols.reshape(E, 6), axis=1, kind="stable") + 6 * np.arange(E)[:, None]).ravel(),
                      (np.argsort(ang_cols.reshape(-1, 12), axis=1, kind="stable")
                       + 6 * E + 12 * np.arange(len(ie))[:, None]).ravel()]
        indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=2 * E))]
        # value buffer of a block: row s holds local value s (0..5 length gradient, 6..17
        # angle gradient) of the block's edges, so value (s, e) sits at s * width + e - start
        blocks = _edge_blocks(topology)
        w = blocks["width"]
        len_src = (np.arange(6)[None, :] * w + (np.arange(E) % w)[:, None]).ravel()
        ang_src = ((6 + np.arange(12))[None, :] * w + (ie % w)[:, None]).ravel()
        gather = np.r_[len_src, ang_src][order]
        slices = []
        for (s0, s1), k0 in zip(blocks["ranges"], blocks["interior_before"], strict=True):
            k1 = k0 + np.count_nonzero(~topology.is_boundary_edge[s0:s1])
            slices.append((slice(6 * s0, 6 * s1), slice(6 * E + 12 * k0, 6 * E + 12 * k1)))
        out = {"order": order, "indices": cols[order].astype(np.int32), "indptr": indptr.astype(np.int32),
               "quad": quad, "shape": (2 * E, 3 * topology.n_vertices), "gather": gather, "slices": slices}
        for key in ("order", "indices", "indptr", "quad", "gather"):
            out[key].setflags(write=False)
        return out
    return topology.cache.get((__name__, "jacobian_pattern"), compute)


def _csr(data, pattern):
    """CSR matrix with ``data`` on a cached, canonical pattern (whose read-only index arrays it shares)."""
    J = sp.csr_matrix((data, pattern["indices"], pattern["indptr"]), shape=pattern["shape"])
    J.has_canonical_format = True
    return J


def _block_jacobian_values(e, a, b, n0, n1, lengths, B, s, t):
    """Local gradients of one edge block into ``B`` (18, n): rows 0-5 length, 6-17 angle (x0, x1, x2, x3).

    ``s, t`` are (n,) scratch rows.  See :func:`lengths_and_angles_jacobian` for the formulas.
    """
    # length rows: -u, u with u = e / l
    inv_l = np.divide(1.0, lengths, out=t)
    np.multiply(e, inv_l, out=B[3:6])
    np.negative(B[3:6], out=B[0:3])
    # angle rows: g2 = -l n0 / |n0|^2, g3 = -l n1 / |n1|^2
    g2, g3 = B[12:15], B[15:18]
    np.divide(lengths, _dot_rows(n0, n0, s), out=s)
    np.negative(s, out=s)
    np.multiply(n0, s, out=g2)
    np.divide(lengths, _dot_rows(n1, n1, s), out=s)
    np.negative(s, out=s)
    np.multiply(n1, s, out=g3)
    # t2 = <a, e> / l^2, t3 = <b, e> / l^2:  g1 = -t2 g2 - t3 g3,  g0 = (t2 - 1) g2 + (t3 - 1) g3
    inv_l *= inv_l
    np.multiply(_dot_rows(a, e, s), inv_l, out=s)
    np.multiply(_dot_rows(b, e, lengths), inv_l, out=t)      # lengths no longer needed
    g0, g1 = B[6:9], B[9:12]
    np.multiply(g2, s, out=g1)
    np.multiply(g3, t, out=g0)                                  # g0 used as scratch
    g1 += g0
    np.negative(g1, out=g1)
    s -= 1.0
    t -= 1.0
    np.multiply(g2, s, out=g0)
    g0 += np.multiply(g3, t, out=n0)                            # n0 no longer needed
    return B


def lengths_and_angles_jacobian(vertices, topology, return_z=False):
    """Analytic Jacobian ``dZ/dX`` as a ``(2E, 3V)`` CSR matrix.

    Rows ``0..E-1`` are the length gradients ``-+ (X_b - X_a) / l_e`` and rows
    ``E..2E-1`` the dihedral-angle gradients: for the opposite vertices
    ``x2`` (left face) and ``x3`` (right face)
    ``d theta / d x2 = -l_e n0 / |n0|^2``, ``d theta / d x3 = -l_e n1 / |n1|^2``
    (``n0, n1`` unnormalized face normals) and for the edge's end points
    ``d theta / d x0 = -(1 - t2) g2 - (1 - t3) g3``, ``d theta / d x1 = -t2 g2 - t3 g3``
    with ``t = <x - x0, e> / l_e^2`` the projection of the opposite vertices on the
    edge.  Boundary rows are empty.  The sparsity pattern is cached on the
    topology, so repeated calls only fill values; the returned matrices share
    its (read-only) index arrays.

    Parameters
    ----------
    vertices : (V, 3) array_like
    topology : MeshTopology
    return_z : bool
        Also return ``z = Z[X]`` (computed from the same intermediates).

    Returns
    -------
    J : scipy.sparse.csr_matrix, shape (2E, 3V)
    z : (2E,) ndarray, only if ``return_z``

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> J = lengths_and_angles_jacobian(X, topo)
    >>> J.shape
    (120, 66)
    >>> dX = 1e-7 * np.random.default_rng(0).standard_normal(X.shape)
    >>> dz = lengths_and_angles(X + dX, topo) - lengths_and_angles(X, topo)
    >>> bool(np.abs(J @ dX.ravel() - dz).max() < 1e-12)
    True
    """
    X = _as_vertices(vertices, topology.n_vertices)   # shape, NaN/inf: one-line MeshError
    k = safe_scale_exponent(X)
    if k:  # exact power-of-two scaling into the safe range: length rows invariant, angle rows scale by 2^-k
        out = lengths_and_angles_jacobian(np.ldexp(X, -k), topology, return_z)
        J = out[0] if return_z else out
        J.data[J.indptr[topology.n_edges]:] = np.ldexp(J.data[J.indptr[topology.n_edges]:], -k)
        if not return_z:
            return J
        z = out[1]
        z[:topology.n_edges] = np.ldexp(z[:topology.n_edges], k)
        return J, z
    pat = jacobian_pattern(topology)
    blocks = _edge_blocks(topology)
    E, w = topology.n_edges, blocks["width"]
    buf = scratch(topology, "dz", 46 * w)
    geometry_buf, values_buf = buf[:26 * w], buf[26 * w:]
    data = np.empty(len(pat["indices"]))
    z = np.empty(2 * E) if return_z else None
    Xc = _coordinates(X)
    gather = pat["gather"]
    for (s0, s1), (len_slice, ang_slice) in zip(blocks["ranges"], pat["slices"], strict=True):
        n = s1 - s0
        e, a, b, n0, n1, lengths, tmp = _block_geometry(Xc, blocks["stencil"][4 * s0:4 * s1], geometry_buf)
        if return_z:
            z[s0:s1] = lengths
            _dihedral_rows(b, n0, n1, lengths, z[E + s0:E + s1], tmp)
        B, s = carve(values_buf, (18, w), (w,))
        _block_jacobian_values(e, a, b, n0, n1, lengths, B[:, :n], s[:n], tmp)
        flat = B.reshape(-1)
        np.take(flat, gather[len_slice], out=data[len_slice], mode="wrap")
        np.take(flat, gather[ang_slice], out=data[ang_slice], mode="wrap")
    J = _csr(data, pat)
    if not return_z:
        return J
    bnd = topology.boundary_edges
    if bnd.size:
        z[E + bnd] = 0.0
    return J, z
