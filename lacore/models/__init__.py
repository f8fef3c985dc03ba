"""Statistical shape models in lengths and angles (thesis 4.3).

* :mod:`.shape_model` -- :class:`ShapeModel`: a model's data, the coefficients of poses in it,
  and its methods (fit, synthesize, save, load ...), whose algorithms live in:
* :mod:`.training` -- the fit: extrinsic mean, tangent vectors, PCA in the metric ``g``;
* :mod:`.tangent` -- angles on the circle and the projection onto the tangent space;
* :mod:`.synthesis` -- poses from coefficients and sweeps along a mode, without changing the model;
* :mod:`.localization` -- modes rotated toward locality (group varimax in ``g``);
* :mod:`.model_io` -- the model file: one table of its entries, read and written by it;
* :mod:`.settings` -- accepted values and defaults of a model, :class:`ShapeModelError`;
* :mod:`.fine_level` -- :class:`FineLevel`: the coarsening record and key detail a model built on a
  coarse mesh carries to show its poses on the fine mesh.
"""

from .fine_level import FineLevel
from .settings import ShapeModelError
from .shape_model import ShapeModel

__all__ = ["ShapeModel", "ShapeModelError", "FineLevel"]
