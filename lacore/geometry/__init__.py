"""The core maps: connectivity, and vertex positions to lengths and angles (thesis 1.3, 3.1).

* :mod:`.topology` -- :class:`MeshTopology`: edges, faces, one-rings, boundary, and the
  per-connectivity cache of derived data.
* :mod:`.lengths_angles` -- ``Z[X] = (l, theta)``: edge lengths and signed dihedral angles
  (the discrete first and second fundamental forms) and their exact Jacobian.
* :mod:`.hessians` -- their exact second derivatives.
* :mod:`.trigonometry` -- triangle quantities from edge lengths alone (interior angles, areas)
  and their derivatives.
* :mod:`.rigid` -- the one rigid (Kabsch) fit used everywhere.
* :mod:`.self_intersection` -- the pairs of faces passing through each other.
"""

from .lengths_angles import (
                             check_z,
                             dihedral_angles,
                             edge_lengths,
                             face_areas,
                             face_normals,
                             lengths_and_angles,
                             lengths_and_angles_jacobian,
                             split_z,
                             )
from .rigid import apply_rigid, rigid_align, rigid_fit, rigid_rms
from .self_intersection import intersecting_faces, self_intersections
from .topology import MeshTopology, check_faces, check_vertices

__all__ = ["MeshTopology", "check_faces", "check_vertices", "face_normals", "face_areas", "edge_lengths",
           "dihedral_angles", "lengths_and_angles", "lengths_and_angles_jacobian", "split_z", "check_z",
           "rigid_fit", "rigid_align", "apply_rigid", "rigid_rms", "self_intersections", "intersecting_faces"]
