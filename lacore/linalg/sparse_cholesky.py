"""Sparse Cholesky factorization with a fixed sparsity pattern.

Gauss-Newton (thesis 3.4.1) solves one symmetric positive definite system
``H d = -g`` per iteration, always with the same sparsity pattern.  This module
separates the *symbolic* analysis (fill-reducing ordering, elimination tree,
done once per pattern) from the *numeric* factorization (once per iteration),
so the symbolic work is reused across iterations and across calls.

Backends
--------
``"cholmod"``
    CHOLMOD (SuiteSparse) through :mod:`cvxopt.cholmod` when cvxopt is
    importable: supernodal Cholesky ``P A P^T = L L^T`` with a fill-reducing
    ordering computed once in :class:`SparseCholesky` and reused by every
    :meth:`SparseCholesky.factorize`.  This is the default: on the
    Gauss-Newton systems it is several times faster than the SciPy fallback
    (``benchmarks/bench_gauss_newton.py``).
``"scipy"``
    SciPy's SuperLU (:func:`scipy.sparse.linalg.splu`) in symmetric mode with a
    minimum-degree ordering of ``A + A^T`` and diagonal pivoting, i.e. an
    ``L D L^T``-like factorization without row interchanges.  SuperLU has no
    separate symbolic phase, so only the index bookkeeping is reused.

Ordering
--------
CHOLMOD tries the caller's ``ordering`` (if any) and AMD and keeps the one with
fewer nonzeros in the factor (cvxopt's CHOLMOD is built without METIS); with
``try_amd=False`` it takes the caller's ordering alone (:data:`GIVEN_ONLY_SIZE`).
:func:`vertex_ordering` gives the caller's ordering: METIS nested dissection
(:func:`metis_nested_dissection`, the optional dependency pymetis) when it is
importable, else :func:`nested_dissection`, a geometric nested dissection from
coordinates (recursive bisection at the median along the principal axis, the
smaller one-sided vertex separator numbered last).  On large Gauss-Newton
systems METIS fills less than both the geometric ordering and AMD
(``benchmarks/bench_ordering.py`` compares them).

Positive definiteness
---------------------
If a numeric factorization fails because the matrix is not (numerically)
positive definite, the factorization is retried with a diagonal shift
``A + s I``, ``s = shift_start * max|diag A|``, increased tenfold until it
succeeds (at most ``max_shift_tries`` times).  The shift used is reported in
:attr:`SparseCholesky.shift` (0.0 when none was needed), so a caller can tell a
regularized (damped) step from an exact one.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ..errors import InputError

__all__ = ["SparseCholesky", "available_backends", "default_backend", "NotPositiveDefiniteError", "GIVEN_ONLY_SIZE",
           "nested_dissection", "metis_nested_dissection", "vertex_ordering", "ORDERINGS"]

#: Names of :func:`vertex_ordering`'s methods, preferred first.
ORDERINGS = ("metis", "geometric")

#: From this many unknowns up a METIS ordering is analysed alone (``try_amd=False``, see
#: :class:`~lacore.reconstruction.ReconstructionContext`), without CHOLMOD's AMD analysis besides: on the 50k bar's
#: Gauss-Newton systems (147k unknowns) METIS fills less (47 against 67 million entries) and the AMD analysis costs
#: ~0.1 s, while on the 13k body (40k unknowns) AMD fills less and is kept.
GIVEN_ONLY_SIZE = 100_000


class NotPositiveDefiniteError(ArithmeticError):
    """The matrix stayed indefinite even after the largest allowed diagonal shift."""


def _cholmod():
    try:  # imported on demand on purpose: cvxopt is an optional dependency (SciPy fallback without it)
        import cvxopt
        import cvxopt.cholmod
    except ImportError:  # pragma: no cover - depends on the environment
        return None
    return cvxopt


def available_backends():
    """Names of the backends usable in this environment, preferred first."""
    return (["cholmod"] if _cholmod() is not None else []) + ["scipy"]


def default_backend():
    """The backend used when none is requested: ``"cholmod"`` if cvxopt is installed, else ``"scipy"``."""
    return available_backends()[0]


class SparseCholesky:
    """Repeated Cholesky factorizations of SPD matrices sharing one sparsity pattern.

    Parameters
    ----------
    pattern : scipy.sparse matrix, shape (n, n)
        Symmetric sparsity pattern.  Only the structure of its lower triangle
        (including the diagonal, which is always added) is used; values are
        ignored.
    backend : {"cholmod", "scipy"}, optional
        Default :func:`default_backend`.
    shift_start : float
        First relative diagonal shift tried for a matrix that is not positive
        definite (relative to ``max|diag A|``).
    max_shift_tries : int
        How many tenfold shift increases are tried before giving up.
    ordering : (n,) array_like of int, optional
        A fill-reducing permutation to try besides AMD (CHOLMOD backend only;
        e.g. from :func:`nested_dissection`).
    try_amd : bool
        With ``ordering``: also let CHOLMOD analyse AMD and keep the ordering that fills less (the default); False
        takes ``ordering`` alone (one analysis fewer where it is known to win, :data:`GIVEN_ONLY_SIZE`).

    Attributes
    ----------
    n : int
        Matrix size.
    indptr, indices : ndarray
        The lower-triangular CSC structure (sorted row indices per column).
        :meth:`factorize` accepts a value array in exactly this order.
    diagonal : (n,) ndarray
        Positions of the diagonal entries in the value array.
    backend : str
    shift : float
        Absolute diagonal shift added in the last :meth:`factorize` (0.0 if none).

    Notes
    -----
    One instance holds one numeric factorization; it is not thread-safe.  Use
    one instance per thread (the symbolic analysis is cheap compared to a
    Gauss-Newton solve).

    Examples
    --------
    One symbolic analysis, then any number of numeric factorizations with the same pattern:

    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from lacore.linalg.sparse_cholesky import SparseCholesky
    >>> A = sp.diags([-np.ones(4), 2 * np.ones(5), -np.ones(4)], [-1, 0, 1], format="csc")
    >>> chol = SparseCholesky(A)
    >>> for scale in (1.0, 2.0):
    ...     _ = chol.factorize(scale * A)
    ...     print(np.round(chol.solve(np.ones(5)), 6) + 0.0)
    [2.5 4.  4.5 4.  2.5]
    [1.25 2.   2.25 2.   1.25]
    """

    def __init__(self, pattern, backend=None, shift_start=1e-10, max_shift_tries=12, ordering=None, try_amd=True):
        backend = default_backend() if backend is None else backend
        if backend not in ("cholmod", "scipy"):
            raise InputError(f"unknown sparse Cholesky backend {backend!r}; use 'cholmod' or 'scipy'")
        if backend == "cholmod" and _cholmod() is None:
            raise InputError("backend 'cholmod' needs cvxopt (pip install cvxopt); use backend='scipy'")
        P = sp.csc_matrix(pattern)
        n = P.shape[0]
        if P.shape != (n, n):
            raise ValueError(f"the pattern must be square, got shape {P.shape}")
        if not _is_lower_with_diagonal(P):
            P = sp.tril(sp.csc_matrix((np.ones(P.nnz), P.indices, P.indptr), shape=P.shape), format="csc")
            P = (P + sp.eye(n, format="csc")).tocsc()
            P.sort_indices()
        self.n = n
        self.indptr = P.indptr.astype(np.int64, copy=False)
        self.indices = P.indices.astype(np.int64, copy=False)
        self.nnz = len(self.indices)
        cols = np.repeat(np.arange(n), np.diff(self.indptr))
        self._cols = cols
        self.diagonal = np.flatnonzero(self.indices == cols)
        self.backend = backend
        self.shift_start = float(shift_start)
        self.max_shift_tries = int(max_shift_tries)
        self.shift = 0.0
        self._factor = None
        self._keys = None
        if backend == "cholmod":
            cvxopt = _cholmod()
            self._cvxopt = cvxopt
            position = np.arange(1.0, self.nnz + 1.0)
            self._A = cvxopt.spmatrix(position, cvxopt.matrix(self.indices), cvxopt.matrix(cols), (n, n))
            # the spmatrix must keep our (column-major, sorted) order so values can be assigned directly
            if not np.array_equal(np.asarray(self._A.V).ravel(), position):
                raise RuntimeError("cvxopt reordered the pattern")  # pragma: no cover
            if ordering is not None:
                p = np.asarray(ordering, dtype=np.int64)
                if p.shape != (n,) or not np.array_equal(np.sort(p), np.arange(n)):
                    raise ValueError(f"ordering must be a permutation of 0..{n - 1}")
                opts = cvxopt.cholmod.options
                before = opts.get("nmethods")
                if not try_amd:
                    opts["nmethods"] = 1                      # the given ordering only: no AMD analysis
                try:
                    self._symbolic = cvxopt.cholmod.symbolic(self._A, uplo="L", p=cvxopt.matrix(p))
                finally:
                    if before is None:
                        opts.pop("nmethods", None)
                    else:
                        opts["nmethods"] = before
            else:
                self._symbolic = cvxopt.cholmod.symbolic(self._A, uplo="L")
        else:
            # full symmetric structure for SuperLU: the lower part and its mirror image
            lower_rows, lower_cols = self.indices, cols
            off = lower_rows != lower_cols
            rows = np.r_[lower_rows, lower_cols[off]]
            cols_full = np.r_[lower_cols, lower_rows[off]]
            src = np.r_[np.arange(self.nnz), np.flatnonzero(off)]
            order = np.lexsort((rows, cols_full))
            self._full_src = src[order]
            self._full_indices = rows[order].astype(np.int32)
            self._full_indptr = np.r_[0, np.cumsum(np.bincount(cols_full, minlength=n))].astype(np.int32)

    @property
    def has_factor(self):
        """Whether a numeric factorization is available for :meth:`solve`."""
        return self._factor is not None

    # ------------------------------------------------------------------ values
    def values_from_matrix(self, A):
        """Values of a sparse matrix in this pattern's lower-CSC order.

        Entries of ``A``'s lower triangle outside the pattern raise ValueError;
        pattern entries missing from ``A`` are 0.
        """
        A = sp.coo_matrix(A)
        if A.shape != (self.n, self.n):
            raise ValueError(f"matrix shape {A.shape} does not match the pattern ({self.n}, {self.n})")
        low = A.row >= A.col
        r, c, v = A.row[low].astype(np.int64), A.col[low].astype(np.int64), A.data[low]
        if self._keys is None:
            self._keys = self._cols * self.n + self.indices  # sorted (column-major, sorted rows)
        k = c * self.n + r
        pos = np.searchsorted(self._keys, k)
        pos_c = np.minimum(pos, self.nnz - 1)
        if np.any(self._keys[pos_c] != k):
            raise ValueError("the matrix has nonzeros outside the factorization's sparsity pattern")
        return np.bincount(pos_c, weights=v, minlength=self.nnz)

    # ------------------------------------------------------------------ numeric
    def factorize(self, values, regularize=True):
        """Numeric factorization.

        Parameters
        ----------
        values : (nnz,) array_like or scipy.sparse matrix
            Lower-triangle values in the order of :attr:`indices` (fast path),
            or a symmetric matrix whose nonzeros lie in the pattern.
        regularize : bool
            Retry a matrix that is not positive definite with growing diagonal
            shifts (module docstring); with False it raises at once (a caller
            with another matrix to fall back on).

        Returns
        -------
        self

        Raises
        ------
        NotPositiveDefiniteError
            If the matrix is not positive definite even with the largest shift.
        """
        if sp.issparse(values):
            values = self.values_from_matrix(values)
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (self.nnz,):
            raise ValueError(f"expected {self.nnz} values in the pattern's order, got shape {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError("the matrix has NaN or infinite entries")
        scale = float(np.max(np.abs(values[self.diagonal]))) if self.n else 1.0
        scale = scale if scale > 0 else 1.0
        shift = 0.0
        for attempt in range(self.max_shift_tries + 1 if regularize else 1):
            v = values
            if shift:
                v = values.copy()
                v[self.diagonal] += shift
            if self._numeric(v):
                self.shift = shift
                return self
            shift = self.shift_start * scale if attempt == 0 else 10.0 * shift
        self._factor = None
        if not regularize:
            raise NotPositiveDefiniteError(f"the {self.n}x{self.n} matrix is not positive definite")
        raise NotPositiveDefiniteError(
            f"the {self.n}x{self.n} matrix is not positive definite even with diagonal shift {shift / 10:.3g}")

    def _numeric(self, v):
        if self.backend == "cholmod":
            cvxopt = self._cvxopt
            self._A.V = cvxopt.matrix(v)
            try:
                cvxopt.cholmod.numeric(self._A, self._symbolic)
            except ArithmeticError:
                self._factor = None
                return False
            self._factor = self._symbolic
            return True
        A = sp.csc_matrix((v[self._full_src], self._full_indices, self._full_indptr), shape=(self.n, self.n))
        try:
            lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
        except RuntimeError:  # exactly singular
            self._factor = None
            return False
        d = lu.U.diagonal()
        if not (np.all(d > 0) and np.array_equal(lu.perm_r, lu.perm_c)):
            self._factor = None
            return False
        self._factor = lu
        return True

    def factor_column_counts(self):
        """Nonzeros per column of the last factorization's ``L`` (CHOLMOD: ``P A P^T = L L^T``; SciPy: SuperLU's ``L``).

        Their sum is the fill, the sum of their squares about the flops of the factorization
        (``benchmarks/bench_ordering.py``).  Copies the factor: for measurements, not for solver loops.

        Returns
        -------
        (n,) int64 ndarray
        """
        if self._factor is None:
            raise RuntimeError("factorize() must succeed before factor_column_counts()")
        if self.backend == "cholmod":
            L = self._cvxopt.cholmod.getfactor(self._factor)
            return np.diff(np.asarray(L.CCS[0]).ravel()).astype(np.int64)
        return np.diff(self._factor.L.tocsc().indptr).astype(np.int64)

    @property
    def has_triangular_solves(self):
        """Whether :meth:`forward`, :meth:`diagonal_solve` and :meth:`backward` are available (CHOLMOD)."""
        return self.backend == "cholmod"

    def _cholmod_sys(self, b, systems):
        if self._factor is None:
            raise RuntimeError("factorize() must succeed before solve()")
        if not self.has_triangular_solves:
            raise NotImplementedError("triangular solves need the CHOLMOD backend")
        b = np.asarray(b, dtype=np.float64)
        if b.shape[0] != self.n:
            raise ValueError(f"right-hand side has {b.shape[0]} rows, the matrix {self.n}")
        cvxopt = self._cvxopt
        B = cvxopt.matrix(b.reshape(self.n, -1))
        for sys_ in systems:
            cvxopt.cholmod.solve(self._factor, B, sys=sys_)
        return np.array(B).reshape(b.shape)

    def forward(self, b):
        """``L^-1 P b`` for the factorization ``P A P^T = L D L^T`` (``D = I`` for a supernodal ``L L^T``).

        With :meth:`diagonal_solve` and :meth:`backward`: ``A^-1 b = backward(diagonal_solve(forward(b)))``,
        and ``b^T A^-1 c = forward(b)^T diagonal_solve(forward(c))``: a quadratic form in
        ``A^-1`` over ``k`` right-hand sides costs ``k`` forward substitutions only.
        CHOLMOD backend only (:attr:`has_triangular_solves`).
        """
        return self._cholmod_sys(b, (7, 4))

    def diagonal_solve(self, w):
        """``D^-1 w`` (see :meth:`forward`; a copy of ``w`` for an ``L L^T`` factor)."""
        return self._cholmod_sys(w, (6,))

    def backward(self, w):
        """``P^T L^-T w`` (see :meth:`forward`)."""
        return self._cholmod_sys(w, (5, 8))

    def solve(self, b):
        """Solve ``A x = b`` with the last factorization; ``b`` of shape (n,) or (n, k)."""
        if self._factor is None:
            raise RuntimeError("factorize() must succeed before solve()")
        b = np.asarray(b, dtype=np.float64)
        if b.shape[0] != self.n:
            raise ValueError(f"right-hand side has {b.shape[0]} rows, the matrix {self.n}")
        if self.n == 0:                               # no unknowns (e.g. every face a root of its component)
            return b.copy()
        if self.backend == "cholmod":
            cvxopt = self._cvxopt
            B = cvxopt.matrix(b.reshape(self.n, -1))
            cvxopt.cholmod.solve(self._factor, B)
            return np.array(B).reshape(b.shape)
        return self._factor.solve(b)


def _is_lower_with_diagonal(P):
    """Whether the CSC matrix ``P`` is already a lower-triangular structure in canonical form (sorted rows, no
    duplicates) whose every column starts with its diagonal entry: then it is its own pattern."""
    n = P.shape[0]
    starts = P.indptr[:-1]
    if not (P.has_canonical_format and np.all(np.diff(P.indptr) > 0)):
        return False
    return bool(np.array_equal(P.indices[starts], np.arange(n)))


def _pymetis():
    try:  # optional dependency: the geometric nested dissection without it
        import pymetis
    except ImportError:
        return None
    return pymetis


def metis_nested_dissection(graph):
    """METIS nested-dissection ordering of a graph (through pymetis), or None when pymetis is not importable.

    Parameters
    ----------
    graph : scipy.sparse matrix, shape (m, m)
        Symmetric adjacency (nonzeros = edges; the diagonal is ignored).

    Returns
    -------
    (m,) int64 permutation (``order[k]`` is the vertex eliminated k-th), or None.
    METIS' default options: the same graph gives the same ordering in every process.
    """
    pymetis = _pymetis()
    if pymetis is None:
        return None
    G = sp.csr_matrix(graph, copy=True)
    G.setdiag(0)
    G.eliminate_zeros()
    G.sort_indices()
    xadj, adjncy = G.indptr.astype(np.int32), G.indices.astype(np.int32)
    if hasattr(pymetis, "CSRAdjacency"):
        perm, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(xadj, adjncy))
    else:  # pragma: no cover - pymetis before 2025
        perm, _ = pymetis.nested_dissection(xadj=xadj, adjncy=adjncy)
    return np.asarray(perm, dtype=np.int64)


def vertex_ordering(graph, coordinates, method=None):
    """A fill-reducing vertex ordering for CHOLMOD: METIS when available, else the geometric nested dissection.

    Parameters
    ----------
    graph : scipy.sparse matrix, shape (m, m)
        Symmetric adjacency (the diagonal is ignored).
    coordinates : (m, d) array_like
        Vertex positions (used by the geometric method only).
    method : {"metis", "geometric"}, optional
        Default: the first of :data:`ORDERINGS` available here.

    Returns
    -------
    order : (m,) int64 permutation
    method : str
        The method used.

    Raises
    ------
    InputError
        An unknown method, or ``"metis"`` without pymetis.
    """
    if method not in (None, *ORDERINGS):
        raise InputError(f"unknown ordering {method!r}; use one of {', '.join(ORDERINGS)}")
    if method in (None, "metis"):
        order = metis_nested_dissection(graph)
        if order is not None:
            return order, "metis"
        if method == "metis":
            raise InputError("ordering 'metis' needs pymetis (pip install pymetis); use 'geometric'")
    return nested_dissection(graph, coordinates), "geometric"


def nested_dissection(graph, coordinates, leaf_size=32):
    """Geometric nested-dissection ordering of a graph with vertex coordinates.

    Recursively splits a vertex set at the median of its projection on the
    principal axis of its coordinates; the vertices of the smaller side that
    have a neighbour on the other side form the separator, numbered after both
    halves.  Sets of at most ``leaf_size`` vertices keep their order.

    Parameters
    ----------
    graph : scipy.sparse matrix, shape (m, m)
        Symmetric adjacency (nonzeros = edges; the diagonal is ignored).
    coordinates : (m, d) array_like
    leaf_size : int

    Returns
    -------
    (m,) int64 permutation: ``order[k]`` is the vertex eliminated k-th.
    """
    G = sp.coo_matrix(graph)
    off = G.row != G.col
    X = np.asarray(coordinates, float)
    m = G.shape[0]
    out = []
    side = np.zeros(m, np.int8)       # 0 left, 1 right, 2 separator: valid for the set being split
    touched = np.zeros(m, bool)
    # explicit stack of (vertex set, its internal edges (both directions)) frames: no deep recursion;
    # every level of the recursion visits every edge once
    stack = [("split", np.arange(m), (G.row[off].astype(np.int64), G.col[off].astype(np.int64)))]
    while stack:
        kind, verts, (a, b) = stack.pop()
        if kind == "emit" or len(verts) <= leaf_size:
            out.append(verts)
            continue
        c = X[verts] - X[verts].mean(0)
        axis = np.linalg.svd(c, full_matrices=False)[2][0]
        proj = c @ axis
        left_mask = proj <= np.median(proj)
        left, right = verts[left_mask], verts[~left_mask]
        if len(left) == 0 or len(right) == 0:
            out.append(verts)
            continue
        side[left], side[right] = 0, 1
        sa, sb = side[a], side[b]
        cross = (sa == 0) & (sb == 1)                 # left -> right; the reverse direction is listed too
        touched[a[cross]] = True
        touch_l = touched[left]
        touched[a[cross]] = False
        touched[b[cross]] = True
        touch_r = touched[right]
        touched[b[cross]] = False
        if touch_l.sum() <= touch_r.sum():
            sep, left = left[touch_l], left[~touch_l]
        else:
            sep, right = right[touch_r], right[~touch_r]
        side[sep] = 2
        sa, sb = side[a], side[b]
        inner_l, inner_r = (sa == 0) & (sb == 0), (sa == 1) & (sb == 1)
        none = (a[:0], b[:0])
        # processed in reverse push order: left, right, then the separator
        stack += [("emit", sep, none), ("split", right, (a[inner_r], b[inner_r])),
                  ("split", left, (a[inner_l], b[inner_l]))]
    return np.concatenate(out).astype(np.int64)
