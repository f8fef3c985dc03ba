"""Integrability: which lengths and angles belong to a real mesh (thesis 3.2, Theorem 3.2).

* :mod:`.local` -- the conditions at every interior vertex: transition rotations, the
  integrability map ``I_v`` and its Euler-angle form with exact Jacobians, the triangle
  inequalities, and :func:`integrability_violation`.
"""

from .local import *  # noqa: F403
from .local import __all__  # noqa: F401
