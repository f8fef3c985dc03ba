"""The shape space: paths and blends between shapes in lengths and angles (thesis chapter 4).

* :mod:`.projection` -- ``P_Z``: lengths and angles to the nearest admissible ones (4.3, 4.4), one
  target or a sequence of them step by step (:class:`~.projection.SequenceProjection`, the one
  projection loop: warm starts along ``t``, chains in worker processes).
* :mod:`.interpolation` -- in-betweens and keyframed sequences: blend the keys in lengths and
  angles (linearly or by splines), then project every frame.
* :mod:`.geodesics` -- discrete geodesics on the admissible set (4.6): the entry point, its
  options and result; :mod:`.path_energy` -- the discrete path energy (2.7) and its quadratic
  model; :mod:`.geodesic_solvers` -- the SQP and vertex Gauss-Newton solvers.
* :mod:`.mixing` -- the shape mixer: weighted blends of shape keys in lengths and angles,
  projected (:class:`~.mixing.ShapeMixer`).

The submodules are imported on first use of their names (the interpolation pulls in
``scipy.interpolate``).
"""

import importlib

_LAZY = {"project": "projection", "SequenceProjection": "projection", "ProjectionOptions": "projection",
         "ProjectedFrame": "projection", "ChainWorkers": "projection",
         "interpolate": "interpolation", "keyframe_inbetweens": "interpolation", "project_targets": "interpolation",
         "InterpolationResult": "interpolation",
         "discrete_geodesic": "geodesics", "GeodesicResult": "geodesics", "GeodesicOptions": "geodesics",
         "path_energy_profile": "path_energy",
         "ShapeMixer": "mixing", "MixerOptions": "mixing", "MixResult": "mixing", "MixerError": "mixing"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_LAZY)
