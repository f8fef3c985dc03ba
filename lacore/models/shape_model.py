"""Statistical shape models in lengths and angles: PCA and simplified PGA (thesis section 4.3).

From ``N`` example poses of one mesh (vertex arrays in dense correspondence, or
their lengths and angles ``z^i``) :meth:`ShapeModel.fit` learns a
``J``-dimensional family of natural deformations:

1. **Mean** (4.16): the extrinsic mean ``zbar = P_Z[(1/N) sum_i z^i]``, the
   projection of the linear mean onto the admissible set by reconstruction
   (:func:`lacore.shapes.projection.project`, Gauss-Newton on ``W_q`` by default).
   Dihedral angles are averaged on the circle (differences to the reference
   taken modulo ``2 pi``, :func:`wrap_angles`), and every angle difference
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
"""

import copy
import time
from dataclasses import replace

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from ..energies import QuadraticEnergy
from ..errors import LengthsAnglesError, MeshError, format_indices
from ..integrability.local import euler_integrability_jacobian
from ..geometry.lengths_angles import check_nondegenerate, check_z, lengths_and_angles
from ..progress import report
from ..shapes.projection import project
from ..reconstruction import METHODS, reconstruct
from ..linalg.sparse_cholesky import SparseCholesky
from ..geometry.topology import MeshTopology, check_vertices
from .model_io import FORMAT, FORMAT_VERSION, load_model, save_model
from .settings import (DEFAULT_BENDING_WEIGHT, DEFAULT_TANGENT, MIN_LENGTH_RATIO, MODEL_OPTIONS, MODEL_SETTINGS,
                       PROJECTION_METRICS, TANGENTS, ShapeModelError)

__all__ = ["ShapeModel", "ShapeModelError", "TangentProjector", "wrap_angles", "FORMAT", "FORMAT_VERSION", "TANGENTS",
           "DEFAULT_TANGENT", "PROJECTION_METRICS", "DEFAULT_BENDING_WEIGHT", "MODEL_SETTINGS", "MODEL_OPTIONS",
           "MIN_LENGTH_RATIO"]

#: Eigenvalues below this fraction of the largest are treated as zero variance.
_RANK_TOL = 1e-12


