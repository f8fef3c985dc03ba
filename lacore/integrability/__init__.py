"""Integrability: which lengths and angles belong to a real mesh (thesis 3.2, Theorem 3.2).

* :mod:`.transitions` -- frames, transition rotations (3.10) and the triangle inequalities (3.7).
* :mod:`.local` -- the conditions at every interior vertex: the integrability map ``I_v``
  (3.11) and its Euler-angle form (3.13) with exact Jacobians, and
  :func:`integrability_violation`; its ring products are the kernels of :mod:`.ring_products`.
* :mod:`.homology` -- a homology basis of the mesh (tree-cotree): loops around its
  handles and holes, with their corridors (dual loops).
* :mod:`.global_conditions` -- the conditions around those loops: holonomy of the frames
  and accumulated translation, with exact Jacobians; :func:`admissibility_map` and its
  Jacobian stack every condition of Theorem 3.2 (for constrained solvers and tangent spaces).
* :mod:`.checks` -- :func:`check_integrability`: all of Theorem 3.2, one verdict, what fails where.
"""

from .transitions import *  # noqa: F403
from .transitions import __all__ as _transitions_all
from .local import *  # noqa: F403
from .local import __all__ as _local_all
from .homology import HomologyBasis, homology_basis
from .global_conditions import (admissibility_jacobian, admissibility_map, global_integrability_jacobian,
                                global_integrability_map, loop_holonomy, loop_translation)
from .checks import (HOLONOMY_TOLERANCE, LOCAL_TOLERANCE, TRANSLATION_TOLERANCE, IntegrabilityCheck,
                     check_integrability)

__all__ = list(_transitions_all) + list(_local_all) + [
    "HomologyBasis", "homology_basis", "loop_holonomy", "loop_translation", "global_integrability_map",
    "global_integrability_jacobian", "admissibility_map", "admissibility_jacobian", "IntegrabilityCheck",
    "check_integrability", "LOCAL_TOLERANCE", "HOLONOMY_TOLERANCE", "TRANSLATION_TOLERANCE",
]
