"""Multiresolution: groupwise coarsening, prolongation and coarse-to-fine reconstruction (thesis 2.3).

:func:`~.coarsening.coarsen` removes vertices by half-edge collapses ordered
by a quadric error summed over all shapes of a group, so the coarse mesh's
vertices are a subset of the fine ones.
"""

from .coarsening import Coarsening, coarsen

__all__ = ["Coarsening", "coarsen"]
