"""Statistical shape models in lengths and angles (thesis 4.3).

* :mod:`.shape_model` -- :class:`ShapeModel`: PCA and simplified principal geodesic analysis
  of example poses, synthesis of new poses from coefficients, projection of poses onto the
  model, save and load.
* :mod:`.model_io` -- the model file: one table of its entries, read and written by it.
* :mod:`.settings` -- accepted values and defaults of a model, :class:`ShapeModelError`.
"""

from .settings import ShapeModelError
from .shape_model import ShapeModel

__all__ = ["ShapeModel", "ShapeModelError"]
