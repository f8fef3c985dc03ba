"""Settings of shape models: the accepted values, the defaults and the error of bad model input.

Every default of :mod:`lacore.models` is defined here once; the library, the
CLI (``lacore model``) and the Blender add-on take them from here.
"""

from ..errors import InputError
from ..reconstruction.settings import GaussNewtonOptions, ReconstructionSettings

__all__ = ["ShapeModelError", "TANGENTS", "DEFAULT_TANGENT", "PROJECTION_METRICS", "DEFAULT_BENDING_WEIGHT",
           "MODEL_SETTINGS", "MODEL_OPTIONS", "MIN_LENGTH_RATIO"]

#: Tangent-vector variants: (4.18) and (4.17).
TANGENTS = ("ambient", "projected")
#: Tangent used when none is given (library, CLI and add-on): ``"ambient"``.  On skinned poses of the
#: coarse human its first mode reconstructs without folds out to +-2 standard deviations, while the
#: projected variant folds at +-1 (the linear projection at the mean distorts tangents of large
#: deformations; ``tests/test_human_shape_model.py``).
DEFAULT_TANGENT = "ambient"
#: Orthogonality of the tangent projection: the thesis' Euclidean one (default) or ``g``.
PROJECTION_METRICS = ("euclidean", "g")
#: Bending weight ``eta`` of ``W_q`` of a model, as in the thesis' experiments (section 4.3.2).
DEFAULT_BENDING_WEIGHT = 0.005
#: Settings of a model's energy ``W_q`` (its metric ``g``) and reconstructions when none are given.
MODEL_SETTINGS = ReconstructionSettings(bending_weight=DEFAULT_BENDING_WEIGHT)
#: Gauss-Newton options of the mean's projection and of the synthesis when none are given: without geodesic
#: acceleration, which stalls far from the minimum on averaged skinned bodies and at +-2 standard deviations
#: of their modes (``benchmarks/bench_shape_model.py``).
MODEL_OPTIONS = GaussNewtonOptions(geodesic_acceleration=False)
#: Lengths of a synthesized target below this fraction of the mean's length of the same edge are raised to it.
MIN_LENGTH_RATIO = 0.01


class ShapeModelError(InputError):
    """Bad input for a shape model: too few samples, samples not in correspondence, a corrupt model file."""
