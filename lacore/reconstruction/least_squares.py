"""Least-squares relaxation of the frame-based reconstruction (thesis 3.4.2, (3.31)-(3.33); Wang, Liu, Tong 2012).

Instead of enforcing ``F_j = F_i R_ij`` (3.28) and the edge vectors (3.29)
exactly along a tree, both are required in the least-squares sense over the
whole mesh:

* frame energy (3.31)  ``E_F(F) = 1/2 sum_{dual edges (i, j)} w_ij |F_j - F_i R_ij(z*)|_F^2``;
* edge energy (3.32)   ``E_E(X, F) = 1/2 sum_{faces k} sum_{half-edges a->b of k} w_ab |X_b - X_a - F_k a_ab^k|^2``
  with ``a_ab^k = l*_ab (cos phi, sin phi, 0)`` the half-edge in its face's
  standard frame (:func:`lacore.integrability.local.edge_frame_angles`).

Two methods:

``"two_step"`` (default, as in Lipman et al. 2005)
    Minimize ``E_F`` over the nine entries of every frame with the root
    face's frame fixed (the three rows of the frames decouple into three
    right-hand sides of one ``3F x 3F`` system), project every frame to the
    nearest rotation (:func:`nearest_rotations`, ``det = +1``), then minimize ``E_E`` over ``X`` with the
    root face's first vertex fixed.  The position system is a weighted graph
    Laplacian that depends only on the connectivity and the weights: it is
    factorized once per (topology, weights, fixed vertices) and cached on the
    topology, so only the frame system is factorized per call.
``"composite"`` (3.33)
    Minimize ``frame_weight E_F + E_E`` jointly over ``(X, F)`` (one
    ``(V + 3F)`` system with three right-hand sides, no projection).

Weights: ``edge_weights`` (per primal edge, default 1 = uniform) are used for
both energies (dual edge = its primal edge).  Cotan weights as in [WLT12] may be
passed, but must be positive.

Both reproduce admissible targets exactly (zero energy at the true
immersion, whose frames and vertices are then the unique minimizers); for
non-admissible targets the mismatch is spread over the whole mesh instead of
being concentrated where tree paths meet.  Triangles violating the triangle
inequality get interior angles 0 as everywhere in lacore.

Sparse solvers: :class:`lacore.linalg.sparse_cholesky.SparseCholesky` (CHOLMOD through
``cvxopt`` if importable, else SuperLU); the symbolic analysis of the frame
system and the whole factorization of the position system are cached on the
topology (at most four weight/root combinations).  The cached frame solver
holds one numeric factorization at a time: do not call this module for the
same topology from several threads at once.
"""

import hashlib

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, MeshError
from ..integrability.transitions import edge_frame_angles, standard_frames, transition_rotations
from ..geometry.lengths_angles import check_z
from ..linalg.sparse_cholesky import SparseCholesky
from ..geometry.topology import check_vertices
from ..geometry.trigonometry import interior_angles
from .spanning_trees import check_roots_per_component, default_root_faces

__all__ = ["least_squares_reconstruction", "least_squares_start", "least_squares_frames", "nearest_rotations"]

_MAX_CACHED_FACTORS = 4


