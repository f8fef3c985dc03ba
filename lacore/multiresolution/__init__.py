"""Multiresolution: groupwise coarsening, prolongation and coarse-to-fine reconstruction (thesis 2.3).

* :func:`~.coarsening.coarsen` removes vertices by half-edge collapses ordered
  by a quadric error summed over all shapes of a group, so the coarse mesh's
  vertices are a subset of the fine ones (:class:`~.coarsening.Coarsening`).
* :class:`~.prolongation.Prolongation` re-inserts the removed vertices in
  local ring frames (exact for the key shapes and their rigid motions).
* :class:`~.reconstruction.MultiresolutionReconstruction` solves a blend of
  the keys on the coarse mesh, prolongs and finishes with a few fine
  Gauss-Newton steps (exact, preconditioned by one reference factorization,
  or by a two-level cycle with no fine factorization,
  :class:`~.two_level.TwoLevelPreconditioner`).
"""

from .coarsening import Coarsening, coarsen
from .prolongation import Prolongation
from .reconstruction import FINE_SOLVERS, MultiresolutionReconstruction, vertex_rotations
from .two_level import TwoLevelPreconditioner, interpolation_matrix

__all__ = ["Coarsening", "coarsen", "Prolongation", "MultiresolutionReconstruction", "vertex_rotations",
           "FINE_SOLVERS", "TwoLevelPreconditioner", "interpolation_matrix"]
