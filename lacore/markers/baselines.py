"""The baseline a user would otherwise reach for: a PCA model in vertex positions fitted to markers.

:class:`VertexPCA` is linear PCA of training poses after generalized Procrustes
alignment (each pose rigidly aligned to the current mean by
:func:`lacore.geometry.rigid.rigid_fit`, repeated); :func:`fit_markers_vertex_pca` fits
``X = (mu + sum_k c_k sigma_k P_k) R^T + t`` to the markers with the same data
term as :func:`lacore.markers.fitting.fit_markers` (surface points with normal
offsets, NaN markers dropped) and a Tikhonov term ``lambda |c|^2`` on the
whitened coefficients (a Gaussian prior), by Gauss-Newton in ``(c, R, t)``
(rotation updated by the exponential map), every frame warm-started from the
previous one and the first from a Kabsch fit of the mean.
"""

import time

import numpy as np
from scipy.spatial.transform import Rotation

from .binding import surface_point_jacobians, surface_points
from ..geometry.rigid import apply_rigid, rigid_align, rigid_fit

__all__ = ["VertexPCA", "fit_markers_vertex_pca"]


class VertexPCA:
    """Linear PCA of vertex positions after generalized Procrustes alignment.

    Attributes
    ----------
    mean : (V, 3) ndarray
    modes : (K, V, 3) ndarray
        Orthonormal (as ``3V``-vectors) principal directions.
    std : (K,) ndarray
        Standard deviation of the training poses along each mode.
    """

    def __init__(self, mean, modes, std):
        self.mean, self.modes, self.std = mean, modes, std

    @property
    def n_modes(self):
        return len(self.std)

    @classmethod
    def fit(cls, poses, n_modes=None, procrustes_iterations=5):
        """PCA of ``poses (N, V, 3)`` after Procrustes alignment; ``n_modes`` default ``N - 1``."""
        X = np.asarray(poses, float)
        N = len(X)
        mu = X[0]
        for _ in range(int(procrustes_iterations)):
            A = np.stack([rigid_align(x, mu) for x in X])
            mu = A.mean(0)
        D = (A - mu).reshape(N, -1)
        _, s, Vt = np.linalg.svd(D, full_matrices=False)
        K = N - 1 if n_modes is None else int(n_modes)
        return cls(mu, Vt[:K].reshape(K, -1, 3), s[:K] / np.sqrt(N))

    def shape(self, c):
        """``mu + sum_k c_k sigma_k P_k``, ``(V, 3)``."""
        return self.mean + np.einsum("k,k,kvc->vc", c, self.std, self.modes)


def fit_markers_vertex_pca(pca, markers, mesh_faces, binding, *, tikhonov=1.0, iterations=20, ftol=1e-8):
    """Fit a :class:`VertexPCA` to markers, frame by frame (same data term as :func:`fit_markers`).

    Minimizes ``sum_{m visible} |p_m(X) - x_m|^2 + tikhonov |c|^2`` over the
    whitened coefficients ``c`` (K,) and the rigid motion of
    ``X = shape(c) R^T + t``.

    Returns
    -------
    dict with ``vertices (T, V, 3)``, ``coefficients (T, K)``, ``seconds``, ``iterations (T,)``.
    """
    x_all = np.asarray(markers, float)
    T = len(x_all)
    K = pca.n_modes
    F = np.asarray(mesh_faces)
    C = F[binding.faces]                                             # (M, 3) corner vertices
    Pc = pca.std[:, None, None, None] * pca.modes[:, C]               # (K, M, 3, 3) whitened modes at corners
    c = np.zeros(K)
    R, t = np.eye(3), np.zeros(3)
    first = True
    out = np.empty((T,) + pca.mean.shape)
    coeffs = np.empty((T, K))
    its = np.zeros(T, np.int64)
    t0 = time.perf_counter()

    def energy(cc, RR, tt, x, vis):
        X = apply_rigid(pca.shape(cc), RR, tt)
        r = surface_points(X, F, binding)[vis] - x[vis]
        return float(np.sum(r * r) + tikhonov * cc @ cc), X

    for f in range(T):
        x = x_all[f]
        vis = np.flatnonzero(np.isfinite(x[:, 0]))
        if len(vis) >= 3:
            R0, t0r = rigid_fit(surface_points(apply_rigid(pca.shape(c), R, t), F, binding)[vis], x[vis])
            R, t = R0 @ R, R0 @ t + t0r
        elif first and len(vis):
            t = t + x[vis].mean(0) - surface_points(apply_rigid(pca.shape(c), R, t), F, binding)[vis].mean(0)
        first = False
        E, X = energy(c, R, t, x, vis)
        mu = 1e-6
        for it in range(int(iterations)):
            G, _ = surface_point_jacobians(X, F, binding)             # (M, 3, 9)
            G = G[vis].reshape(len(vis), 3, 3, 3)                     # (m, 3 out, 3 corners, 3 coords)
            r = surface_points(X, F, binding)[vis] - x[vis]
            # d X_corner / d c_k = R (sigma_k P_k); / d omega = -[X - t]_x (rotation about t); / d t = Id
            dXc = np.einsum("ij,kmaj->kmai", R, Pc[:, vis])           # (K, m, 3 corners, 3)
            Jc = np.einsum("moaj,kmaj->mok", G, dXc)                  # (m, 3, K)
            Y = X[C[vis]] - t                                         # (m, 3 corners, 3)
            skew = np.zeros(Y.shape + (3,))
            skew[..., 0, 1], skew[..., 0, 2] = Y[..., 2], -Y[..., 1]
            skew[..., 1, 0], skew[..., 1, 2] = -Y[..., 2], Y[..., 0]
            skew[..., 2, 0], skew[..., 2, 1] = Y[..., 1], -Y[..., 0]   # -[Y]_x
            Jw = np.einsum("moaj,majl->mol", G, skew)                 # (m, 3, 3)
            Jt = G.sum(2)                                             # (m, 3, 3)
            Jm = np.concatenate([Jc, Jw, Jt], axis=2).reshape(-1, K + 6)
            H = Jm.T @ Jm
            H[:K, :K] += tikhonov * np.eye(K)
            g = Jm.T @ r.ravel()
            g[:K] += tikhonov * c
            while True:
                step = np.linalg.solve(H + mu * np.diag(np.diag(H) + 1e-12), -g)
                cn = c + step[:K]
                # rotation about the current translation point: X' = exp(w) (X - t) + t + dt
                Rn = Rotation.from_rotvec(step[K:K + 3]).as_matrix() @ R
                tn = t + step[K + 3:]
                En, Xn = energy(cn, Rn, tn, x, vis)
                if En <= E or mu > 1e6:
                    break
                mu *= 10
            its[f] = it + 1
            if En > E:
                break
            dec = E - En
            c, R, t, E, X = cn, Rn, tn, En, Xn
            mu = max(mu / 10, 1e-9)
            if dec <= ftol * max(E, 1e-300):
                break
        out[f], coeffs[f] = X, c
    return {"vertices": out, "coefficients": coeffs, "seconds": time.perf_counter() - t0, "iterations": its}
