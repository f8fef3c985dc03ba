"""Prolongation of coarse marker fits to the full mesh (thesis 2.3 and 4.3.1: fit coarse, prolong, ~20 ms).

:func:`~lacore.markers.fitting.fit_markers` fits the shape model of a coarse
mesh (:func:`lacore.multiresolution.coarsen`); its ``prolongation`` option
turns every fitted coarse pose into a pose of the full mesh by
:class:`lacore.multiresolution.Prolongation` (the removed vertices
re-inserted in local ring frames of the coarse solution, with the local
coordinates of key shapes).  Which key shapes' detail to use:

* one key, the full reference (rest) mesh: ``Prolongation(coarsening, rest)``;
* :class:`NearestKeysProlongation`: the training poses as keys, blended by
  inverse squared distance of the fitted coefficients ``alpha`` to the
  ``n_nearest`` training poses' coefficients (``g``-distance of the poses in
  the model's subspace; :func:`lacore.models.fine_level.nearest_key_weights`).

On the sample human (``benchmarks/bench_marker_fitting.py --prolong``) both are
within 0.1 mm of each other; the blend of the 3 nearest training poses is the
slightly better one (README, marker fitting).
"""

import numpy as np

from ..errors import InputError
from ..models.fine_level import FineLevel, nearest_key_weights
from ..multiresolution import Prolongation

__all__ = ["NearestKeysProlongation", "as_fit_prolongation"]


class NearestKeysProlongation:
    """Prolong with the detail of the training poses nearest to the fitted coefficients.

    Parameters
    ----------
    prolongation : lacore.multiresolution.Prolongation
        Built with the fine training poses as its key shapes, in the order of
        ``key_coefficients`` (more keys before them are allowed: ``offset``).
    key_coefficients : (N, J) array_like
        Model coefficients of the keys (e.g. ``ShapeModel.training_coefficients``).
    n_nearest : int
        Keys blended per pose (weights ``1 / d^2``, normalized; an exact
        match gets weight 1).
    offset : int
        Index of the first training key in ``prolongation``'s key shapes.

    Calling it with ``(coarse_vertices (Vc, 3), coefficients (J,))`` returns
    the fine vertices ``(V, 3)``; with ``(T, Vc, 3)`` and ``(T, J)``, the ``T``
    poses ``(T, V, 3)``, prolonged together.
    """

    def __init__(self, prolongation, key_coefficients, n_nearest=3, offset=0):
        if not isinstance(prolongation, Prolongation):
            raise InputError(f"prolongation must be a lacore.multiresolution.Prolongation, "
                             f"got {type(prolongation).__name__}")
        self.prolongation = prolongation
        self.key_coefficients = np.atleast_2d(np.asarray(key_coefficients, float))
        n_keys = prolongation.alpha.shape[0]
        N = len(self.key_coefficients)
        if not (0 <= offset and offset + N <= n_keys):
            raise InputError(f"{N} key coefficients from key {offset} do not fit the prolongation's {n_keys} keys")
        if not (int(n_nearest) == n_nearest and 1 <= n_nearest <= N):
            raise InputError(f"n_nearest must be an integer from 1 to {N}, got {n_nearest!r}")
        self.n_nearest = int(n_nearest)
        self.offset = int(offset)

    def weights(self, coefficients):
        """Key weights ``(n_keys,)`` for one pose's coefficients ``(J,)``, or ``(T, n_keys)`` for ``(T, J)``."""
        a = np.asarray(coefficients, float)
        J = self.key_coefficients.shape[1]
        if a.shape[-1:] != (J,) or a.ndim > 2:
            raise InputError(f"coefficients must have shape ({J},) or (T, {J}), got {a.shape}")
        A = a.reshape(-1, J)
        w = np.zeros((len(A), self.prolongation.alpha.shape[0]))
        w[:, self.offset:self.offset + len(self.key_coefficients)] = nearest_key_weights(
            self.key_coefficients, A, self.n_nearest)
        return w if a.ndim == 2 else w[0]

    def __call__(self, coarse_vertices, coefficients):
        X = np.asarray(coarse_vertices, float)
        if X.ndim == 3:
            A = np.asarray(coefficients, float).reshape(len(X), -1)
            return self.prolongation(X, self.weights(A) if len(X) else None)
        return self.prolongation(X, self.weights(np.asarray(coefficients, float).reshape(-1)))


def as_fit_prolongation(prolongation):
    """A callable ``f(coarse_vertices (T, Vc, 3), coefficients (T, J)) -> (T, V, 3)`` from what ``fit_markers`` accepts.

    A :class:`~lacore.multiresolution.Prolongation` is used with its first key shape (its
    default weights); a :class:`lacore.models.FineLevel` or a :class:`NearestKeysProlongation`
    prolongs the ``T`` poses together (several times cheaper per pose than one at a time);
    any other callable must take one pose ``(coarse_vertices (Vc, 3), coefficients (J,))``
    and is called once per pose.
    """
    if isinstance(prolongation, Prolongation):
        return lambda X, a: prolongation(X)
    if isinstance(prolongation, (FineLevel, NearestKeysProlongation)):
        return prolongation
    if not callable(prolongation):
        raise InputError(f"prolongation must be a Prolongation or a callable, got {type(prolongation).__name__}")
    return lambda X, a: np.stack([np.asarray(prolongation(x, c), float) for x, c in zip(X, a, strict=True)])
