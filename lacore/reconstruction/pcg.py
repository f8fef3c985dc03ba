"""Preconditioned conjugate gradients on the free coordinates, and a BLAS-free dot product.

Used by the Gauss-Newton loop (:mod:`lacore.reconstruction.gauss_newton`) for
inexact steps: the Gauss-Newton system at the current point is solved with an
earlier Cholesky factorization as the preconditioner.
"""

import numpy as np

__all__ = ["preconditioned_cg", "dot"]


def dot(a, b):
    """``a . b`` of two 1-D float arrays without BLAS.

    NumPy's OpenBLAS runs ``ddot`` multithreaded above 10000 entries (an energy
    has ``2E``); its worker threads then spin-wait, which doubled the CPU time
    of a reconstruction on an idle 2-core machine at no gain in wall time.
    ``einsum`` uses NumPy's own (SIMD, single-threaded) loops.
    """
    return float(np.einsum("i,i->", a, b))


def preconditioned_cg(matvec, b, precondition, fixed, rtol, maxiter):
    """Preconditioned conjugate gradients for ``A x = b`` on the free coordinates.

    Parameters
    ----------
    matvec : callable
        ``v -> A v`` for the symmetric positive (semi-)definite ``A``.
    b : (n,) ndarray
        Right-hand side; its ``fixed`` entries are ignored (treated as 0).
    precondition : callable
        ``r -> M^{-1} r`` for a symmetric positive definite ``M`` (e.g. a
        Cholesky factorization of ``A`` at another point).
    fixed : (k,) int array
        Coordinates held at 0 (rows and columns of ``A`` removed).
    rtol : float
        Stop when ``sqrt(r^T M^{-1} r) <= rtol sqrt(b^T M^{-1} b)`` (relative
        residual in the preconditioner's dual norm).
    maxiter : int
        At most this many iterations (each: one ``matvec``, one ``precondition``).

    Returns
    -------
    x : (n,) ndarray
        The last iterate (``x[fixed] = 0``).
    iterations : int
    relative_residual : float
        ``sqrt(r^T M^{-1} r / b^T M^{-1} b)`` of the returned iterate; ``inf``
        when a non-positive curvature ``p^T A p <= 0`` stopped the iteration.
    """
    b = np.array(b, dtype=float)
    b[fixed] = 0.0
    x = np.zeros_like(b)
    r = b
    zr = precondition(r)
    zr[fixed] = 0.0
    rz = dot(r, zr)
    if not rz > 0:
        return x, 0, 0.0 if rz == 0.0 else np.inf
    rz0 = rz
    target = rtol * rtol * rz
    p = zr
    for k in range(1, int(maxiter) + 1):
        Ap = matvec(p)
        Ap[fixed] = 0.0
        curv = dot(p, Ap)
        if not (curv > 0 and np.isfinite(curv)):
            return x, k, np.inf
        alpha = rz / curv
        x = x + alpha * p
        r = r - alpha * Ap
        zr = precondition(r)
        zr[fixed] = 0.0
        rz_new = dot(r, zr)
        if rz_new <= target:
            return x, k, float(np.sqrt(rz_new / rz0))
        p = zr + (rz_new / rz) * p
        rz = rz_new
    return x, int(maxiter), float(np.sqrt(max(rz, 0.0) / rz0))

