"""The map X -> z = (edge lengths, signed dihedral angles) and its Jacobian (thesis 3.1, eq. 3.5).

Conventions
-----------
``z`` has shape ``(2E,)``: ``z[:E]`` are the edge lengths ``l_e`` and ``z[E:]`` the
dihedral angles ``theta_e`` in radians, ordered like ``topology.edges``.

The dihedral angle of an interior edge ``e = (a, b)`` (oriented as in
:mod:`lacore.topology`, left face ``f0`` traversing it from ``a`` to ``b``) is the
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
"""

import numpy as np
import scipy.sparse as sp

from .errors import LengthsAnglesError, format_indices
from .topology import check_vertices

__all__ = [
    "face_normals",
    "face_areas",
    "edge_lengths",
    "dihedral_angles",
    "lengths_and_angles",
    "lengths_and_angles_jacobian",
    "split_z",
    "check_z",
    "check_nondegenerate",
]


def _cross(a, b):
    """Row-wise cross product of two (N, 3) arrays (faster than np.cross for small N)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    out[:, 0] = a1 * b2 - a2 * b1
    out[:, 1] = a2 * b0 - a0 * b2
    out[:, 2] = a0 * b1 - a1 * b0
    return out


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def face_normals(vertices, faces, unit=True):
    """Face normals ``(X1 - X0) x (X2 - X0)`` (1.14), ``(F, 3)``; unnormalized (length ``2 a_f``) if ``unit=False``."""
    X = np.asarray(vertices, float)
    p0 = X[faces[:, 0]]
    n = _cross(X[faces[:, 1]] - p0, X[faces[:, 2]] - p0)
    if unit:
        n /= np.sqrt(_dot(n, n))[:, None]
    return n


def face_areas(vertices, faces):
    """Triangle areas ``(F,)``."""
    n = face_normals(vertices, faces, unit=False)
    return 0.5 * np.sqrt(_dot(n, n))


def check_nondegenerate(vertices, topology, rtol=1e-14):
    """Raise :class:`~lacore.errors.MeshError` naming triangles with (numerically) zero area."""
    from .errors import MeshError

    X = check_vertices(vertices, topology.n_vertices)
    n = face_normals(X, topology.faces, unit=False)
    area2 = np.sqrt(_dot(n, n))
    e = X[topology.edges[:, 1]] - X[topology.edges[:, 0]]
    scale = np.max(_dot(e, e)) if len(e) else 1.0
    bad = np.flatnonzero(~(area2 > rtol * scale))
    if bad.size:
        raise MeshError(f"degenerate triangles (zero area): faces {format_indices(bad)}")
    return X


def edge_lengths(vertices, topology):
    """Edge lengths ``(E,)``."""
    X = np.asarray(vertices, float)
    e = X[topology.edges[:, 1]] - X[topology.edges[:, 0]]
    return np.sqrt(_dot(e, e))


def dihedral_angles(vertices, topology):
    """Signed dihedral angles ``(E,)`` in radians (0 on boundary edges); see the module docstring."""
    X = np.asarray(vertices, float)
    return _lengths_angles(X, topology)[1]


def _lengths_angles(X, topology):
    edges = topology.edges
    e = X[edges[:, 1]] - X[edges[:, 0]]
    lengths = np.sqrt(_dot(e, e))
    n = face_normals(X, topology.faces, unit=False)
    theta = np.zeros(len(edges))
    ie = topology.interior_edges
    d = topology.dual_edges
    n0, n1 = n[d[:, 0]], n[d[:, 1]]
    y = _dot(_cross(n0, n1), e[ie]) / lengths[ie]
    theta[ie] = np.arctan2(y, _dot(n0, n1))
    return lengths, theta


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
    """
    X = check_vertices(vertices, topology.n_vertices) if check else np.asarray(vertices, float)
    lengths, theta = _lengths_angles(X, topology)
    return np.concatenate([lengths, theta])


def split_z(z, topology):
    """Split ``z`` into ``(lengths (E,), angles (E,))`` views after checking its size."""
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


def _jacobian_pattern(topology):
    """Fixed CSR sparsity pattern of dZ/dX, computed once per topology."""
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
        order = np.lexsort((cols, rows))
        indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=2 * E))]
        return {"order": order, "indices": cols[order].astype(np.int32),
                "indptr": indptr.astype(np.int32), "quad": quad,
                "shape": (2 * E, 3 * topology.n_vertices)}
    return topology._cached("z_jacobian_pattern", compute)


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
    topology, so repeated calls only fill values.

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
    """
    X = np.asarray(vertices, float)
    pat = _jacobian_pattern(topology)
    edges = topology.edges
    e = X[edges[:, 1]] - X[edges[:, 0]]
    lengths = np.sqrt(_dot(e, e))
    u = e / lengths[:, None]
    len_vals = np.concatenate([-u, u], axis=1)

    ie = topology.interior_edges
    quad = pat["quad"]
    x0, x1, x2, x3 = X[quad[:, 0]], X[quad[:, 1]], X[quad[:, 2]], X[quad[:, 3]]
    ei = e[ie]
    le = lengths[ie]
    n0 = _cross(x1 - x0, x2 - x0)
    n1 = _cross(x0 - x1, x3 - x1)
    n0sq, n1sq = _dot(n0, n0), _dot(n1, n1)
    g2 = n0 * (-le / n0sq)[:, None]
    g3 = n1 * (-le / n1sq)[:, None]
    inv_le2 = 1.0 / (le * le)
    t2 = (_dot(x2 - x0, ei) * inv_le2)[:, None]
    t3 = (_dot(x3 - x0, ei) * inv_le2)[:, None]
    g0 = -(1.0 - t2) * g2 - (1.0 - t3) * g3
    g1 = -t2 * g2 - t3 * g3
    ang_vals = np.concatenate([g0, g1, g2, g3], axis=1)

    data = np.concatenate([len_vals.ravel(), ang_vals.ravel()])[pat["order"]]
    J = sp.csr_matrix((data, pat["indices"], pat["indptr"]), shape=pat["shape"])
    if not return_z:
        return J
    theta = np.zeros(len(edges))
    theta[ie] = np.arctan2(_dot(_cross(n0, n1), ei) / le, _dot(n0, n1))
    return J, np.concatenate([lengths, theta])
