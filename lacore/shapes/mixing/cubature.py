"""Cubature of the mixer's reduced energy: a sparse weighted subset of edges reproducing its gradient.

The reduced gradient is a sum over edges of pieces affine in the weights ``w``
(:meth:`~lacore.shapes.mixing.reduced.ReducedEnergy.gradient_pieces`).  At training points ``q`` of
the subspace the exact sums over all edges are matched by a non-negative combination of a few
edges' pieces (non-negative least squares, greedy selection): the cubature of the reduced energy
(An, Kim and James 2008; von Tycowicz et al. 2015).  Matching every piece separately makes the
cubature valid for all ``w`` at once.  The match can be measured in the energy norm (``metric`` of
:func:`fit_cubature`): what a gradient error costs in energy at a minimizer; and the whole gradient at
each training point's own weights can be matched besides, relative to the energy there (``weights``,
``energies``): near a minimizer the pieces nearly cancel.
"""

import numpy as np
import scipy.linalg as sl
import scipy.optimize as so

__all__ = ["greedy_nnls", "nnls_gram", "fit_cubature"]


def _cholesky(gram):
    n = len(gram)
    shift = 1e-13 * np.trace(gram) / max(n, 1)
    return sl.cholesky(gram + shift * np.eye(n), lower=False, check_finite=False)


def nnls_gram(G, h, start=None, max_iterations=12):
    """``argmin c^T G c - 2 h^T c`` over ``c >= 0`` for a positive definite ``G`` ``(n, n)``, or None.

    Block principal pivoting (Kim and Park 2011): the free set's least-squares solution and the
    gradient on the others are checked, and every variable that breaks the optimality conditions
    changes set at once (one at a time after three exchanges that did not reduce their number);
    ``start`` (bool ``(n,)``, default all) is the first free set: from the least-squares weights of a
    greedy support, whose signs are nearly right, a few Cholesky factorizations.  None when the sets
    did not settle in ``max_iterations`` (the caller falls back to Lawson-Hanson).  On the mixer's fits
    it settles in 2-4 exchanges on the 13k bodies (10x faster than Lawson-Hanson there) and not on the
    5k bar, whose Gram matrix is far worse conditioned (condition number ~1e15).

    Examples
    --------
    >>> import numpy as np
    >>> nnls_gram(np.eye(3), np.array([1.0, -1.0, 0.5]))
    array([1. , 0. , 0.5])
    """
    n = len(h)
    free = np.ones(n, bool) if start is None else np.array(start, bool)
    tol = 1e-12 * max(float(np.abs(h).max()) if n else 0.0, 1e-300)
    best, backup = n + 1, 3
    for _ in range(max_iterations):
        c = np.zeros(n)
        F = np.flatnonzero(free)
        if F.size:
            c[F] = sl.cho_solve((sl.cholesky(G[np.ix_(F, F)], lower=False, check_finite=False), False), h[F],
                                check_finite=False)
        y = G @ c - h                                   # the gradient / 2; >= 0 where c = 0 at the minimizer
        bad = np.flatnonzero((free & (c < 0)) | (~free & (y < -tol)))
        if not bad.size:
            return c
        if bad.size < best:
            best, backup = bad.size, 3
            free[bad] = ~free[bad]
        elif backup > 0:
            backup -= 1
            free[bad] = ~free[bad]
        else:
            free[bad[-1]] = ~free[bad[-1]]
    return None


