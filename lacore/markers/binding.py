"""Bindings of motion-capture markers to a triangle mesh and their surface points (data term of thesis (4.20)).

A marker ``m`` is bound to a point of face ``f_m`` given by barycentric
coordinates ``b_m`` (3,), lifted by ``o_m`` along the unit face normal::

    p_m(X) = sum_k b_mk X[F[f_m, k]] + o_m n_f(X),   n_f = c / |c|,  c = (X1 - X0) x (X2 - X0).

The face normal (not an interpolated vertex normal) is used: it depends only on
the three vertices of the bound face, so the Jacobian of ``p_m`` is one
``(3, 9)`` block and the data term keeps the sparsity of the mesh; its
derivative ``dn = (Id - n n^T) dc / |c|`` enters the Gauss-Newton system
(:func:`surface_point_jacobians`).  Real markers sit 5-10 mm off the skin
(positive ``o_m`` = outside for outward-oriented faces).

A vertex binding (the thesis' ``X_{i_m}`` (4.20)) is the surface point with
barycentric coordinates ``(1, 0, 0)`` on the lowest-numbered face containing
the vertex, the vertex in the first corner; its offset (if any) follows that
face's normal.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import InputError, format_indices
from ..geometry.lengths_angles import face_normals
from ..geometry.proximity import closest_point_barycentrics
from ..geometry.rigid import apply_rigid, rigid_fit
from ..progress import report

__all__ = ["MarkerBinding", "MarkerBindingError", "bind_markers", "closest_surface_points", "surface_points",
           "surface_point_jacobians"]


class MarkerBindingError(InputError):
    """A marker binding does not fit the mesh or the marker data (index out of range, unbound marker, counts)."""


@dataclass(frozen=True)
class MarkerBinding:
    """Where each of ``M`` markers sits on the mesh.

    Attributes
    ----------
    faces : (M,) int64 ndarray
        Bound face of every marker (index into the mesh's faces).
    barycentric : (M, 3) ndarray
        Barycentric coordinates in that face's corner order (sum 1).
    offsets : (M,) ndarray
        Distance along the unit face normal (same unit as the vertices).
    vertices : (M,) int64 ndarray or None
        For a binding made by :meth:`from_vertices`: the bound vertex of every marker.
    """

    faces: np.ndarray
    barycentric: np.ndarray
    offsets: np.ndarray
    vertices: np.ndarray = None

    @property
    def n_markers(self):
        """``M``."""
        return len(self.faces)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_vertices(cls, vertex_indices, mesh_faces, n_vertices=None, offsets=None):
        """Markers sitting on vertices (4.20), optionally lifted along a face normal.

        Parameters
        ----------
        vertex_indices : (M,) array_like of int
        mesh_faces : (F, 3) array_like of int
        n_vertices : int, optional
            Number of mesh vertices (default ``mesh_faces.max() + 1``).
        offsets : (M,) array_like, optional
            Default 0.

        Raises
        ------
        MarkerBindingError
            Non-integer or out-of-range indices, a negative index (marker bound
            to nothing), a vertex in no face, bad offsets.
        """
        F = np.asarray(mesh_faces, np.int64)
        nv = int(F.max()) + 1 if n_vertices is None else int(n_vertices)
        v = _as_index_array(vertex_indices, "vertex index")
        _check_range(v, nv, "vertex")
        first = np.full(nv, -1, np.int64)
        corner = np.zeros(nv, np.int64)
        flat = F.ravel()
        order = np.arange(len(flat))[::-1]  # assign in reverse so the lowest face wins
        first[flat[order]] = order // 3
        corner[flat[order]] = order % 3
        lonely = np.flatnonzero(first[v] < 0)
        if lonely.size:
            raise MarkerBindingError(f"markers {format_indices(lonely)} are bound to vertices in no face "
                                     f"({format_indices(v[lonely])}): bound to nothing")
        bary = np.zeros((len(v), 3))
        bary[np.arange(len(v)), corner[v]] = 1.0
        return cls(first[v], bary, _as_offsets(offsets, len(v)), v)

    @classmethod
    def from_surface(cls, faces, barycentric, offsets=None):
        """Markers on surface points ``(face, barycentric)``; checks shapes and finiteness (not the mesh)."""
        f = _as_index_array(faces, "face index")
        b = _as_reals(barycentric, "barycentric coordinates")
        if b.shape != (len(f), 3):
            raise MarkerBindingError(f"barycentric must have shape ({len(f)}, 3) for {len(f)} bound faces, "
                                     f"got {b.shape}")
        bad = np.flatnonzero(~np.isfinite(b).all(1) | (np.abs(b.sum(1) - 1.0) > 1e-6))
        if bad.size:
            raise MarkerBindingError(f"barycentric coordinates of markers {format_indices(bad)} are not finite or "
                                     "do not sum to 1")
        return cls(f, b.copy(), _as_offsets(offsets, len(f)), None)

    def check(self, mesh_faces, n_markers=None):
        """Raise :class:`MarkerBindingError` unless every bound face exists (and ``M == n_markers``)."""
        nf = len(mesh_faces)
        _check_range(self.faces, nf, "face")
        if n_markers is not None and int(n_markers) != self.n_markers:
            raise MarkerBindingError(f"the marker data has {n_markers} markers, the binding {self.n_markers}")
        return self

    def corner_vertices(self, mesh_faces):
        """Vertices of the bound faces, ``(M, 3)``."""
        return np.asarray(mesh_faces, np.int64)[self.faces]


def _as_reals(a, what):
    """``a`` as a float array; MarkerBindingError unless it holds real numbers."""
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiu":
        raise MarkerBindingError(f"{what} must be real numbers, got {arr.dtype} values")
    return arr.astype(float)


def _as_index_array(a, what):
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiu":
        raise MarkerBindingError(f"{what}es must be integers, got {arr.dtype} values")
    if arr.ndim != 1:
        raise MarkerBindingError(f"{what}es must be a 1-D array (one per marker), got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not (np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))):
            raise MarkerBindingError(f"{what}es must be integers")
    arr = arr.astype(np.int64)
    neg = np.flatnonzero(arr < 0)
    if neg.size:
        raise MarkerBindingError(f"markers {format_indices(neg)} are bound to nothing (negative {what})")
    return arr


def _check_range(idx, n, what):
    bad = np.flatnonzero(idx >= n)
    if bad.size:
        plural = {"vertex": "vertices"}.get(what, what + "s")
        raise MarkerBindingError(f"markers {format_indices(bad)} are bound to {plural} {format_indices(idx[bad])} "
                                 f"out of range (the mesh has {n} {plural})")


def _as_offsets(offsets, m):
    if offsets is None:
        return np.zeros(m)
    o = _as_reals(offsets, "offsets")
    if o.ndim == 0:
        o = np.full(m, float(o))
    if o.shape != (m,) or not np.all(np.isfinite(o)):
        raise MarkerBindingError(f"offsets must be {m} finite numbers (one per marker), got shape {o.shape}")
    return o.copy()


# --------------------------------------------------------------------------- geometry
def surface_points(vertices, mesh_faces, binding):
    """``p_m(X)`` of all markers, ``(M, 3)`` (or ``(T, M, 3)`` for vertices ``(T, V, 3)``)."""
    X = np.asarray(vertices, float)
    if X.ndim == 3:
        return np.stack([surface_points(x, mesh_faces, binding) for x in X])
    C = binding.corner_vertices(mesh_faces)
    P = np.einsum("mk,mkc->mc", binding.barycentric, X[C])
    if np.any(binding.offsets):
        n = face_normals(X, C)
        P += binding.offsets[:, None] * n
    return P


def _skew(v):
    """Cross-product matrices ``[v]_x`` of rows ``(..., 3) -> (..., 3, 3)``."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def surface_point_jacobians(vertices, mesh_faces, binding):
    """Jacobians of the surface points: ``(M, 3, 9)`` blocks on the coordinates of the bound faces' corners.

    Block ``G_m[:, 3 k + c] = d p_m / d X[F[f_m, k], c]``
    ``= b_mk e_c + o_m (Id - n n^T) / |c| dc/dX_k e_c`` with
    ``dc/dX_0 = [e_2 - e_1]_x``, ``dc/dX_1 = -[e_2]_x``, ``dc/dX_2 = [e_1]_x``
    (``e_1 = X_1 - X_0``, ``e_2 = X_2 - X_0``).

    Returns
    -------
    G : (M, 3, 9) ndarray
    dofs : (M, 9) int64 ndarray
        Global coordinate index ``3 v + c`` of every column.
    """
    X = np.asarray(vertices, float)
    C = binding.corner_vertices(mesh_faces)
    M = len(C)
    G = np.zeros((M, 3, 9))
    eye = np.eye(3)
    for k in range(3):
        G[:, :, 3 * k:3 * k + 3] = binding.barycentric[:, k, None, None] * eye
    lift = np.flatnonzero(binding.offsets != 0)
    if lift.size:
        P = X[C[lift]]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        c = np.cross(e1, e2)
        norm = np.linalg.norm(c, axis=1)
        n = c / norm[:, None]
        proj = (eye - n[:, :, None] * n[:, None, :]) * (binding.offsets[lift] / norm)[:, None, None]
        dc = (_skew(e2 - e1), -_skew(e2), _skew(e1))
        for k in range(3):
            G[lift, :, 3 * k:3 * k + 3] += proj @ dc[k]
    dofs = (3 * C[:, :, None] + np.arange(3)).reshape(M, 9)
    return G, dofs


# --------------------------------------------------------------------------- nearest surface points
def closest_surface_points(vertices, mesh_faces, points, chunk=2_000_000):
    """Nearest point of a triangle mesh to every query point (exhaustive, vectorized over faces).

    Per triangle the closest point is found by the Voronoi-region test of
    Ericson (:func:`lacore.geometry.proximity.closest_point_barycentrics`) for all (point, face) pairs
    in chunks of about ``chunk`` pairs; ``O(P F)`` work, fine for the few
    dozen markers of a motion-capture set.

    Returns
    -------
    closest : (P, 3) ndarray
    face : (P,) int64 ndarray
    barycentric : (P, 3) ndarray
        Of ``closest`` in ``face`` (non-negative, sum 1).
    """
    X = np.asarray(vertices, float)
    F = np.asarray(mesh_faces, np.int64)
    Q = np.atleast_2d(np.asarray(points, float))
    A, B, C = X[F[:, 0]], X[F[:, 1]], X[F[:, 2]]
    best_d = np.full(len(Q), np.inf)
    best_f = np.zeros(len(Q), np.int64)
    best_b = np.zeros((len(Q), 3))
    step = max(1, int(chunk) // max(1, len(F)))
    for s in range(0, len(Q), step):
        P = Q[s:s + step, None, :]                                  # (p, 1, 3)
        bc = np.nan_to_num(closest_point_barycentrics(P, A, B, C), nan=1.0 / 3.0)   # (p, F, 3)
        closest = bc[..., :1] * A + bc[..., 1:2] * B + bc[..., 2:] * C
        dist = np.einsum("pfc,pfc->pf", closest - P, closest - P)
        f = np.argmin(dist, axis=1)
        rows = np.arange(len(f))
        best_d[s:s + step] = dist[rows, f]
        best_f[s:s + step] = f
        best_b[s:s + step] = bc[rows, f]
    best_b = np.clip(best_b, 0.0, None)
    best_b /= best_b.sum(1, keepdims=True)
    closest = np.einsum("pk,pkc->pc", best_b, X[F[best_f]])
    return closest, best_f, best_b


# --------------------------------------------------------------------------- binding helper
#: ICP stops when the markers' RMS distance to their targets has not fallen by this fraction ...
ICP_RTOL = 1e-3
#: ... for this many iterations in a row, and keeps the placement with the smallest distance.
ICP_PATIENCE = 5


def bind_markers(vertices, mesh_faces, marker_positions, *, align=True, iterations=100, offsets="signed",
                 progress=None):
    """Bind markers to the nearest surface points of a mesh pose, after a rigid alignment.

    The markers (one frame, e.g. a calibration pose, roughly placed on the mesh)
    are moved rigidly onto the mesh by an iterative-closest-point loop (nearest
    surface points, then :func:`lacore.geometry.rigid.rigid_fit`) starting from where they
    are, then every marker is bound to its nearest surface point.  ICP is a
    local method: start within a few degrees and a fraction of the marker
    offsets of the right placement (ICP cannot tell a marker's offset from a
    misplacement: the targets are the nearest points lifted by the median
    signed distance, exact for markers sharing one offset; pass
    ``align=False`` for markers already in the mesh's frame).  It stops when
    the placement no longer changes, or when the markers' RMS distance to their
    targets has not fallen by :data:`ICP_RTOL` in :data:`ICP_PATIENCE`
    iterations (noisy markers or markers of different offsets, whose nearest
    points keep switching faces), with the placement of the smallest distance.

    Parameters
    ----------
    vertices : (V, 3) array_like
        The mesh pose.
    mesh_faces : (F, 3) array_like
    marker_positions : (M, 3) array_like
        Marker positions (finite; occluded markers cannot be bound).
    align : bool
        Rigidly align the markers first (default); False binds them where they are.
    iterations : int
        Maximal ICP iterations.
    offsets : {"signed", "zero"}
        ``"signed"``: offset = signed distance of the (aligned) marker from its
        surface point along the face normal (positive outside); ``"zero"``: 0.
    progress : callable, optional
        ``progress(done, total, message)`` after every ICP iteration (``total`` =
        ``iterations``) and when bound (:mod:`lacore.progress`; True cancels).

    Returns
    -------
    binding : MarkerBinding
    info : dict
        ``rotation`` (3, 3) and ``translation`` (3,) mapping the markers onto the
        mesh, ``offsets`` (M,), ``tangential`` (M,): distance of each aligned
        marker from the line through its surface point along the normal (0 if it
        sits straight above a face interior), ``iterations``: the ICP iterations
        run (nearest points and a rigid fit each; ``iterations`` when ICP ran to
        its limit, 0 without ``align``).
    """
    X = np.asarray(vertices, float)
    F = np.asarray(mesh_faces, np.int64)
    x = np.asarray(marker_positions, float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise MarkerBindingError(f"marker positions must have shape (M, 3), got {x.shape}")
    bad = np.flatnonzero(~np.isfinite(x).all(1))
    if bad.size:
        raise MarkerBindingError(f"markers {format_indices(bad)} have no finite position: cannot bind them")
    R, t = np.eye(3), np.zeros(3)
    total = int(iterations) if align else 1
    report(progress, 0, total, "aligning the markers" if align else "binding")
    done = 0
    if align:
        best, stalled = (np.inf, R, t), 0
        for it in range(int(iterations)):
            y = apply_rigid(x, R, t)
            q, tri, _ = closest_surface_points(X, F, y)
            n = face_normals(X, F[tri])
            lift = np.median(np.einsum("mc,mc->m", y - q, n))   # common marker offset, estimated
            target = q + lift * n
            rms = np.sqrt(np.mean(np.einsum("mc,mc->m", y - target, y - target)))
            if rms < (1.0 - ICP_RTOL) * best[0]:
                best, stalled = (rms, R, t), 0
            else:
                stalled += 1
                if stalled >= ICP_PATIENCE:  # noise or markers' own offsets: the nearest points keep switching
                    R, t = best[1], best[2]
                    break
            R_new, t_new = rigid_fit(x, target)
            done = it + 1
            report(progress, done, total, f"ICP iteration {done}")
            if np.allclose(R_new, R, atol=1e-10) and np.allclose(t_new, t, atol=1e-10 * (1 + np.abs(t).max())):
                R, t = R_new, t_new
                break
            R, t = R_new, t_new
    y = apply_rigid(x, R, t)
    q, tri, bary = closest_surface_points(X, F, y)
    n = face_normals(X, F[tri])
    d = y - q
    signed = np.einsum("mc,mc->m", d, n)
    o = signed if offsets == "signed" else np.zeros(len(x))
    binding = MarkerBinding.from_surface(tri, bary, o)
    tangential = np.linalg.norm(d - signed[:, None] * n, axis=1)
    report(progress, total, total, "bound")
    return binding, {"rotation": R, "translation": t, "offsets": o, "tangential": tangential, "iterations": done}
