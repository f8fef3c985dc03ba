"""lacore: triangle meshes in edge lengths and dihedral angles.

The headless core of the *Lengths & Angles* Blender extension, after the thesis
"Discrete Gauss-Codazzi Equations for Efficient Triangle Mesh Processing".
Lengths and angles ``z = (l, theta)`` (the discrete first and second fundamental
forms) describe a mesh up to rigid motion; admissible ``z`` satisfy the discrete
integrability conditions.

Main entry points
-----------------
MeshTopology                    connectivity, edges, one-rings (:mod:`lacore.geometry.topology`)
lengths_and_angles              X -> z, and its Jacobian (:mod:`lacore.geometry.lengths_angles`)
euler_integrability_map         admissibility conditions (:mod:`lacore.integrability.local`)
integrability_violation         |tr I_v - 3| per vertex
check_integrability             all of Theorem 3.2: vertices, holes, handles (:mod:`lacore.integrability.checks`)
QuadraticEnergy, ThinShellsEnergy  deformation energies (:mod:`lacore.energies`)
reconstruct                     vertex positions from z (:mod:`lacore.reconstruction`)
ReconstructionSettings, GaussNewtonOptions, HybridOptions  its settings (:mod:`lacore.reconstruction.settings`)
SolverResult                    base of every solver's result (:mod:`lacore.result`)
interpolate, keyframe_inbetweens  in-betweens in z (:mod:`lacore.shapes.interpolation`, imported on first use)
discrete_geodesic               geodesics on the admissible set (:mod:`lacore.shapes.geodesics`, on first use)
ShapeModel                      PCA / simplified PGA shape models (:mod:`lacore.models.shape_model`, on first use)
ShapeMixer, MixerOptions, MixResult  nonlinear shape-key mixing (:mod:`lacore.shapes.mixing`, on first use)

Examples
--------
Encode a mesh, change its lengths and angles, and reconstruct vertex positions:

>>> import numpy as np
>>> import lacore
>>> from lacore.samples.bar import bar_mesh
>>> X, faces = bar_mesh(n_along=4, n_side=1)          # a closed box bar
>>> topo = lacore.MeshTopology.from_faces(faces)
>>> z = lacore.lengths_and_angles(X, topo)            # (2E,): edge lengths, then dihedral angles
>>> z[:topo.n_edges] *= 2.0                           # the same shape, twice the size
>>> res = lacore.reconstruct(z, topo, X)
>>> res.success, round(float(np.ptp(res.vertices[:, 0]) / np.ptp(X[:, 0])), 6)
(True, 2.0)
"""

import importlib

from .energies import EnergyInVertices, QuadraticEnergy, ThinShellsEnergy
from .errors import InputError, LengthsAnglesError, MeshError, ReconstructionWarning
from .integrability.local import (euler_integrability_jacobian, euler_integrability_map, integrability_map,
                                  integrability_violation)
from .integrability.transitions import transition_rotations, triangle_inequality_map
from .integrability import check_integrability, homology_basis, loop_holonomy, loop_translation
from .geometry.lengths_angles import (dihedral_angles, edge_lengths, lengths_and_angles, lengths_and_angles_jacobian,
                                      split_z)
from .progress import Cancelled
from .shapes.projection import project
from .reconstruction import (GaussNewtonOptions, HybridOptions, ReconstructionSettings, reconstruct,
                             reconstruction_errors)
from .result import SolverResult
from .geometry.rigid import rigid_align, rigid_fit
from .geometry.topology import MeshTopology, check_vertices

#: Names imported on first use (their modules pull in scipy.interpolate, which is slow to import).
_LAZY = {"interpolate": "shapes.interpolation", "keyframe_inbetweens": "shapes.interpolation",
         "discrete_geodesic": "shapes.geodesics", "path_energy_profile": "shapes.path_energy",
         "ShapeModel": "models.shape_model",
         "ShapeMixer": "shapes.mixing", "MixerOptions": "shapes.mixing", "MixResult": "shapes.mixing"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__version__ = "0.1.0"

__all__ = [
    "InputError", "MeshError", "LengthsAnglesError", "ReconstructionWarning", "Cancelled", "rigid_fit", "rigid_align",
    "MeshTopology", "check_vertices",
    "edge_lengths", "dihedral_angles", "lengths_and_angles", "lengths_and_angles_jacobian", "split_z",
    "integrability_map", "euler_integrability_map", "euler_integrability_jacobian", "integrability_violation",
    "transition_rotations", "triangle_inequality_map",
    "check_integrability", "homology_basis", "loop_holonomy", "loop_translation",
    "QuadraticEnergy", "ThinShellsEnergy", "EnergyInVertices", "reconstruct", "reconstruction_errors", "project",
    "ReconstructionSettings", "GaussNewtonOptions", "HybridOptions", "SolverResult",
    "interpolate", "keyframe_inbetweens", "discrete_geodesic", "path_energy_profile", "ShapeModel",
    "ShapeMixer", "MixerOptions", "MixResult",
]