# --------------------------------------------------------------------------- tangent projection
class TangentProjector:
    """Linear projection onto the tangent space ``T_z Z = ker D_z Ĩ`` (4.4), (4.17), without an explicit basis.

    ``P u = u - C A^T (A C A^T)^-1 A u`` with ``A = D_z Ĩ`` (Jacobian of the
    Euler integrability map, ``(3 V_int, 2E)``) and ``C = Id`` (Euclidean, the
    thesis' formula) or ``C = M^-1`` (``g``-orthogonal; entries of zero weight,
    the angles of boundary edges, are held at their value, which is 0).

    ``A C A^T`` is singular on closed meshes (the ``3 V`` conditions have rank
    ``3 V - 6``, (4.3)), so it is equilibrated to unit diagonal, factorized
    with a tiny diagonal shift ``delta = shift`` and the projection is
    refined: each step applies the shifted projection to the remainder, which
    shrinks ``|A v|`` by about ``delta / sigma_min^2``, until
    ``|A v| <= rtol |A u|`` or no further progress.  The factorization is one
    :class:`~lacore.linalg.sparse_cholesky.SparseCholesky` whose symbolic
    analysis is cached on the topology.

    Parameters
    ----------
    z : (2E,) array_like
        Point of ``Z`` (admissible lengths and angles), e.g. the mean.
    topology : MeshTopology
    metric_weights : (2E,) array_like, optional
        Diagonal of ``M``; required for ``metric="g"``.
    metric : {"euclidean", "g"}
    shift : float
        Diagonal shift of the equilibrated ``A C A^T`` (default ``1e-14``).
    max_refinements : int
        At most this many refinement steps after the first projection (default 8).
    rtol : float
        Target of ``|A v| / |A u|`` per vector (default ``1e-13``).
    solver : {"cholmod", "scipy"}, optional
        Sparse Cholesky backend.

    Attributes
    ----------
    jacobian : (3 V_int, 2E) sparse matrix
        ``A = D_z Ĩ``.
    timings : dict
        ``jacobian``, ``factorization`` (seconds).
    last_refinements : int
        Refinement steps of the last call.
    """

    def __init__(self, z, topology, metric_weights=None, metric="euclidean", shift=1e-14, max_refinements=8,
                 rtol=1e-13, solver=None):
        if metric not in PROJECTION_METRICS:
            raise ValueError(f"unknown projection metric {metric!r}; use 'euclidean' or 'g'")
        t0 = time.perf_counter()
        A = euler_integrability_jacobian(z, topology).tocsr()
        t1 = time.perf_counter()
        n = 2 * topology.n_edges
        if metric == "g":
            if metric_weights is None:
                raise ValueError("metric='g' needs metric_weights")
            w = np.asarray(metric_weights, float)
            c = np.divide(1.0, w, out=np.zeros(n), where=w > 0)
        else:
            c = np.ones(n)
        self.metric = metric
        self.jacobian = A
        self._c = c
        self._AC = (A @ sp.diags(c)).tocsr()
        S = (self._AC @ A.T).tocsc()
        cache = topology.cache.get((__name__, "tangent_cholesky"), dict)
        key = (metric, solver)
        chol = cache.get(key)
        if chol is None:
            # structural pattern of A A^T (a product of values may cancel to an exact zero and be dropped)
            B = sp.csr_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape)
            chol = SparseCholesky((B @ B.T).tocsc(), backend=solver)
            cache[key] = chol
        # symmetric diagonal equilibration D S D (unit diagonal): the shift then acts evenly (one solve less)
        diag = S.diagonal()
        self._d = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 1.0)
        Dm = sp.diags(self._d)
        values = chol.values_from_matrix((Dm @ S @ Dm).tocsc())
        self.shift = float(shift)
        values[chol.diagonal] += self.shift
        chol.factorize(values)  # adds a larger shift itself if rounding made a pivot non-positive
        self.shift += chol.shift
        self._chol = chol
        self.max_refinements = int(max_refinements)
        self.rtol = float(rtol)
        self.last_refinements = 0
        t2 = time.perf_counter()
        self.timings = {"jacobian": t1 - t0, "factorization": t2 - t1}

    def __call__(self, u):
        """Project ``u`` of shape ``(2E,)`` or ``(N, 2E)`` (rows) onto the tangent space."""
        u = np.asarray(u, float)
        U = np.atleast_2d(u).T.copy()  # (2E, N)
        if self._chol.n == 0:
            return u.copy()
        A = self.jacobian
        AU = np.asarray(A @ U)
        r0 = np.linalg.norm(AU, axis=0)
        r0 = np.where(r0 > 0, r0, 1.0)
        last = np.inf
        for k in range(1 + self.max_refinements):
            x = self._d[:, None] * self._chol.solve(self._d[:, None] * AU)
            U -= self._c[:, None] * np.asarray(A.T @ x)
            AU = np.asarray(A @ U)
            rel = float(np.max(np.linalg.norm(AU, axis=0) / r0))
            self.last_refinements = k
            if rel <= self.rtol or rel > 0.5 * last:  # converged, or stagnating at round-off
                break
            last = rel
        out = U.T
        return out[0] if u.ndim == 1 else out

    def residual(self, v):
        """``|A v|_2`` per row of ``v`` (0 for tangent vectors)."""
        v = np.atleast_2d(np.asarray(v, float))
        return np.linalg.norm(np.asarray(self.jacobian @ v.T), axis=0)


