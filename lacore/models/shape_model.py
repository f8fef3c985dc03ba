"""Statistical shape models in lengths and angles: PCA and simplified PGA (thesis section 4.3).

From ``N`` example poses of one mesh (vertex arrays in dense correspondence, or
their lengths and angles ``z^i``) :meth:`ShapeModel.fit` learns a
``J``-dimensional family of natural deformations:

1. **Mean** (4.16): the extrinsic mean ``zbar = P_Z[(1/N) sum_i z^i]``, the
   projection of the linear mean onto the admissible set by reconstruction
   (:func:`lacore.shapes.projection.project`, Gauss-Newton on ``W_q`` by default).
   Dihedral angles are averaged on the circle (differences to the reference
   taken modulo ``2 pi``, :func:`~.tangent.wrap_angles`), and every angle difference
   below is wrapped likewise: identical to the thesis unless samples straddle
   the branch cut at ``+-pi`` (nearly folded skin, as linear-blend skinning
   makes at a bent elbow), where a plain average would be meaningless.
2. **Tangent vectors**: ``ambient`` (4.18) ``v^i = z^i - zbar``, or
   ``projected`` (4.17) ``v^i = P^lin_{T Z}[z^i - zbar]``, the linear
   projection onto the tangent space ``T_zbar Z = ker D Ĩ`` (4.4) without an
   explicit basis: ``v = (Id - A^T (A A^T)^-1 A) u`` with ``A = D_zbar Ĩ`` the
   Jacobian of the Euler integrability map (3.13) at the mean, one sparse
   Cholesky factorization of ``A A^T`` (symbolic analysis once per topology)
   and one multi-right-hand-side solve for all samples.  This is the
   *Euclidean* orthogonal projection the thesis writes (section 4.1, remark on
   implementation); ``projection_metric="g"`` gives the ``g``-orthogonal one,
   ``v = u - M^-1 A^T (A M^-1 A^T)^-1 A u`` (the tangent vector nearest to
   ``u`` in the metric of the PCA; lengths and angles then need no common
   unit).  Only interior vertices carry integrability conditions, so open
   meshes work unchanged.
3. **PCA in the metric g** (4.14): ``g(v, w) = 1/2 v^T d^2_2 W_q[zbar, zbar] w``
   (4.5).  For ``W_q`` (3.19) the Hessian is constant and diagonal,
   ``d^2_2 W_q = 2 diag(w)`` with ``w = (w_s, eta w_b)`` the residual weights
   (3.20) from the reference mesh, so ``g(v, w) = sum_k w_k v_k w_k``
   (:attr:`ShapeModel.metric_weights`).  The modes come from the ``N x N`` Gram
   matrix ``K = V M V^T`` (``M = diag(w)``): with ``K phi_j = lambda_j phi_j``,
   ``u_j = V^T phi_j / sqrt(lambda_j)`` is ``g``-orthonormal, so the cost grows
   with ``N``, not with ``E``.  As in (4.14) the tangent vectors are not
   re-centred: the subspace passes through ``zbar``.
4. **Synthesis** (4.19): ``P_Z[zbar + sum_j alpha_j u_j]`` by reconstruction,
   warm-started from the mean's vertices.

5. **Localized modes** (beyond the thesis, its "Sparse PCA" outlook):
   :meth:`ShapeModel.localized` rotates the modes within their span toward
   locality (a group varimax in ``g``).

Rigid motions of the training meshes change nothing (lengths and angles are
invariant; the mean's vertices are placed in the reference mesh's frame).

Modules
-------
This module holds :class:`ShapeModel` (its data and the projection of poses
onto it); its methods' algorithms live beside it: :mod:`.training` (steps 1-3),
:mod:`.tangent` (angles on the circle, :class:`~.tangent.TangentProjector`),
:mod:`.synthesis` (step 4), :mod:`.localization` (step 5), :mod:`.model_io`
(the file), :mod:`.settings` (defaults, :class:`~.settings.ShapeModelError`).
"""

import numpy as np

from ..energies import QuadraticEnergy
from ..errors import format_indices
from ..geometry.lengths_angles import lengths_and_angles
from . import localization, synthesis, training
from .model_io import FORMAT, FORMAT_VERSION, load_model, save_model
from .settings import (DEFAULT_BENDING_WEIGHT, DEFAULT_TANGENT, MIN_LENGTH_RATIO, MODEL_OPTIONS, MODEL_SETTINGS,
                       PROJECTION_METRICS, TANGENTS, ShapeModelError)