# --------------------------------------------------------------------------- helpers
def _check_weights(topology, edge_weights):
    if edge_weights is None:
        return None, "uniform"
    w = np.asarray(edge_weights, float)
    if w.shape != (topology.n_edges,):
        raise InputError(f"edge_weights must have shape ({topology.n_edges},) (one per edge), got {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise InputError("edge_weights must be finite and positive")
    return w, hashlib.sha1(w.tobytes()).hexdigest()


def _roots_and_placement(z, topology, root_face, reference_vertices):
    if root_face is None:
        roots = default_root_faces(topology, z=z, vertices=reference_vertices)
    else:
        roots = np.atleast_1d(np.asarray(root_face)).astype(np.int64)
        check_roots_per_component(topology, roots)
    C = len(roots)
    if reference_vertices is not None:
        frames = standard_frames(reference_vertices, topology.faces[roots])
        pos = reference_vertices[topology.faces[roots, 0]]
    else:
        frames = np.broadcast_to(np.eye(3), (C, 3, 3))
        pos = np.zeros((C, 3))
    return roots, np.asarray(frames), np.asarray(pos)


def _local_half_edges(z, topology):
    """Half-edge vectors in their faces' standard frames, ``(F, 3, 2)`` (third component 0)."""
    E = topology.n_edges
    L = z[:E][topology.face_edges]
    phi = edge_frame_angles(interior_angles(L))
    return np.stack([L * np.cos(phi), L * np.sin(phi)], axis=-1)


def _incidence(topology):
    """Half-edge incidence ``D`` (3F x V): row ``3 f + i`` is ``X[to] - X[from]`` of half-edge ``i`` of ``f``."""
    def compute():
        F, V = topology.n_faces, topology.n_vertices
        fr = topology.faces[:, [1, 2, 0]].ravel()
        to = topology.faces[:, [2, 0, 1]].ravel()
        rows = np.repeat(np.arange(3 * F), 2)
        cols = np.stack([fr, to], 1).ravel()
        vals = np.tile([-1.0, 1.0], 3 * F)
        return sp.csr_matrix((vals, (rows, cols)), shape=(3 * F, V))
    return topology.cache.get((__name__, "incidence"), compute)


def _factor_cache(topology):
    return topology.cache.get((__name__, "factors"), dict)


def _remember(cache, key, value):
    cache[key] = value
    while len(cache) > _MAX_CACHED_FACTORS:
        cache.pop(next(iter(cache)))
    return value


def _position_system(topology, w, wkey, fixed):
    """Cached factorization of the position Laplacian ``D^T W D`` with ``fixed`` vertices eliminated."""
    cache = _factor_cache(topology)
    key = ("positions", wkey, tuple(fixed.tolist()))
    if key in cache:
        return cache[key]
    D = _incidence(topology)
    wh = np.ones(3 * topology.n_faces) if w is None else w[topology.face_edges].ravel()
    DtW = (D.T @ sp.diags(wh)).tocsr()
    Lap = (DtW @ D).tocsr()
    V = topology.n_vertices
    free = np.setdiff1d(np.arange(V), fixed)
    entry = {
        "free": free,
        "G": DtW[free],                          # (V_free, 3F): right-hand side from the half-edge vectors
        "Lfr": Lap[free][:, fixed],              # coupling to the fixed vertices
        "solver": _factorized(Lap[free][:, free]),
    }
    return _remember(cache, key, entry)


def _frame_pattern(topology, roots, w, wkey):
    """z-independent structure of the frame system (3.31) with the root frames eliminated."""
    cache = _factor_cache(topology)
    key = ("frame_pattern", wkey, tuple(roots.tolist()))
    if key in cache:
        return cache[key]
    F = topology.n_faces
    d = topology.dual_edges
    ie = topology.interior_edges
    wd = np.ones(len(ie)) if w is None else w[ie]
    deg = np.bincount(d.ravel(), weights=np.repeat(wd, 2), minlength=F)
    unknown = np.full(3 * F, -1, np.int64)
    is_root = np.zeros(F, bool)
    is_root[roots] = True
    free_faces = np.flatnonzero(~is_root)
    unknown[(3 * free_faces[:, None] + np.arange(3)).ravel()] = np.arange(3 * len(free_faces))
    a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    # off-diagonal block entries (i, j) = -w R[a, b] and (j, i) = -w R[a, b] (transposed block)
    r_ij = 3 * d[:, 0, None, None] + a
    c_ij = 3 * d[:, 1, None, None] + b
    rows = np.concatenate([r_ij.ravel(), c_ij.ravel()])
    cols = np.concatenate([c_ij.ravel(), r_ij.ravel()])
    ur, uc = unknown[rows], unknown[cols]
    mat = (ur >= 0) & (uc >= 0)
    rhs = (ur >= 0) & (uc < 0)
    n = 3 * len(free_faces)
    diag = np.repeat(deg[free_faces], 3)
    lower = mat & (ur >= uc)
    pattern = sp.csc_matrix((np.ones(lower.sum()), (ur[lower], uc[lower])), shape=(n, n))
    chol = SparseCholesky(pattern)
    # slots of the diagonal and of the lower off-diagonal entries in the solver's value array
    keys = np.repeat(np.arange(n), np.diff(chol.indptr)) * n + chol.indices
    slot_lower = np.searchsorted(keys, uc[lower] * n + ur[lower])
    entry = {"lower": lower, "rhs": rhs, "ur": ur, "uc": uc, "cols": cols, "wd": wd, "diag": diag, "n": n,
             "free_faces": free_faces, "chol": chol, "slot_lower": slot_lower}
    return _remember(cache, key, entry)


def _factorized(A):
    """A SparseCholesky factorization of the SPD matrix ``A``."""
    return SparseCholesky(A).factorize(A)


def least_squares_frames(z, topology, roots, root_frames, edge_weights=None):
    """Frames minimizing (3.31) with the root frames fixed, projected to SO(3), ``(F, 3, 3)``.

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    roots : (C,) int array
        One fixed face per connected component.
    root_frames : (C, 3, 3) array_like
        Their (fixed) frames.
    edge_weights : (E,) array_like, optional
        Weights of the dual edges (by primal edge); default 1.
    """
    z = check_z(z, topology)
    w, wkey = _check_weights(topology, edge_weights)
    roots = np.asarray(roots, np.int64)
    pat = _frame_pattern(topology, roots, w, wkey)
    R = transition_rotations(z, topology)                       # (E_int, 3, 3), F_right = F_left R
    vals = -(pat["wd"][:, None, None] * R).ravel()
    vals = np.r_[vals, vals]
    n = pat["n"]
    chol = pat["chol"]
    values = np.bincount(pat["slot_lower"], weights=vals[pat["lower"]], minlength=chol.nnz)
    values[chol.diagonal] += pat["diag"]
    # fixed unknowns: u_root^r = row r of the root frame, stored at 3 f + c
    fixed_vals = np.zeros((3 * topology.n_faces, 3))
    Rf = np.asarray(root_frames, float)
    for k, f in enumerate(roots):
        fixed_vals[3 * f:3 * f + 3] = Rf[k].T                    # column r = row r of the frame
    B = np.zeros((n, 3))
    rr = pat["rhs"]
    np.add.at(B, pat["ur"][rr], -vals[rr, None] * fixed_vals[pat["cols"][rr]])
    U = chol.factorize(values).solve(B)                   # (n, 3): column r holds the rows r of the frames
    frames = np.empty((topology.n_faces, 3, 3))
    frames[pat["free_faces"]] = U.reshape(-1, 3, 3).transpose(0, 2, 1)
    frames[roots] = Rf
    return nearest_rotations(frames)


# cofactor matrix of a 3x3 matrix stored row-major as 9 rows: C[k] = A[p1] A[p2] - A[q1] A[q2]
_COF = np.array([[4, 8, 5, 7], [5, 6, 3, 8], [3, 7, 4, 6],
                 [2, 7, 1, 8], [0, 8, 2, 6], [1, 6, 0, 7],
                 [1, 5, 2, 4], [2, 3, 0, 5], [0, 4, 1, 3]]).T


def nearest_rotations(M, tol=1e-15, max_iter=30):
    """Nearest rotation matrices (Frobenius norm) of ``(n, 3, 3)`` matrices.

    Scaled Newton iteration for the orthogonal polar factor,
    ``R <- (g R + R^{-T} / g) / 2`` with Higham's scaling
    ``g = (|R^{-T}|_F / |R|_F)^{1/2}`` and ``R^{-T} = cof(R) / det(R)`` in closed form,
    vectorized over all matrices (a few passes over ``(9, n)`` arrays per
    iteration instead of one LAPACK SVD per matrix).  Matrices with
    ``det <= 0`` or nearly singular ones use the SVD
    (``U diag(1, 1, det(U V^T)) V^T``).
    """
    M = np.asarray(M, float)
    n = len(M)
    A = np.ascontiguousarray(M.reshape(n, 9).T)                # (9, n), row-major entries
    C = A[_COF[0]] * A[_COF[1]] - A[_COF[2]] * A[_COF[3]]
    det = np.einsum("kn,kn->n", A[:3], C[:3])
    norm = np.sqrt(np.einsum("kn,kn->n", A, A))
    ok = det > 1e-8 * norm ** 3
    idx = np.flatnonzero(ok)
    R = A[:, idx]
    for _ in range(max_iter):
        C = R[_COF[0]] * R[_COF[1]] - R[_COF[2]] * R[_COF[3]]
        d = np.einsum("kn,kn->n", R[:3], C[:3])
        C /= d                                                 # R^{-T}
        g = np.sqrt(np.sqrt(np.einsum("kn,kn->n", C, C) / np.einsum("kn,kn->n", R, R)))
        new = R * (0.5 * g)
        new += C * (0.5 / g)
        change = np.abs(new - R).max() if new.size else 0.0
        R = new
        if change < tol:
            break
    out = np.empty((n, 3, 3))
    out[idx] = R.T.reshape(-1, 3, 3)
    bad = np.flatnonzero(~ok)
    if bad.size:
        u, _, vt = np.linalg.svd(M[bad])
        flip = np.linalg.det(u @ vt) < 0
        u[flip, :, 2] *= -1.0
        out[bad] = u @ vt
    return out


def least_squares_start(z, topology, context):
    """The relaxation of ``z`` as a reconstruction with ``context``: its fixed faces and units, its output frame.

    Parameters
    ----------
    z : (2E,) ndarray
        Validated target (the caller's units).
    topology : MeshTopology
    context : ReconstructionContext

    Returns
    -------
    (V, 3) ndarray
        In the caller's units, the fixed faces placed as the reference has them
        (a fixed face that is degenerate here keeps the relaxation's placement).
    """
    X = least_squares_reconstruction(context.internal_z(z), topology, root_face=context.fixed_faces,
                                     reference_vertices=context.internal_reference)
    return context.align(context.external_vertices(X), keep_degenerate=True)


def least_squares_reconstruction(z, topology, frame_weight=1.0, edge_weights=None, root_face=None,
                                 reference_vertices=None, method="two_step"):
    """Linear least-squares reconstruction (3.31)-(3.33).

    Parameters
    ----------
    z : (2E,) array_like
        Target lengths and angles; need not be admissible.
    topology : MeshTopology
    frame_weight : float
        Weight ``w`` of the frame energy in the composite energy (3.33); unused
        by ``"two_step"`` (scaling one energy does not change its minimizer).
    edge_weights : (E,) array_like, optional
        Positive weights per primal edge for both energies; default uniform (1).
    root_face : int or sequence of int, optional
        Fixed face per connected component (frame and first vertex); default
        :func:`~.spanning_trees.default_root_faces`.
    reference_vertices : (V, 3) array_like, optional
        Fix the root frame and vertex as in this mesh (output in its frame);
        otherwise identity frame at the origin.
    method : {"two_step", "composite"}

    Returns
    -------
    (V, 3) ndarray

    Raises
    ------
    LengthsAnglesError
        For a ``z`` of the wrong size, with NaN/inf or non-positive lengths.
    MeshError
        For bad reference vertices or root faces.
    ValueError
        For bad weights or an unknown method.
    """
    z = check_z(z, topology)
    if reference_vertices is not None:
        reference_vertices = check_vertices(reference_vertices, topology.n_vertices, "reference_vertices")
    if method not in ("two_step", "composite"):
        raise InputError(f"method must be 'two_step' or 'composite', got {method!r}")
    if not (np.isfinite(frame_weight) and frame_weight > 0):
        raise InputError(f"frame_weight must be positive, got {frame_weight}")
    w, wkey = _check_weights(topology, edge_weights)
    roots, root_frames, root_pos = _roots_and_placement(z, topology, root_face, reference_vertices)
    fixed = topology.faces[roots, 0]
    if method == "composite":
        X = _composite(z, topology, roots, root_frames, fixed, root_pos, w, float(frame_weight))
    else:
        frames = least_squares_frames(z, topology, roots, root_frames, w)
        local = _local_half_edges(z, topology)                                  # (F, 3, 2)
        hvec = np.einsum("fcd,fid->fic", frames[:, :, :2], local).reshape(-1, 3)
        sysp = _position_system(topology, w, wkey, fixed)
        rhs = sysp["G"] @ hvec - sysp["Lfr"] @ root_pos
        X = np.empty((topology.n_vertices, 3))
        X[fixed] = root_pos
        X[sysp["free"]] = sysp["solver"].solve(rhs)
    unused = np.setdiff1d(np.arange(topology.n_vertices), topology.faces.ravel())
    if unused.size:
        X[unused] = reference_vertices[unused] if reference_vertices is not None else 0.0
    return X


def _composite(z, topology, roots, root_frames, fixed, root_pos, w, frame_weight):
    """Joint minimizer of ``frame_weight E_F + E_E`` (3.33) over positions and frame rows."""
    F, V = topology.n_faces, topology.n_vertices
    ie = topology.interior_edges
    d = topology.dual_edges
    wd = np.ones(len(ie)) if w is None else w[ie]
    wh = np.ones(3 * F) if w is None else w[topology.face_edges].ravel()
    R = transition_rotations(z, topology)
    # frame Laplacian (connection Laplacian) on the rows u^r of the frames, 3F x 3F
    a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    r_ij = (3 * d[:, 0, None, None] + a).ravel()
    c_ij = (3 * d[:, 1, None, None] + b).ravel()
    off = -(wd[:, None, None] * R).ravel()
    deg = np.repeat(np.bincount(d.ravel(), weights=np.repeat(wd, 2), minlength=F), 3)
    diag = np.arange(3 * F)
    AF = sp.csr_matrix((np.r_[deg, off, off], (np.r_[diag, r_ij, c_ij], np.r_[diag, c_ij, r_ij])), shape=(3 * F, 3 * F))
    # half-edge h = 3 f + i:  X_to - X_from - a_h . u_f^r,  a_h = local vector in frame coordinates
    local = _local_half_edges(z, topology).reshape(-1, 2)
    h = np.arange(3 * F)
    fh = h // 3
    Ahat = sp.csr_matrix((local.ravel(), (np.repeat(h, 2), (3 * fh[:, None] + np.arange(2)).ravel())),
                         shape=(3 * F, 3 * F))
    D = _incidence(topology)
    W = sp.diags(wh)
    K = sp.hstack([D, -Ahat]).tocsr()                            # residual operator on (X^r, u^r)
    M = (K.T @ W @ K + sp.block_diag([sp.csr_matrix((V, V)), frame_weight * AF])).tocsr()
    n = V + 3 * F
    fixed_idx = np.r_[fixed, V + (3 * roots[:, None] + np.arange(3)).ravel()]
    fixed_val = np.zeros((len(fixed_idx), 3))
    fixed_val[:len(fixed)] = root_pos
    fixed_val[len(fixed):] = np.concatenate([rf.T for rf in root_frames])
    free = np.setdiff1d(np.arange(n), fixed_idx)
    Mf = M[free]
    rhs = -(Mf[:, fixed_idx] @ fixed_val)
    sol = _factorized(Mf[:, free]).solve(rhs)
    full = np.empty((n, 3))
    full[fixed_idx] = fixed_val
    full[free] = sol
    if not np.all(np.isfinite(full)):
        raise MeshError("the composite least-squares system is singular (is the mesh connected to its root faces?)")
    return full[:V]
