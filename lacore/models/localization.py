"""Localized modes of a shape model: a group varimax rotation in the metric ``g`` (beyond the thesis).

The thesis names sparse PCA as future work for modes that move one part of the
body at a time; :func:`localized` rotates the modes within their span toward
locality instead (the span, the synthesized poses and the fit of any pose are
unchanged).  :func:`localized` and :func:`region_energy` are the methods of the
same names of :class:`~lacore.models.shape_model.ShapeModel`.
"""

import copy
import time

import numpy as np
import scipy.sparse as sp

from .settings import ShapeModelError

__all__ = ["localized", "region_energy"]


def localized(model, regions=None, n_starts=3, max_iterations=500, tol=1e-10, seed=0):
    """The same subspace with modes rotated toward locality (beyond the thesis: its "Sparse PCA" outlook).

    A *group varimax* rotation in the metric ``g``: with the ``g``-unit
    loadings ``L = U sqrt(M)`` (rows orthonormal) and the energy of mode
    ``j`` in region ``r``, ``e_jr = sum_{k in r} L'_jk^2`` (``sum_r e_jr = 1``),
    find the rotation ``R`` (``J x J`` orthogonal, ``U' = R U``) maximizing
    ``sum_j sum_r e_jr^2``: each mode's energy gathered in as few regions as
    possible.  Maximized by the usual varimax iteration ``R <- polar(grad)``
    (monotone for this convex objective) from the identity and from
    ``n_starts - 1`` random rotations (the best is kept: symmetric data make
    the PCA modes a stationary point).  The span, the synthesized poses
    and the fit of any pose are unchanged; the modes are no longer
    uncorrelated over the training set.

    Parameters
    ----------
    regions : (V,) or (2E,) array_like of int, optional
        Region label per vertex (an entry of ``z`` then counts half for
        each end vertex of its edge) or per entry of ``z``.  Default: every
        vertex its own region (locality on the scale of a one-ring).
    n_starts : int
        Starting rotations (default 3).
    max_iterations : int
        Per start.
    tol : float
        Stop when the objective grows by less than ``tol`` (relative).
    seed : int
        Seed of the random starts.

    Returns
    -------
    ShapeModel
        A copy with rotated ``modes``, ``training_coefficients`` (``C R^T``),
        ``variances`` (mean squared coefficients), ``explained_variance_ratio``
        (of the total), sorted by variance; ``rotation`` ``(J, J)`` and
        ``localization`` (the objective before and after, iterations) set.
    """

    t0 = time.perf_counter()
    G = _region_matrix(model, regions)
    L = model.modes * np.sqrt(model.metric_weights)  # (J, 2E), orthonormal rows
    J = model.n_modes
    rng = np.random.default_rng(seed)
    best, best_f, iterations = None, -np.inf, []
    for start in range(max(1, int(n_starts))):
        # the identity, then random rotations: symmetric data make the PCA modes a stationary point
        R = np.eye(J) if start == 0 else np.linalg.qr(rng.normal(size=(J, J)))[0]
        last = -np.inf
        it = 0
        while it < int(max_iterations):
            it += 1
            Lr = R @ L
            e = (G @ (Lr * Lr).T).T  # (J, n_regions)
            f = float(np.sum(e * e))
            if f - last <= tol * abs(f):
                break
            last = f
            grad = (4.0 * (e @ G) * Lr) @ L.T  # d f / d R, (J, J)
            u, _, vt = np.linalg.svd(grad)
            R = u @ vt
        iterations.append(it)
        if last > best_f * (1 + 1e-9):
            best, best_f = R, last
    R = best
    it = iterations
    Lr = R @ L
    e0 = (G @ (L * L).T).T
    e1 = (G @ (Lr * Lr).T).T
    coeffs = model.training_coefficients @ R.T
    var = np.mean(coeffs**2, axis=0)
    order = np.argsort(-var, kind="stable")
    R, coeffs, var = R[order], coeffs[:, order], var[order]
    modes = R @ model.modes
    # sign: the largest g-scaled entry positive, as in fit
    k = np.argmax(np.abs(modes) * np.sqrt(model.metric_weights), axis=1)
    sign = np.where(modes[np.arange(J), k] < 0, -1.0, 1.0)
    R *= sign[:, None]
    modes *= sign[:, None]
    coeffs *= sign[None, :]
    out = copy.copy(model)
    out.modes = modes
    out.training_coefficients = coeffs
    out.variances = var
    out.explained_variance_ratio = var / model.total_variance
    out.rotation = R
    out.localization = {"objective_before": float(np.sum(e0 * e0)), "objective_after": float(np.sum(e1 * e1)),
                        "iterations": it, "seconds": time.perf_counter() - t0}
    return out


def _region_matrix(model, regions):
    """Sparse ``(n_regions, 2E)`` 0/0.5/1 matrix summing entries of ``z`` per region."""
    topo = model.topology
    E, V = topo.n_edges, topo.n_vertices
    if regions is None:
        regions = np.arange(V)
    regions = np.asarray(regions)
    if regions.shape == (V,):
        lab = regions[topo.edges]  # (E, 2)
        cols = np.tile(np.arange(2 * E), 2)
        rows = np.concatenate([np.tile(lab[:, 0], 2), np.tile(lab[:, 1], 2)])
        vals = np.full(len(rows), 0.5)
    elif regions.shape == (2 * E,):
        rows, cols, vals = regions, np.arange(2 * E), np.ones(2 * E)
    else:
        raise ShapeModelError(f"regions must have one label per vertex ({V},) or per entry of z ({2 * E},), "
                              f"got shape {regions.shape}")
    if not np.issubdtype(regions.dtype, np.integer) or regions.min() < 0:
        raise ShapeModelError("region labels must be non-negative integers")
    n = int(rows.max()) + 1
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, 2 * E))


def region_energy(model, regions, modes=None):
    """Fraction of each mode's ``g``-energy per region, ``(J, n_regions)``, rows summing to 1.

    ``regions`` as in :meth:`localized`; ``modes`` default :attr:`modes`.
    """
    U = model.modes if modes is None else np.atleast_2d(np.asarray(modes, float))
    G = _region_matrix(model, regions)
    e = (G @ (U * U * model.metric_weights).T).T
    return e / e.sum(axis=1, keepdims=True)
