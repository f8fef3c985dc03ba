"""Statistical shape models in lengths and angles (thesis 4.3).

* :mod:`.shape_model` -- :class:`ShapeModel`: PCA and simplified principal geodesic analysis
  of example poses, synthesis of new poses from coefficients, projection of poses onto the
  model, save and load.
* :mod:`.fine_level` -- :class:`FineLevel`: the coarsening record and key detail a model built on a
  coarse mesh carries to show its poses on the fine mesh.
"""

from .fine_level import FineLevel
from .shape_model import ShapeModel, ShapeModelError

__all__ = ["ShapeModel", "ShapeModelError", "FineLevel"]