def greedy_nnls(A, b, max_points, batch=16, passes=3):
    """A sparse non-negative ``c`` with ``A[:, sel] @ c ~ b``, at most ``max_points`` columns.

    Columns are added in batches by their correlation with the residual (orthogonal matching
    pursuit with least-squares refits), then the weights on the support are fitted by NNLS and
    columns with weight 0 dropped; repeated ``passes`` times while the support is short.  A batch of
    ``k`` columns costs one product ``A^T r`` with the residual ``r = b - A[:, sel] c`` (the
    correlations) and the Gram products of the new columns with the selected ones, ``O(R N + R n k)``
    for ``A`` of shape ``(R, N)`` and ``n`` selected columns (not ``O(R N k)``); the selected columns
    are kept column-major in double precision, so that the Gram products and the refits read one
    contiguous block.  ``A`` may be single precision: only the correlations, which rank the
    candidates, are then computed in single precision (half the memory traffic of the product that
    dominates); the fit itself is in double precision on the columns as given.

    Parameters
    ----------
    A : (R, N) ndarray
        float64 or float32.
    b : (R,) ndarray
    max_points : int
    batch : int
    passes : int

    Returns
    -------
    sel : (n,) int ndarray
        Selected columns.
    c : (n,) ndarray
        Their positive weights.
    relative_residual : float
        ``|A[:, sel] c - b| / |b|``.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.random.default_rng(0).normal(size=(40, 30))
    >>> sel, c, rel = greedy_nnls(A, A[:, [3, 7]] @ [1.0, 2.0], 2, batch=1)
    >>> sel.tolist(), c.round(6).tolist(), bool(rel < 1e-10)
    ([7, 3], [2.0, 1.0], True)
    """
    A = np.asarray(A)
    if A.dtype not in (np.float32, np.float64):
        A = A.astype(float)
    b = np.asarray(b, float)
    R_, N = A.shape
    max_points = min(int(max_points), N)
    norms = np.sqrt(np.einsum("ij,ij->j", A, A, dtype=float))
    norms[norms == 0] = np.inf
    # the selected columns, their Gram matrix and products with b: a batch costs one product A^T r and the Gram of
    # the new columns with the selected ones, not a product of A^T with the new columns
    AS = np.empty((R_, max_points), order="F")         # column-major: the selected columns are one block
    G = np.empty((max_points, max_points))
    atb = np.empty(max_points)
    sel = np.zeros(0, np.int64)
    c = np.zeros(0)
    for _ in range(passes):
        while len(sel) < max_points:
            n = len(sel)
            res = b - AS[:, :n] @ c if n else b
            corr = np.abs(A.T @ res.astype(A.dtype, copy=False)) / norms
            corr[sel] = -np.inf
            k = min(batch, max_points - n)
            new = np.argpartition(-corr, k - 1)[:k]
            new = new[np.isfinite(corr[new]) & (corr[new] > 0)]
            if not new.size:
                break
            k = len(new)
            AS[:, n:n + k] = A[:, new]
            G[:n + k, n:n + k] = AS[:, :n + k].T @ AS[:, n:n + k]
            G[n:n + k, :n] = G[:n, n:n + k].T
            atb[n:n + k] = AS[:, n:n + k].T @ b
            sel = np.r_[sel, new]
            c = sl.cho_solve((_cholesky(G[:n + k, :n + k]), False), atb[:n + k], check_finite=False)
        n = len(sel)
        Gs = G[:n, :n] + 1e-13 * np.trace(G[:n, :n]) / max(n, 1) * np.eye(n)    # the shift of _cholesky
        c = nnls_gram(Gs, atb[:n], start=c > 0)
        if c is None:
            R = _cholesky(G[:n, :n])
            y = sl.solve_triangular(R, atb[:n], trans="T", check_finite=False)
            c, _ = so.nnls(R, y, maxiter=50 * max(n, 1))
        keep = np.flatnonzero(c > 0)
        sel, c = sel[keep], c[keep]
        AS[:, :len(keep)] = AS[:, keep]
        G[:len(keep), :len(keep)] = G[np.ix_(keep, keep)]
        atb[:len(keep)] = atb[keep]
        if len(sel) >= 0.97 * max_points:
            break
    bn = float(np.linalg.norm(b)) or 1.0
    return sel, c, float(np.linalg.norm(b - AS[:, :len(sel)] @ c)) / bn


#: Weight of the rows of :func:`fit_cubature` that match the whole gradient at a sample's own weights, relative to the
#: rows of its pieces (see there).
GRADIENT_ROWS_WEIGHT = 300.0

#: Floor of the sample energies that scale those rows, as a fraction of their median.
GRADIENT_ROWS_FLOOR = 1e-3


