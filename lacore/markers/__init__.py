"""Motion-capture markers: reading takes, binding markers to a surface, fitting shape models.

* :mod:`.io` -- :class:`MarkerTake` from C3D and TRC files (units, labels, occlusions),
  writing.
* :mod:`.takes` -- the points of a take that are markers (:func:`read_take`,
  :func:`drop_non_markers`), the samples their neighbours contradict
  (:func:`drop_inconsistent_samples`), resampling.
* :mod:`.binding` -- :class:`MarkerBinding`: each marker as a surface point (triangle,
  barycentric coordinates) plus a normal offset; :func:`bind_markers`.
* :mod:`.fitting` -- :func:`fit_markers`: per-frame fits of a shape model to the markers
  (thesis 4.3.1), without skeleton or skinning.
* :mod:`.calibration` -- :func:`calibrate`: a take calibrated to a model (axes, units, size,
  binding, proportions) with no hand work; :func:`model_pins` for characters without standard marker names.
* :mod:`.take_fit` -- :func:`fit_take`: the whole take calibrated and fitted.
* :mod:`.interpenetration` -- where a fit passes through itself and the markers do not.
* :mod:`.marker_sets` -- standard marker-set labels as hints for a humanoid.
* :mod:`.prolongation` -- coarse fits prolonged to the full mesh.
* :mod:`.baselines` -- the vertex-PCA baseline the fits are measured against.
"""

from .binding import MarkerBinding, MarkerBindingError, bind_markers, closest_surface_points, surface_points
from .calibration import (AxisMismatchError, Calibration, CalibrationError, CalibrationOptions, UnitMismatchError,
                          calibrate, model_pins)
from .fitting import FIT_DEFAULTS, FitOptions, MarkerDataError, MarkerFitResult, check_markers, fit_markers
from .io import MarkerError, MarkerFileError, MarkerTake, read_markers, write_c3d, write_trc
from .take_fit import TakeFitResult, fit_take
from .takes import drop_inconsistent_samples, drop_non_markers, inconsistent_samples, read_take, resample

__all__ = ["MarkerTake", "MarkerError", "MarkerFileError", "read_markers", "resample", "write_c3d", "write_trc",
           "MarkerBinding", "MarkerBindingError", "bind_markers", "closest_surface_points", "surface_points",
           "MarkerDataError", "MarkerFitResult", "check_markers", "fit_markers", "FitOptions", "FIT_DEFAULTS",
           "read_take", "drop_non_markers", "calibrate", "model_pins", "fit_take", "Calibration", "CalibrationOptions",
           "TakeFitResult", "CalibrationError", "UnitMismatchError", "AxisMismatchError", "inconsistent_samples",
           "drop_inconsistent_samples"]
