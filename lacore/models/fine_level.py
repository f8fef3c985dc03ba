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
  of the ``n_nearest`` training poses nearest to its coefficients (weights ``1 / d^2``),
  as :class:`lacore.markers.prolongation.NearestKeysProlongation` does.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from ..multiresolution import Coarsening, Prolongation

__all__ = ["FineLevel", "FINE_LEVEL_VERSION"]

#: Version of the stored fine-level record (keys ``fine_*`` of a model file).
FINE_LEVEL_VERSION = 1


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

    @classmethod
    def build(cls, coarsening, fine_reference, fine_keys, key_coefficients, n_nearest=3):
        """From the fine reference mesh ``(V, 3)`` and fine training poses ``(N, V, 3)`` with their coefficients."""
        shapes = np.concatenate([np.asarray(fine_reference, float)[None], np.asarray(fine_keys, float)])
        alpha = Prolongation(coarsening, shapes).alpha
        return cls(coarsening, alpha.astype(np.float32).astype(float), key_coefficients, n_nearest)

    def weights(self, coefficients):
        """Key weights ``(N,)``: inverse squared distance of the ``n_nearest`` training keys (the reference if none)."""
        w = np.zeros(self.alpha.shape[0])
        C = self.key_coefficients
        a = np.asarray(coefficients, float).reshape(-1)
        if C.shape[1] == 0 or a.shape[0] != C.shape[1]:
            w[0] = 1.0
            return w
        d2 = np.sum((C - a) ** 2, axis=1)
        idx = np.argsort(d2, kind="stable")[:self.n_nearest]
        if d2[idx[0]] <= 1e-24 * max(1.0, float(a @ a)):
            w[1 + idx[0]] = 1.0
            return w
        inv = 1.0 / d2[idx]
        w[1 + idx] = inv / inv.sum()
        return w

    def __call__(self, coarse_vertices, coefficients=None):
        """Fine vertices ``(V, 3)`` of one coarse pose ``(Vc, 3)`` (its coefficients choose the keys' detail).

        ``T`` poses ``(T, Vc, 3)`` with their coefficients ``(T, J)`` give ``(T, V, 3)``, prolonged
        together (:meth:`lacore.multiresolution.Prolongation.__call__`).
        """
        X = np.asarray(coarse_vertices, float)
        if X.ndim == 3:
            A = np.zeros((len(X), 0)) if coefficients is None else np.asarray(coefficients, float).reshape(len(X), -1)
            return self._prolongation(X, np.stack([self.weights(a) for a in A]) if len(X) else None)
        return self._prolongation(X, self.weights(np.zeros(0) if coefficients is None else coefficients))

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