# --------------------------------------------------------------------------- the model
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
                 settings, method, timings=None, mean_result=None, all_eigenvalues=None):
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
        self._projector = None

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

    # ------------------------------------------------------------------ fitting
    @classmethod
    def fit(cls, vertices, topology, *, reference_vertices=None, **options):
        """Fit a model to ``N`` meshes in dense correspondence.

        Parameters
        ----------
        vertices : (N, V, 3) array_like or sequence of (V, 3) arrays
            Training poses with the connectivity of ``topology`` (any rigid
            placement).
        topology : MeshTopology or (F, 3) array_like of faces
        reference_vertices : (V, 3) array_like, optional
            Reference mesh (weights of ``W_q``, output frame); default the first pose.
        **options
            See :meth:`fit_z`.

        Returns
        -------
        ShapeModel

        Examples
        --------
        >>> import numpy as np
        >>> from lacore import ShapeModel
        >>> from lacore.samples.bar import bar_family
        >>> poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
        >>> model = ShapeModel.fit(poses, faces, n_modes=2)
        >>> model
        ShapeModel(vertices=22, edges=60, samples=9, modes=2, tangent='ambient', explained=0.9981)
        >>> model.settings.bending_weight, model.tangent
        (0.005, 'ambient')
        """
        topology = _as_topology(topology, vertices)
        t0 = time.perf_counter()
        X = _check_poses(vertices, topology)
        Z = np.stack([lengths_and_angles(x, topology, check=False) for x in X])
        t_encode = time.perf_counter() - t0
        reference = X[0] if reference_vertices is None else reference_vertices
        model = cls.fit_z(Z, topology, reference, **options)
        model.timings["encode"] = t_encode
        model.timings["total"] += t_encode
        return model

    @classmethod
    def fit_z(cls, z, topology, reference_vertices, *, n_modes=None, tangent=DEFAULT_TANGENT,
              projection_metric=PROJECTION_METRICS[0], method="gn", settings=None, options=None, progress=None):
        """Fit a model to ``N`` lengths-and-angles vectors (4.14)-(4.18).

        Parameters
        ----------
        z : (N, 2E) array_like
            Training samples ``z^i`` (edge order of ``topology``).
        topology : MeshTopology
        reference_vertices : (V, 3) array_like
            Reference mesh: weights (3.20) of ``W_q``, start and frame of the
            mean's reconstruction.
        n_modes : int, optional
            ``J``, ``1 <= J <= N - 1``; default ``N - 1``.
        tangent : {"ambient", "projected"}
            (4.18) ``v = z - zbar`` (default, :data:`DEFAULT_TANGENT` says why) or (4.17)
            its linear projection onto ``T_zbar Z`` (the thesis' simplified PGA).
        projection_metric : {"euclidean", "g"}
            Orthogonality of the tangent projection: the thesis' Euclidean
            ``Id - A^T (A A^T)^-1 A`` (default) or ``g``-orthogonal.
        method : str
            Reconstruction method of the mean and of :meth:`synthesize`
            (``"gn"``: energy-based projection, Def. 4.3).
        settings : ReconstructionSettings, optional
            ``W_q`` (energy ``"quadratic"``): its weights (3.20) (default), (3.21)
            or 1 and ``eta`` give the metric; with fixed face, solver and ordering
            they are the settings of the mean's projection and of :meth:`synthesize`
            (the solver also of the tangent projection).  Default
            :data:`~lacore.models.settings.MODEL_SETTINGS` (``eta = 0.005``, thesis 4.3.2).
        options : GaussNewtonOptions, optional
            Options of the mean's projection; default
            :data:`~lacore.models.settings.MODEL_OPTIONS` (no geodesic acceleration).
        progress : callable, optional
            ``progress(done, total, message)`` over the stages (see :mod:`lacore.progress`).

        Returns
        -------
        ShapeModel

        Raises
        ------
        ShapeModelError
            Fewer than 2 samples, ``n_modes`` outside ``1..N-1`` or larger
            than the number of directions with non-zero variance, unknown
            ``tangent``.
        LengthsAnglesError, MeshError
            Samples that do not fit the mesh, a bad reference mesh.
        """
        t_start = time.perf_counter()
        if tangent not in TANGENTS:
            raise ShapeModelError(f"unknown tangent {tangent!r}; use 'ambient' or 'projected'")
        if projection_metric not in PROJECTION_METRICS:
            raise ShapeModelError(f"unknown projection_metric {projection_metric!r}; use 'euclidean' or 'g'")
        if method not in METHODS:
            raise ShapeModelError(f"unknown reconstruction method {method!r}; use one of {', '.join(METHODS)}")
        if not isinstance(topology, MeshTopology):
            raise TypeError(f"topology must be a MeshTopology, got {type(topology).__name__}")
        settings = MODEL_SETTINGS if settings is None else settings
        if settings.energy != "quadratic":
            raise ShapeModelError(f"a shape model's metric is the Hessian of W_q: settings.energy must be "
                                  f"'quadratic', got {settings.energy!r}")
        Z = np.asarray(z, float)
        E2 = 2 * topology.n_edges
        if Z.ndim != 2 or Z.shape[1] != E2:
            raise ShapeModelError(f"z must have shape (N, {E2}) (N samples of 2 x {topology.n_edges} edges), "
                                  f"got {Z.shape}")
        N = Z.shape[0]
        if N < 2:
            raise ShapeModelError(f"a shape model needs at least 2 training samples, got {N}")
        for i in range(N):
            try:
                check_z(Z[i], topology, name=f"training sample {i}")
            except LengthsAnglesError as exc:
                raise ShapeModelError(str(exc)) from None
        J = N - 1 if n_modes is None else n_modes
        if int(J) != J or not 1 <= J <= N - 1:
            raise ShapeModelError(f"n_modes must be an integer from 1 to N - 1 = {N - 1} ({N} samples), got {J}")
        J = int(J)
        X_ref = check_nondegenerate(check_vertices(reference_vertices, topology.n_vertices,
                                                   name="reference vertices"), topology)
        n_stages = 4
        report(progress, 0, n_stages, "mean")

        # (4.16) extrinsic mean; angles averaged on the circle about the reference (no effect unless samples
        # straddle the branch cut at +-pi, e.g. skin folded by skinning)
        t = time.perf_counter()
        z_ref = lengths_and_angles(X_ref, topology)
        z_lin = wrap_angles(z_ref + wrap_angles(Z - z_ref, topology).mean(axis=0), topology)
        mean_z, mean_result = project(z_lin, topology, X_ref, method=method, settings=settings,
                                      options=MODEL_OPTIONS if options is None else options)
        mean_vertices = mean_result.vertices
        t_mean = time.perf_counter() - t
        report(progress, 1, n_stages, "tangent vectors")

        energy = QuadraticEnergy(topology, reference_vertices=X_ref, weights=settings.weights,
                                 bending_weight=settings.bending_weight)
        w = energy.residual_weights
        Vt = wrap_angles(Z - mean_z, topology)  # (4.18)
        t_dec = t_solve = 0.0
        projector = None
        if tangent == "projected":  # (4.17)
            t = time.perf_counter()
            projector = TangentProjector(mean_z, topology, metric_weights=w, metric=projection_metric,
                                         solver=settings.solver)
            t_dec = time.perf_counter() - t
            t = time.perf_counter()
            Vt = projector(Vt)
            t_solve = time.perf_counter() - t
        report(progress, 2, n_stages, "Gram matrix")

        # (4.14) PCA in g through the N x N Gram matrix
        t = time.perf_counter()
        VW = Vt * w
        K = VW @ Vt.T
        K = 0.5 * (K + K.T)
        t_gram = time.perf_counter() - t
        report(progress, 3, n_stages, "eigendecomposition")
        t = time.perf_counter()
        lam, phi = scipy.linalg.eigh(K)
        lam, phi = lam[::-1], phi[:, ::-1]
        t_eig = time.perf_counter() - t
        lam_all = np.maximum(lam, 0.0)
        total = float(lam_all.sum())
        # directions of zero variance: below _RANK_TOL of the largest eigenvalue, or (all samples equal up to
        # round-off) below 1e-20 of the samples' own squared g-size
        floor = _RANK_TOL * max(lam_all[0], float(np.sum(Z * Z * w)) * 1e-8)
        n_pos = int(np.count_nonzero(lam_all > floor))
        if J > n_pos:
            raise ShapeModelError(f"only {n_pos} directions of the {N} training samples have non-zero variance "
                                  f"(identical samples?); asked for n_modes={J}")
        lam_J, phi_J = lam_all[:J], phi[:, :J]
        modes = (phi_J.T @ Vt) / np.sqrt(lam_J)[:, None]
        coeffs = phi_J * np.sqrt(lam_J)[None, :]
        # sign convention: the largest-magnitude entry of each mode (in g-scaled units) is positive
        k = np.argmax(np.abs(modes) * np.sqrt(w), axis=1)
        sign = np.where(modes[np.arange(J), k] < 0, -1.0, 1.0)
        modes *= sign[:, None]
        coeffs *= sign[None, :]
        report(progress, 4, n_stages, "done")
        timings = {"mean": t_mean, "tangent_decomposition": t_dec, "tangent_solves": t_solve, "gram": t_gram,
                   "eigen": t_eig, "total": time.perf_counter() - t_start}
        model = cls(topology=topology, reference_vertices=X_ref, mean_z=mean_z, mean_vertices=mean_vertices,
                    linear_mean_z=z_lin, modes=modes, variances=lam_J / N,
                    explained_variance_ratio=lam_J / total, total_variance=total / N,
                    training_coefficients=coeffs, tangent=tangent, projection_metric=projection_metric,
                    settings=settings, method=method, timings=timings, mean_result=mean_result,
                    all_eigenvalues=lam_all)
        model._projector = projector
        return model

    # ------------------------------------------------------------------ using the model
    def tangent_projector(self):
        """The :class:`TangentProjector` at the mean (built on first use, e.g. after :meth:`load`)."""
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
        a = self._check_coefficients(coefficients)
        return wrap_angles(self.mean_z + a @ self.modes, self.topology)

    def _check_coefficients(self, coefficients):
        a = np.asarray(coefficients, float)
        if a.shape[-1:] != (self.n_modes,) or a.ndim not in (1, 2):
            raise ShapeModelError(f"coefficients must have shape ({self.n_modes},) or (K, {self.n_modes}) for a "
                                  f"model with {self.n_modes} modes, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ShapeModelError("coefficients contain NaN or infinite values")
        return a

    def synthesis_targets(self, coefficients, min_length_ratio=MIN_LENGTH_RATIO):
        """The lengths and angles :meth:`synthesize` projects: ``zbar + sum_j alpha_j u_j``, lengths floored.

        Far along a mode (or with extreme coefficients) a length varying strongly
        over the training set, e.g. in a skin crease, reaches zero or below;
        lengths below ``min_length_ratio`` times the mean's length of the same
        edge are raised to that floor.

        Parameters
        ----------
        coefficients : (J,) or (K, J) array_like
        min_length_ratio : float
            The floor as a fraction of the mean's lengths.

        Returns
        -------
        z : (2E,) or (K, 2E) ndarray
        clamped : (E,) or (K, E) bool ndarray
            The lengths raised to the floor.
        """
        z = self.z_of(coefficients)
        E = self.topology.n_edges
        floor = float(min_length_ratio) * self.mean_z[:E]
        clamped = z[..., :E] < floor
        z[..., :E] = np.maximum(z[..., :E], floor)
        return z, clamped

    def synthesize(self, coefficients, *, method=None, options=None, hybrid=None, initial_vertices=None,
                   min_length_ratio=MIN_LENGTH_RATIO, progress=None, return_results=False):
        """Poses of the model, ``P_Z[zbar + sum_j alpha_j u_j]`` (4.19), as vertices.

        Changes nothing in the model: the same coefficients give the same poses.

        Parameters
        ----------
        coefficients : (J,) or (K, J) array_like
        method : str, optional
            Reconstruction method (default :attr:`method`), see :func:`lacore.reconstruct`.
        options : GaussNewtonOptions, optional
            Gauss-Newton options; default :data:`~lacore.models.settings.MODEL_OPTIONS`
            (no geodesic acceleration: at +-2 standard deviations of a body's modes the
            accelerated iteration stops at higher energies).
        hybrid : HybridOptions, optional
            Options of ``method="hybrid"``.
        initial_vertices : (V, 3) array_like, optional
            Gauss-Newton start (default the mean's vertices, for every pose).
        min_length_ratio : float
            Floor of the target lengths (:meth:`synthesis_targets`, which also says
            which were raised); a result's ``notes`` count them.
        progress : callable, optional
            ``progress(done, total, message)`` per pose.
        return_results : bool
            Also return the :class:`~lacore.reconstruction.ReconstructionResult` of every pose.

        Returns
        -------
        vertices : (V, 3) or (K, V, 3) ndarray
            In the frame of the reference mesh.
        results : ReconstructionResult or list of them (only with ``return_results``)

        Examples
        --------
        >>> import numpy as np
        >>> from lacore import ShapeModel
        >>> from lacore.samples.bar import bar_family
        >>> poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
        >>> model = ShapeModel.fit(poses, faces, n_modes=2)
        >>> X, result = model.synthesize(2 * model.standard_deviations * [1, 0], return_results=True)
        >>> X.shape, result.success
        ((22, 3), True)
        >>> poses = model.synthesize(np.eye(2) * model.standard_deviations)   # K = 2 poses at once
        >>> poses.shape
        (2, 22, 3)
        """
        a = self._check_coefficients(coefficients)
        single = a.ndim == 1
        A = np.atleast_2d(a)
        method = self.method if method is None else method
        options = MODEL_OPTIONS if options is None else options
        X0 = self.mean_vertices if initial_vertices is None else initial_vertices
        zs, clamped = self.synthesis_targets(A, min_length_ratio)
        out = np.empty((len(A), self.topology.n_vertices, 3))
        results = []
        for k, zk in enumerate(zs):
            report(progress, k, len(A), f"pose {k + 1} of {len(A)}")
            res = reconstruct(zk, self.topology, self.reference_vertices, method=method, settings=self.settings,
                              options=options, hybrid=hybrid, initial_vertices=X0)
            n = int(np.count_nonzero(clamped[k]))
            if n:
                res = replace(res, notes=res.notes + [f"{n} target lengths below {min_length_ratio:g} of the mean's "
                                                      "were raised to that floor"])
            out[k] = res.vertices
            results.append(res)
        report(progress, len(A), len(A), "done")
        if single:
            out, results = out[0], results[0]
        return (out, results) if return_results else out

    def mode_sweep(self, mode, t_range=(-2.0, 2.0), n_frames=5, in_std=True, progress=None, **synthesize_options):
        """Poses along one mode, ``P_Z[zbar + t u_j]`` for ``n_frames`` values of ``t`` (thesis Figure 4.4).

        Parameters
        ----------
        mode : int
            ``j`` in ``0..J-1``.
        t_range : (float, float)
            First and last ``t``.
        n_frames : int
            ``K >= 1`` evenly spaced values (inclusive).
        in_std : bool
            ``t`` in standard deviations of the mode (default; ``alpha_j = t sqrt(variance_j)``)
            or, if False, the raw factor of the ``g``-unit mode (as the thesis' ``t = +-10``).
        progress : callable, optional
            ``progress(done, total, message)`` per pose.
        **synthesize_options
            Keyword arguments of :meth:`synthesize` (``method``, ``options``, ``return_results`` ...).

        Returns
        -------
        vertices : (K, V, 3) ndarray
            (with ``return_results``: ``(vertices, results)``)
        t : (K,) ndarray
        """
        if int(mode) != mode or not 0 <= mode < self.n_modes:
            raise ShapeModelError(f"mode must be an integer from 0 to {self.n_modes - 1}, got {mode}")
        if int(n_frames) != n_frames or n_frames < 1:
            raise ShapeModelError(f"n_frames must be a positive integer, got {n_frames}")
        t = np.linspace(float(t_range[0]), float(t_range[1]), int(n_frames))
        A = np.zeros((len(t), self.n_modes))
        A[:, int(mode)] = t * (self.standard_deviations[int(mode)] if in_std else 1.0)
        return self.synthesize(A, progress=progress, **synthesize_options), t

    def localized(self, regions=None, n_starts=3, max_iterations=500, tol=1e-10, seed=0):
        """The same subspace with modes rotated toward locality (beyond the thesis: its "Sparse PCA" outlook).

        A *group varimax* rotation in the metric ``g``: with the ``g``-unit
        loadings ``L = U sqrt(M)`` (rows orthonormal) and the energy of mode
        ``j`` in region ``r``, ``e_jr = sum_{k in r} L'_jk^2`` (``sum_r e_jr = 1``),
        find the rotation ``R`` (``J x J`` orthogonal, ``U' = R U``) maximizing
        ``sum_j sum_r e_jr^2``: each mode's energy gathered in as few regions as
        possible.  Maximized by the usual varimax iteration ``R <- polar(grad)``
        (monotone for this convex objective) from the identity and from
        ``n_starts - 1`` random rotations (the best is kept: symmetric data make
        the PCA modes a stationary point).  The span, the synthesized poses
        and the fit of any pose are unchanged; the modes are no longer
        uncorrelated over the training set.

        Parameters
        ----------
        regions : (V,) or (2E,) array_like of int, optional
            Region label per vertex (an entry of ``z`` then counts half for
            each end vertex of its edge) or per entry of ``z``.  Default: every
            vertex its own region (locality on the scale of a one-ring).
        n_starts : int
            Starting rotations (default 3).
        max_iterations : int
            Per start.
        tol : float
            Stop when the objective grows by less than ``tol`` (relative).
        seed : int
            Seed of the random starts.

        Returns
        -------
        ShapeModel
            A copy with rotated ``modes``, ``training_coefficients`` (``C R^T``),
            ``variances`` (mean squared coefficients), ``explained_variance_ratio``
            (of the total), sorted by variance; ``rotation`` ``(J, J)`` and
            ``localization`` (the objective before and after, iterations) set.
        """

        t0 = time.perf_counter()
        G = self._region_matrix(regions)
        L = self.modes * np.sqrt(self.metric_weights)  # (J, 2E), orthonormal rows
        J = self.n_modes
        rng = np.random.default_rng(seed)
        best, best_f, iterations = None, -np.inf, []
        for start in range(max(1, int(n_starts))):
            # the identity, then random rotations: symmetric data make the PCA modes a stationary point
            R = np.eye(J) if start == 0 else np.linalg.qr(rng.normal(size=(J, J)))[0]
            last = -np.inf
            it = 0
            while it < int(max_iterations):
                it += 1
                Lr = R @ L
                e = (G @ (Lr * Lr).T).T  # (J, n_regions)
                f = float(np.sum(e * e))
                if f - last <= tol * abs(f):
                    break
                last = f
                grad = (4.0 * (e @ G) * Lr) @ L.T  # d f / d R, (J, J)
                u, _, vt = np.linalg.svd(grad)
                R = u @ vt
            iterations.append(it)
            if last > best_f * (1 + 1e-9):
                best, best_f = R, last
        R = best
        it = iterations
        Lr = R @ L
        e0 = (G @ (L * L).T).T
        e1 = (G @ (Lr * Lr).T).T
        coeffs = self.training_coefficients @ R.T
        var = np.mean(coeffs**2, axis=0)
        order = np.argsort(-var, kind="stable")
        R, coeffs, var = R[order], coeffs[:, order], var[order]
        modes = R @ self.modes
        # sign: the largest g-scaled entry positive, as in fit
        k = np.argmax(np.abs(modes) * np.sqrt(self.metric_weights), axis=1)
        sign = np.where(modes[np.arange(J), k] < 0, -1.0, 1.0)
        R *= sign[:, None]
        modes *= sign[:, None]
        coeffs *= sign[None, :]
        out = copy.copy(self)
        out.modes = modes
        out.training_coefficients = coeffs
        out.variances = var
        out.explained_variance_ratio = var / self.total_variance
        out.rotation = R
        out.localization = {"objective_before": float(np.sum(e0 * e0)), "objective_after": float(np.sum(e1 * e1)),
                            "iterations": it, "seconds": time.perf_counter() - t0}
        return out

    def _region_matrix(self, regions):
        """Sparse ``(n_regions, 2E)`` 0/0.5/1 matrix summing entries of ``z`` per region."""
        topo = self.topology
        E, V = topo.n_edges, topo.n_vertices
        if regions is None:
            regions = np.arange(V)
        regions = np.asarray(regions)
        if regions.shape == (V,):
            lab = regions[topo.edges]  # (E, 2)
            cols = np.tile(np.arange(2 * E), 2)
            rows = np.concatenate([np.tile(lab[:, 0], 2), np.tile(lab[:, 1], 2)])
            vals = np.full(len(rows), 0.5)
        elif regions.shape == (2 * E,):
            rows, cols, vals = regions, np.arange(2 * E), np.ones(2 * E)
        else:
            raise ShapeModelError(f"regions must have one label per vertex ({V},) or per entry of z ({2 * E},), "
                                  f"got shape {regions.shape}")
        if not np.issubdtype(regions.dtype, np.integer) or regions.min() < 0:
            raise ShapeModelError("region labels must be non-negative integers")
        n = int(rows.max()) + 1
        return sp.csr_matrix((vals, (rows, cols)), shape=(n, 2 * E))

    def region_energy(self, regions, modes=None):
        """Fraction of each mode's ``g``-energy per region, ``(J, n_regions)``, rows summing to 1.

        ``regions`` as in :meth:`localized`; ``modes`` default :attr:`modes`.
        """
        U = self.modes if modes is None else np.atleast_2d(np.asarray(modes, float))
        G = self._region_matrix(regions)
        e = (G @ (U * U * self.metric_weights).T).T
        return e / e.sum(axis=1, keepdims=True)

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

        The entries are the rows of :data:`lacore.models.model_io.FIELDS`.

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
        save_model(self, path)

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


# --------------------------------------------------------------------------- helpers
def wrap_angles(z, topology):
    """``z (..., 2E)`` with its angle half wrapped to ``[-pi, pi)``; lengths unchanged.

    Dihedral angles live on the circle: differences of angles and sums like
    ``zbar + sum alpha_j u_j`` are taken modulo ``2 pi``.  This changes nothing
    unless angles straddle the branch cut at ``+-pi`` (nearly folded skin).
    """
    z = np.array(z, float)
    E = topology.n_edges
    a = z[..., E:]
    out = np.where(np.abs(a) < np.pi, a, np.mod(a + np.pi, 2 * np.pi) - np.pi)
    z[..., E:] = out
    return z


def _as_topology(topology, vertices):
    if isinstance(topology, MeshTopology):
        return topology
    faces = np.asarray(topology)
    first = np.asarray(vertices[0])
    return MeshTopology.from_faces(faces, n_vertices=len(first))


def _check_poses(vertices, topology):
    """Training poses as a float ``(N, V, 3)`` array; ShapeModelError / MeshError naming the bad pose."""
    poses = list(vertices)
    if len(poses) < 2:
        raise ShapeModelError(f"a shape model needs at least 2 training meshes, got {len(poses)}")
    V = topology.n_vertices
    out = np.empty((len(poses), V, 3))
    for i, x in enumerate(poses):
        x = np.asarray(x, float)
        if x.shape != (V, 3):
            raise ShapeModelError(f"training mesh {i} has vertices of shape {x.shape}, expected ({V}, 3): the meshes "
                                  "are not in correspondence")
        try:
            out[i] = check_nondegenerate(x, topology)
        except MeshError as exc:
            raise MeshError(f"training mesh {i}: {exc}") from None
    return out
