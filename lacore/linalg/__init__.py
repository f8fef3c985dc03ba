"""Sparse linear algebra: the one sparse Cholesky interface and its fill-reducing orderings.

* :mod:`.sparse_cholesky` -- :class:`SparseCholesky` (CHOLMOD through cvxopt when installed,
  else SciPy's SuperLU) with the symbolic analysis done once per sparsity pattern, and the
  vertex orderings it uses (METIS through pymetis when installed, else a geometric nested
  dissection).
* :mod:`.heap` -- :func:`retained_heap`: freed memory kept in the process during a long run of factorizations
  (glibc), instead of page faults on every new block.
"""

from .heap import retained_heap
from .sparse_cholesky import (
                              ORDERINGS,
                              NotPositiveDefiniteError,
                              SparseCholesky,
                              available_backends,
                              default_backend,
                              metis_nested_dissection,
                              nested_dissection,
                              vertex_ordering,
                              )

__all__ = ["SparseCholesky", "available_backends", "default_backend", "NotPositiveDefiniteError",
           "nested_dissection", "metis_nested_dissection", "vertex_ordering", "ORDERINGS",
           "retained_heap"]
