"""The fine mesh of a shape model built on a coarse level: what prolongation needs, stored with the model.

A model trained on a coarse mesh (:func:`lacore.multiresolution.coarsen`) is fitted
fast; its poses are shown on the fine mesh by :class:`lacore.multiresolution.Prolongation`
(removed vertices re-inserted in local ring frames, thesis 2.3).  :class:`FineLevel` holds
everything that takes, so a model file is self-contained:

* the coarsening record (:meth:`lacore.multiresolution.Coarsening.to_arrays`): stored,
  never recomputed (the greedy collapse order is not reproducible bit for bit across
  machines);
* the local coordinates ``alpha (N, K, 3)`` of the removed vertices in ``N`` fine key
  shapes (key 0: the fine reference mesh, then the training poses), float32;
* the model coefficients of the training keys: a fitted pose is prolonged with the detail
  of the ``n_nearest`` training poses nearest to its coefficients (:func:`nearest_key_weights`),
  as :class:`lacore.markers.prolongation.NearestKeysProlongation` does.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from ..multiresolution import Coarsening, Prolongation

__all__ = ["FineLevel", "FINE_LEVEL_VERSION", "nearest_key_weights"]

#: Version of the stored fine-level record (keys ``fine_*`` of a model file).
FINE_LEVEL_VERSION = 1


def nearest_key_weights(key_coefficients, coefficients, n_nearest):
    """Weights of the keys nearest to model coefficients: inverse squared distance of the ``n_nearest``.

    Parameters
    ----------
    key_coefficients : (N, J) array_like
        Model coefficients of the keys (e.g. ``ShapeModel.training_coefficients``).
    coefficients : (J,) or (T, J) array_like
        One pose's coefficients, or ``T`` poses'.
    n_nearest : int
        Keys blended per pose, ``1 <= n_nearest <= N``.

    Returns
    -------
    (N,) or (T, N) ndarray
        Per pose, ``1 / d^2`` normalized over its ``n_nearest`` nearest keys (ties: the lower
        index first), zero elsewhere; a pose at a key (``d^2 <= 1e-24 max(1, |a|^2)``) gets
        that key's weight 1.

    Examples
    --------
    >>> nearest_key_weights([[0.0], [1.0], [3.0]], [0.5], 2)
    array([0.5, 0.5, 0. ])
    """
    C = np.atleast_2d(np.asarray(key_coefficients, float))
    a = np.asarray(coefficients, float)
    A = a.reshape(-1, C.shape[1])
    d2 = np.sum((C[None] - A[:, None]) ** 2, axis=2)
    idx = np.argsort(d2, axis=1, kind="stable")[:, :int(n_nearest)]
    near = np.take_along_axis(d2, idx, axis=1)
    exact = near[:, 0] <= 1e-24 * np.maximum(1.0, np.sum(A * A, axis=1))
    inv = 1.0 / np.where(exact[:, None], 1.0, near)
    inv[exact] = 0.0
    inv[exact, 0] = 1.0
    w = np.zeros(d2.shape)
    np.put_along_axis(w, idx, inv / inv.sum(axis=1, keepdims=True), axis=1)
    return w[0] if a.ndim == 1 else w


@dataclass(eq=False)
class FineLevel:
    """Coarse-to-fine prolongation of a shape model's poses (see the module docstring).

    Attributes
    ----------
    coarsening : Coarsening
    alpha : (N, K, 3) ndarray
        Local coordinates of the ``K`` removed vertices in ``N`` key shapes.
    key_coefficients : (N - 1, J) ndarray
        Model coefficients of keys ``1..N-1`` (the training poses).
    n_nearest : int
    fine_faces : (F, 3) int64 ndarray
    """

    coarsening: Coarsening
    alpha: np.ndarray
    key_coefficients: np.ndarray
    n_nearest: int = 3

    def __post_init__(self):
        self._prolongation = Prolongation.from_local_coordinates(self.coarsening, self.alpha)
        self.key_coefficients = np.atleast_2d(np.asarray(self.key_coefficients, float))
        if len(self.key_coefficients) != self.alpha.shape[0] - 1:
            raise MeshError(f"{self.alpha.shape[0]} key shapes need {self.alpha.shape[0] - 1} key coefficient rows, "
                            f"got {len(self.key_coefficients)}")
        self.n_nearest = int(min(max(1, self.n_nearest), max(1, len(self.key_coefficients))))

    @property
    def fine_faces(self):
        return self.coarsening.fine_faces

    @property
    def n_fine_vertices(self):
        return self.coarsening.n_fine_vertices

    def coarse_vertices(self, vertices):
        """The coarse vertex of each fine vertex ``(n,)`` int: itself where it was kept, else the one that absorbed
        it (:attr:`lacore.multiresolution.Coarsening.parent`).

        Examples
        --------
        >>> from lacore.samples.human import human_model
        >>> level = human_model().fine_level                      # doctest: +SKIP
        >>> level.coarse_vertices([0, 13379]).shape                # doctest: +SKIP
        (2,)
        """
        v = np.asarray(vertices, np.int64)
        return self.coarsening.parent[v]

    @classmethod
    def build(cls, coarsening, fine_reference, fine_keys, key_coefficients, n_nearest=3):
        """From the fine reference mesh ``(V, 3)`` and fine training poses ``(N, V, 3)`` with their coefficients."""
        shapes = np.concatenate([np.asarray(fine_reference, float)[None], np.asarray(fine_keys, float)])
        alpha = Prolongation(coarsening, shapes).alpha
        return cls(coarsening, alpha.astype(np.float32).astype(float), key_coefficients, n_nearest)

    def weights(self, coefficients):
        """Key weights ``(N,)`` of one pose's coefficients ``(J,)``, or ``(T, N)`` of ``(T, J)``.

        The ``n_nearest`` training keys by inverse squared distance (:func:`nearest_key_weights`);
        the reference alone when the model has no modes or the coefficients do not match them.
        """
        a = np.asarray(coefficients, float)
        C = self.key_coefficients
        A = a.reshape(len(a) if a.ndim == 2 else 1, -1)
        w = np.zeros((len(A), self.alpha.shape[0]))
        if C.shape[1] == 0 or A.shape[1] != C.shape[1]:
            w[:, 0] = 1.0
        else:
            w[:, 1:] = nearest_key_weights(C, A, self.n_nearest)
        return w if a.ndim == 2 else w[0]

    def __call__(self, coarse_vertices, coefficients=None):
        """Fine vertices ``(V, 3)`` of one coarse pose ``(Vc, 3)`` (its coefficients choose the keys' detail).

        ``T`` poses ``(T, Vc, 3)`` with their coefficients ``(T, J)`` give ``(T, V, 3)``, prolonged
        together (:meth:`lacore.multiresolution.Prolongation.__call__`).
        """
        X = np.asarray(coarse_vertices, float)
        if X.ndim == 3:
            A = np.zeros((len(X), 0)) if coefficients is None else np.asarray(coefficients, float).reshape(len(X), -1)
            return self._prolongation(X, self.weights(A) if len(X) else None)
        return self._prolongation(X, self.weights(np.zeros(0) if coefficients is None
                                                  else np.asarray(coefficients, float).reshape(-1)))

    # ------------------------------------------------------------------ files
    def to_arrays(self):
        """``{fine_*: array}`` for a model file."""
        out = self.coarsening.to_arrays("fine_coarsening_")
        out.update({"fine_version": np.array(FINE_LEVEL_VERSION), "fine_alpha": self.alpha.astype(np.float32),
                    "fine_key_coefficients": self.key_coefficients, "fine_n_nearest": np.array(self.n_nearest)})
        return out

    @classmethod
    def from_arrays(cls, arrays):
        """Inverse of :meth:`to_arrays`; ``None`` if the arrays hold no fine level; MeshError if corrupt."""
        if "fine_version" not in arrays:
            return None
        version = int(arrays["fine_version"])
        if version != FINE_LEVEL_VERSION:
            raise MeshError(f"fine-level record version {version}; this lacore reads version {FINE_LEVEL_VERSION}")
        c = Coarsening.from_arrays(arrays, "fine_coarsening_")
        return cls(c, np.asarray(arrays["fine_alpha"], float), np.asarray(arrays["fine_key_coefficients"], float),
                   int(arrays["fine_n_nearest"]))