from .tangent import TangentProjector, wrap_angles

#: :class:`ShapeModel`; the other names are those of :mod:`.settings`, :mod:`.tangent` and :mod:`.model_io`,
#: importable from here too.
__all__ = ["ShapeModel", "ShapeModelError", "TangentProjector", "wrap_angles", "FORMAT", "FORMAT_VERSION", "TANGENTS",
           "DEFAULT_TANGENT", "PROJECTION_METRICS", "DEFAULT_BENDING_WEIGHT", "MODEL_SETTINGS", "MODEL_OPTIONS",
           "MIN_LENGTH_RATIO"]


class ShapeModel:
    """A ``J``-dimensional shape model in lengths and angles (thesis 4.3, (4.14)-(4.19)).

    Build with :meth:`fit` (vertex arrays) or :meth:`fit_z` (lengths and
    angles), or :meth:`load`.  All attributes are plain arrays (read them,
    do not modify them).

    Attributes
    ----------
    topology : MeshTopology
        Connectivity and edge order of ``z``.
    faces : (F, 3) int64 ndarray
    edges : (E, 2) int64 ndarray
    reference_vertices : (V, 3) ndarray
        Reference mesh: weights (3.20) of ``W_q``, frame of all reconstructions.
    mean_z : (2E,) ndarray
        Extrinsic mean ``zbar`` (4.16), admissible: ``Z[mean_vertices]``.
    mean_vertices : (V, 3) ndarray
        Immersion of the mean, in the reference frame.
    linear_mean_z : (2E,) ndarray
        ``(1/N) sum_i z^i`` before projection (angles averaged on the circle).
    modes : (J, 2E) ndarray
        ``u_j``, ``g``-orthonormal: ``modes * metric_weights @ modes.T = Id``.
    variances : (J,) ndarray
        ``lambda_j / N``: mean squared ``g``-length of the tangent vectors along ``u_j``.
    explained_variance_ratio : (J,) ndarray
        ``lambda_j / sum_k lambda_k`` (all ``N`` eigenvalues in the denominator).
    total_variance : float
        ``(1/N) sum_i g(v^i, v^i)``.
    training_coefficients : (N, J) ndarray
        ``alpha_ij = g(u_j, v^i)``.
    n_modes, n_samples : int
    tangent : {"ambient", "projected"}
        (4.18) or (4.17).
    projection_metric : {"euclidean", "g"}
        Metric of the tangent projection (``projected`` only).
    settings : ReconstructionSettings
        Weights and ``eta`` of ``W_q`` (the metric), fixed face, solver and ordering of the reconstructions.
    bending_weight : float
        ``eta`` of ``W_q`` (``settings.bending_weight``; default 0.005, the thesis' value for this application).
    weights : str
        Weight scheme of ``W_q`` (``settings.weights``; ``"frohlich_botsch"`` = (3.20)).
    energy : QuadraticEnergy
        ``W_q`` with weights from the reference.
    metric_weights : (2E,) ndarray
        Diagonal of the metric ``g`` (4.5): ``energy.residual_weights``; the
        Hessian of ``W_q`` in ``z`` is ``2 diag(metric_weights)``.
    method : str
        Reconstruction method of :meth:`synthesize` (see :func:`lacore.reconstruct`).
    timings : dict
        Seconds of the stages of :meth:`fit`: ``encode``, ``mean``,
        ``tangent_decomposition`` (Jacobian and Cholesky of ``A A^T``),
        ``tangent_solves``, ``gram``, ``eigen``, ``total`` (empty after :meth:`load`).
    mean_result : ReconstructionResult or None
        The reconstruction that projected the linear mean (None after :meth:`load`).

    Examples
    --------
    A model of a bar bent and twisted by nine pairs of angles (two degrees of freedom):

    >>> import numpy as np
    >>> from lacore import ShapeModel
    >>> from lacore.samples.bar import bar_family
    >>> poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
    >>> model = ShapeModel.fit(poses, faces, n_modes=2)
    >>> model.n_samples, model.n_modes, round(float(model.explained_variance_ratio.sum()), 4)
    (9, 2, 0.9981)
    >>> X = model.synthesize(model.training_coefficients[4])       # a training pose back
    >>> from lacore.geometry.rigid import rigid_rms
    >>> bool(rigid_rms(X, poses[4]) < 1e-3 * np.linalg.norm(np.ptp(poses[4], axis=0)))
    True
    """

    def __init__(self, *, topology, reference_vertices, mean_z, mean_vertices, linear_mean_z, modes, variances,
                 explained_variance_ratio, total_variance, training_coefficients, tangent, projection_metric,
                 settings, method, timings=None, mean_result=None, all_eigenvalues=None, projector=None,
                 fine_level=None, length_unit=None, up_axis=None, forward_axis=None):
        if settings.energy != "quadratic":
            raise ShapeModelError(f"a shape model's metric is the Hessian of W_q: settings.energy must be "
                                  f"'quadratic', got {settings.energy!r}")
        self.topology = topology
        self.reference_vertices = reference_vertices
        self.settings = settings
        self.energy = QuadraticEnergy(topology, reference_vertices=reference_vertices, weights=settings.weights,
                                      bending_weight=settings.bending_weight)
        self.mean_z = mean_z
        self.mean_vertices = mean_vertices
        self.linear_mean_z = linear_mean_z
        self.modes = modes
        self.variances = variances
        self.explained_variance_ratio = explained_variance_ratio
        self.total_variance = float(total_variance)
        self.training_coefficients = training_coefficients
        self.tangent = tangent
        self.projection_metric = projection_metric
        self.method = method
        self.timings = dict(timings or {})
        self.mean_result = mean_result
        self.all_eigenvalues = all_eigenvalues
        self._projector = projector
        #: Optional :class:`lacore.models.FineLevel`: prolongation of poses to the fine mesh.
        self.fine_level = fine_level
        #: Optional length of one model unit in metres (e.g. 0.1 for decimetres); None if not declared.
        self.length_unit = None if length_unit is None else float(length_unit)
        #: Optional up and forward axes of the reference mesh (``"x"``, ``"-y"``...); None if not declared.
        self.up_axis = up_axis
        self.forward_axis = forward_axis

    def log_length_modes(self, n_modes=None):
        """The first ``n_modes`` modes for the logarithms of the edge lengths relative to the mean ``(J, E)``.

        ``log(l / lbar) ~ alpha @ Ulog`` with ``lbar`` the mean's lengths: the least-squares fit,
        over the training poses, of the logarithms of their lengths within the modes (``lbar +
        alpha_i U_l``, floored at :data:`MIN_LENGTH_RATIO` of ``lbar``) from their coefficients
        ``alpha_i``.  The fitting's prior uses them (:attr:`lacore.markers.FitOptions.log_lengths`):
        a sum of modes that each shorten an edge multiplies the length by their factors instead of
        subtracting their shortenings, and never reaches 0.  Without training coefficients (fewer
        than 2) the modes at first order, ``U_l / lbar``.

        Examples
        --------
        >>> import numpy as np
        >>> from lacore import ShapeModel
        >>> from lacore.samples.bar import bar_family
        >>> poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
        >>> model = ShapeModel.fit(poses, faces, n_modes=2)
        >>> lbar = model.mean_z[:model.topology.n_edges]
        >>> L = lbar * np.exp(model.training_coefficients @ model.log_length_modes())   # training poses' lengths
        >>> from lacore.geometry.lengths_angles import lengths_and_angles
        >>> true = lengths_and_angles(poses[4], model.topology)[:len(lbar)]
        >>> bool(np.abs(L[4] / true - 1).max() < 0.01)
        True
        """
        E = self.topology.n_edges
        U = np.asarray(self.modes, float)[:n_modes, :E]
        lbar = np.asarray(self.mean_z, float)[:E]
        T = self.training_coefficients
        if T is None or len(T) < 2:
            return U / lbar
        T = np.asarray(T, float)[:, :len(U)]
        L = np.maximum(lbar + T @ U, MIN_LENGTH_RATIO * lbar)
        return np.linalg.lstsq(T, np.log(L / lbar), rcond=None)[0]

    # ------------------------------------------------------------------ properties
    @property
    def faces(self):
        """(F, 3) int64 faces."""
        return self.topology.faces

    @property
    def edges(self):
        """(E, 2) int64 edges in the order of ``z``."""
        return self.topology.edges

    @property
    def n_modes(self):
        """``J``."""
        return int(self.modes.shape[0])

    @property
    def n_samples(self):
        """``N``, the number of training samples."""
        return int(self.training_coefficients.shape[0])

    @property
    def bending_weight(self):
        """``eta`` of ``W_q`` (``settings.bending_weight``)."""
        return self.settings.bending_weight

    @property
    def weights(self):
        """Weight scheme of ``W_q`` (``settings.weights``)."""
        return self.settings.weights

    @property
    def metric_weights(self):
        """Diagonal of ``g`` (4.5), ``(2E,)``: ``g(u, v) = sum(metric_weights * u * v)``."""
        return self.energy.residual_weights

    @property
    def standard_deviations(self):
        """``sqrt(variances)``, (J,)."""
        return np.sqrt(self.variances)

    def metric_dot(self, u, v):
        """``g(u, v)`` (4.5) of vectors ``(..., 2E)``, broadcast over leading axes."""
        return np.sum(np.asarray(u, float) * self.metric_weights * np.asarray(v, float), axis=-1)

    def __repr__(self):
        return (f"ShapeModel(vertices={self.topology.n_vertices}, edges={self.topology.n_edges}, "
                f"samples={self.n_samples}, modes={self.n_modes}, tangent={self.tangent!r}, "
                f"explained={float(np.sum(self.explained_variance_ratio)):.4f})")

    # ------------------------------------------------------------------ fitting (:mod:`.training`)
    fit = classmethod(training.fit)
    fit_z = classmethod(training.fit_z)

    # ------------------------------------------------------------------ using the model
    def tangent_projector(self):
        """The :class:`~.tangent.TangentProjector` at the mean (built on first use, e.g. after :meth:`load`)."""
        if self._projector is None:
            self._projector = TangentProjector(self.mean_z, self.topology, metric_weights=self.metric_weights,
                                               metric=self.projection_metric, solver=self.settings.solver)
        return self._projector

    def tangent_vectors(self, z):
        """Tangent vectors of samples ``z (N, 2E)`` or ``(2E,)`` by the model's variant, (4.17) or (4.18)."""
        z = self._as_z(z)
        v = wrap_angles(z - self.mean_z, self.topology)
        if self.tangent == "projected":
            v = self.tangent_projector()(v)
        return v

    def _as_z(self, x):
        """``x`` as lengths and angles ``(2E,)`` / ``(K, 2E)``: given as z or as vertices ``(V, 3)`` / ``(K, V, 3)``."""
        x = np.asarray(x, float)
        topo = self.topology
        V, E2 = topo.n_vertices, 2 * topo.n_edges
        if x.shape[-2:] == (V, 3) and x.ndim in (2, 3):
            if x.ndim == 2:
                return lengths_and_angles(x, topo)
            return np.stack([lengths_and_angles(xi, topo) for xi in x])
        if x.shape[-1:] == (E2,) and x.ndim in (1, 2):
            bad = np.flatnonzero(~np.all(np.isfinite(np.atleast_2d(x)), axis=0))
            if bad.size:
                raise ShapeModelError(f"lengths and angles with NaN or infinite entries at {format_indices(bad)}")
            return x
        raise ShapeModelError(f"expected lengths and angles of shape ({E2},) or (K, {E2}), or vertices of shape "
                              f"({V}, 3) or (K, {V}, 3) for this model's mesh; got {x.shape}")

    def coefficients(self, x, tangent=None):
        """Coefficients ``alpha_j = g(u_j, v)`` of poses in the model: the ``g``-orthogonal projection onto the modes.

        Parameters
        ----------
        x : (2E,), (K, 2E), (V, 3) or (K, V, 3) array_like
            Lengths and angles or vertices (any rigid placement) of one or ``K`` poses.
        tangent : {"ambient", "projected"}, optional
            How ``v`` is formed from ``z - zbar``; default the model's
            :attr:`tangent`, so that the training poses give
            :attr:`training_coefficients`.  ``"ambient"`` gives the plain
            ``g``-orthogonal projection of ``z - zbar`` used by the prior (4.22).

        Returns
        -------
        (J,) or (K, J) ndarray

        Examples
        --------
        >>> import numpy as np
        >>> from lacore import ShapeModel
        >>> from lacore.samples.bar import bar_family
        >>> poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
        >>> model = ShapeModel.fit(poses, faces, n_modes=2)
        >>> a = model.coefficients(poses[4])             # any rigid placement of the pose
        >>> bool(np.allclose(a, model.training_coefficients[4]))
        True
        """
        z = self._as_z(x)
        tangent = self.tangent if tangent is None else tangent
        if tangent not in TANGENTS:
            raise ShapeModelError(f"unknown tangent {tangent!r}; use 'ambient' or 'projected'")
        v = wrap_angles(z - self.mean_z, self.topology)
        if tangent == "projected":
            v = self.tangent_projector()(v)
        return (v * self.metric_weights) @ self.modes.T

    def z_of(self, coefficients):
        """``zbar + sum_j alpha_j u_j`` for ``(J,)`` or ``(K, J)`` coefficients (the argument of ``P_Z`` in (4.19))."""
        a = self.check_coefficients(coefficients)
        return wrap_angles(self.mean_z + a @ self.modes, self.topology)

    def check_coefficients(self, coefficients):
        """``coefficients`` as a float ``(J,)`` or ``(K, J)`` array; :class:`ShapeModelError` if they do not fit."""
        a = np.asarray(coefficients, float)
        if a.shape[-1:] != (self.n_modes,) or a.ndim not in (1, 2):
            raise ShapeModelError(f"coefficients must have shape ({self.n_modes},) or (K, {self.n_modes}) for a "
                                  f"model with {self.n_modes} modes, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ShapeModelError("coefficients contain NaN or infinite values")
        return a

    # ------------------------------------------------------------------ synthesis (:mod:`.synthesis`)
    synthesis_targets = synthesis.synthesis_targets
    synthesize = synthesis.synthesize
    mode_sweep = synthesis.mode_sweep

    # ------------------------------------------------------------------ localized modes (:mod:`.localization`)
    localized = localization.localized
    region_energy = localization.region_energy

    def check_mesh(self, vertices=None, faces=None):
        """Raise :class:`ShapeModelError` unless ``faces`` / ``vertices`` have this model's connectivity and size."""
        if faces is not None:
            f = np.asarray(faces)
            if f.shape != self.faces.shape or not np.array_equal(f, self.faces):
                raise ShapeModelError(f"the mesh's {len(f)} faces are not this model's connectivity "
                                      f"({len(self.faces)} faces, {self.topology.n_vertices} vertices)")
        if vertices is not None:
            x = np.asarray(vertices)
            if x.shape != (self.topology.n_vertices, 3):
                raise ShapeModelError(f"the mesh has vertices of shape {x.shape}, the model ({self.topology.n_vertices}"
                                      ", 3)")

    # ------------------------------------------------------------------ files
    def save(self, path):
        """Write the model to one ``.npz`` file (atomically) or binary file object (:func:`~.model_io.save_model`).

        The entries are the rows of :data:`lacore.models.model_io.FIELDS`; ``.npz`` is appended to a file
        name without it and the path written is returned.

        Examples
        --------
        >>> import numpy as np
        >>> from lacore import ShapeModel
        >>> from lacore.samples.bar import bar_family
        >>> poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
        >>> model = ShapeModel.fit(poses, faces, n_modes=2)
        >>> import io
        >>> buffer = io.BytesIO()                        # or a path ending in .npz
        >>> model.save(buffer)
        >>> loaded = ShapeModel.load(io.BytesIO(buffer.getvalue()), faces=faces)
        >>> bool(np.array_equal(loaded.modes, model.modes)), loaded.bending_weight
        (True, 0.005)
        """
        return save_model(self, path)

    @classmethod
    def load(cls, path, faces=None):
        """Read a model written by :meth:`save` (:func:`~.model_io.load_model`).

        Parameters
        ----------
        path : str, path-like or binary file object
        faces : (F, 3) array_like, optional
            If given, the model must have exactly these faces.

        Raises
        ------
        ShapeModelError
            Not a shape-model file, another format version, inconsistent arrays,
            or other faces than ``faces``.
        FileNotFoundError
        """
        return load_model(path, cls, faces=faces)