def fit_cubature(make_energy, samples, totals, score, n_points, max_candidates=3000, seed=0, metric=None,
                 weights=None, energies=None):
    """Edges and weights of a cubature of the reduced energy, trained at the subspace points ``samples``.

    Parameters
    ----------
    make_energy : callable
        ``make_energy(edges, c, metric=None)`` -> :class:`~lacore.shapes.mixing.reduced.ReducedEnergy` on those
        edges, with the basis ``U metric^T`` when ``metric`` is given.
    samples : list of (r,) ndarrays
    totals : list of (m+1, r) ndarrays
        The exact gradient pieces (sums over all edges) at the samples.
    score : (E,) ndarray
        Importance of every edge (the size of its contributions).
    n_points : int
        Largest number of edges of the cubature.
    max_candidates : int
        Edges offered to the selection: all when there are not more, else the half with the largest
        ``score`` and a seeded random draw of the others.  The greedy fit costs about in proportion.
    seed : int
        Seed of that draw.  The candidates' pieces are stored in single precision (the largest array of
        the build; the greedy fit ranks them in single precision and fits the weights in double precision
        on the rounded columns, :func:`greedy_nnls`): on the 13k bodies the same edges as in double
        precision; on the bars, whose regular meshes make near-ties of the ranking, another selection as
        good as another seed's (``docs/shape-space.md``).
    metric : (r, r) ndarray, optional
        A matrix ``M``: the gradient errors are measured as ``|M e|`` instead of ``|e|``.
        With ``M = C^{-1}``, ``C C^T`` the reduced Gauss-Newton matrix there, ``|M e|^2 = e^T H^{-1} e``
        is twice the energy an error ``e`` of the gradient costs at a minimizer, to second order (the
        minimizer moves by ``H^{-1} e``): the fit weighs the soft directions of the space, where a small
        gradient error moves the minimizer far, above the stiff ones, whose pieces are the largest.  The
        pieces ``M P`` are those of the basis ``U M^T`` at ``M^{-T} q`` (the same points): no product per sample.
    weights : (S, m) array_like, optional
        The weights ``w`` of the samples.  With ``energies``, every sample also has rows matching its whole
        gradient ``piece_0 - sum_k w_k piece_k`` at its own weights, divided by the square root of its energy
        (floored at :data:`GRADIENT_ROWS_FLOOR` times their median) and weighted by :data:`GRADIENT_ROWS_WEIGHT`:
        near a minimizer the pieces nearly cancel in the gradient, so that a small relative error of every piece is
        a large one of the gradient, and in the energy norm ``|M e|^2 / E`` is twice the relative energy a gradient
        error ``e`` costs there.
    energies : (S,) array_like, optional
        The full energies ``W_q`` at the samples.

    Returns
    -------
    edges : (n,) int ndarray
    c : (n,) ndarray
    relative_residual : float
        Of the training fit.
    """
    E = len(score)
    if E <= max_candidates:
        cand = np.arange(E)
    else:
        rng = np.random.default_rng(seed)
        n_top = max_candidates // 2
        top = np.argpartition(-score, n_top)[:n_top]
        rest = np.setdiff1d(np.arange(E), top)
        cand = np.sort(np.r_[top, rng.choice(rest, max_candidates - n_top, replace=False)])
    model = make_energy(cand, None) if metric is None else make_energy(cand, None, metric)
    gradient_rows = weights is not None and energies is not None
    if gradient_rows:
        energies = np.asarray(energies, float)
        floor = GRADIENT_ROWS_FLOOR * float(np.median(energies))
    A = b = None
    for i, (q, tot) in enumerate(zip(samples, totals, strict=True)):
        tot = np.asarray(tot)
        if metric is not None:
            q = np.linalg.solve(metric.T, q)                       # the same point in the basis U M^T
            tot = tot @ metric.T
        P = model.gradient_pieces(q)                              # (m+1, r, n)
        k, r, n = P.shape
        if A is None:
            # single precision: the pieces of all candidates at all samples are the build's largest array (100 MB at
            # 13k vertices in double); rounding them to 6e-8 is far below the fit's residual (1e-3 to 1e-2).  One
            # array for the pieces' rows (k r per sample) and the whole gradients' (r per sample): no copy of it
            S = len(samples)
            A = np.zeros((S * (k + gradient_rows) * r, n), np.float32)
            b = np.zeros(len(A))
        s = np.sqrt(np.einsum("krn,krn->k", P, P) / n)
        s[s == 0] = 1.0
        np.divide(P, s[:, None, None], out=A[i * k * r:(i + 1) * k * r].reshape(k, r, n), casting="same_kind")
        b[i * k * r:(i + 1) * k * r] = (tot / s[:, None]).ravel()
        if gradient_rows and energies[i] + floor > 0:
            coef = np.r_[1.0, -np.asarray(weights[i], float)] * (GRADIENT_ROWS_WEIGHT / np.sqrt(energies[i] + floor))
            at = S * k * r + i * r
            A[at:at + r] = np.einsum("k,krn->rn", coef, P)
            b[at:at + r] = coef @ tot
    sel, c, rel = greedy_nnls(A, b, n_points, batch=max(1, n_points // 25))
    order = np.argsort(cand[sel])
    return cand[sel][order], c[order], rel
