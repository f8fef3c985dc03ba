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

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from ..io.atomic import save_npz_atomic
from ..io.npz import open_npz, read_array
from ..energies import QuadraticEnergy
from ..errors import InputError, LengthsAnglesError, MeshError, format_indices
from ..integrability.local import euler_integrability_jacobian
from ..geometry.lengths_angles import check_nondegenerate, check_z, lengths_and_angles
from ..progress import report
from ..shapes.projection import project
from ..reconstruction import METHODS, reconstruct
from ..reconstruction.settings import WEIGHTS
from ..linalg.sparse_cholesky import SparseCholesky
from ..geometry.topology import MeshTopology, check_vertices

__all__ = ["ShapeModel", "ShapeModelError", "TangentProjector", "wrap_angles", "FORMAT", "FORMAT_VERSION", "TANGENTS",
           "DEFAULT_TANGENT", "PROJECTION_METRICS", "DEFAULT_BENDING_WEIGHT"]

#: Value of the ``format`` entry of a saved model.
FORMAT = "lacore.models.shape_model"
#: Version of the ``.npz`` layout written by :meth:`ShapeModel.save`.
FORMAT_VERSION = 1
#: Tangent-vector variants: (4.18) and (4.17).
TANGENTS = ("ambient", "projected")
#: Tangent used when none is given (library, CLI and add-on): ``"ambient"``.  On 20 random skinned poses
#: of the coarse human, its first mode reconstructs without folds out to +-2 standard deviations, while the
#: projected variant folds already at +-1 and even at the training samples' own coefficients (the linear
#: projection at the mean distorts tangents of large deformations; ``tests/test_human_shape_model.py``).
DEFAULT_TANGENT = "ambient"
#: Orthogonality of the tangent projection: the thesis' Euclidean one (default) or ``g``.
PROJECTION_METRICS = ("euclidean", "g")
#: Bending weight ``eta`` of ``W_q`` of a model, as in the thesis' experiments.
DEFAULT_BENDING_WEIGHT = 0.005
#: Largest ratio of a synthesized length to the mean's: the squared residuals of longer ones overflow.
_MAX_LENGTH_GROWTH = 1e100
#: Eigenvalues below this fraction of the largest are treated as zero variance.
_RANK_TOL = 1e-12


class ShapeModelError(InputError):
    """Bad input for a shape model: too few samples, samples not in correspondence, a corrupt model file."""


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
    shrinks ``|A v|`` by about ``delta / sigma_min^2`` (measured on the 13.4k
    vertex body: ``|A v| / |A u|`` 1.5e-9 after the first solve, 7e-15 after
    one refinement), until ``|A v| <= rtol |A u|`` or no further progress.  The factorization is
    one :class:`~lacore.linalg.sparse_cholesky.SparseCholesky` whose symbolic analysis
    is cached on the topology.

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
    bending_weight : float
        ``eta`` of ``W_q`` (default 0.005, the thesis' value for this application).
    weights : str
        Weight scheme of ``W_q`` (``"frohlich_botsch"`` = (3.20)).
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
    last_clamped_lengths : (K,) ndarray or None
        Lengths raised to their floor per pose in the last :meth:`synthesize`.
    """

    def __init__(self, *, topology, reference_vertices, mean_z, mean_vertices, linear_mean_z, modes, variances,
                 explained_variance_ratio, total_variance, training_coefficients, tangent, projection_metric,
                 bending_weight, weights, method, timings=None, mean_result=None, all_eigenvalues=None):
        self.topology = topology
        self.reference_vertices = reference_vertices
        self.energy = QuadraticEnergy(topology, reference_vertices=reference_vertices, weights=weights,
                                      bending_weight=bending_weight)
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
        self.bending_weight = float(bending_weight)
        self.weights = weights
        self.method = method
        self.timings = dict(timings or {})
        self.mean_result = mean_result
        self.all_eigenvalues = all_eigenvalues
        self._projector = None
        self._solver = None
        self.last_clamped_lengths = None

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
              projection_metric=PROJECTION_METRICS[0], bending_weight=DEFAULT_BENDING_WEIGHT,
              weights="frohlich_botsch", method="gn", mean_options=None, solver=None,
              progress=None):
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
        bending_weight : float
            ``eta`` of ``W_q`` (default 0.005, thesis 4.3.2).
        weights : {"frohlich_botsch", "heeren", "uniform"}
            Weights of ``W_q``: (3.20) (default), (3.21) or 1.
        method : str
            Reconstruction method of the mean and of :meth:`synthesize`
            (``"gn"``: energy-based projection, Def. 4.3).
        mean_options : dict, optional
            Extra keyword arguments of :func:`lacore.reconstruct` for the mean
            (e.g. tolerances).  Default for Gauss-Newton:
            ``geodesic_acceleration=False`` (measured on averaged skinned
            bodies, the accelerated iteration stalls far from the minimum).
        solver : {"cholmod", "scipy"}, optional
            Sparse Cholesky backend (reconstruction and tangent projection).
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
        # Gauss-Newton without geodesic acceleration: on averaged skinned bodies the accelerated steps stall
        # (energy 46.6 vs 1.46 on the 13.4k body, 30 poses: bench_shape_model.py)
        opts = {"geodesic_acceleration": False} if method in ("gn", "hybrid") else {}
        opts.update(mean_options or {})
        mean_z, mean_result = project(z_lin, topology, X_ref, method=method, bending_weight=bending_weight,
                                      weights=weights, solver=solver, **opts)
        mean_vertices = mean_result.vertices
        t_mean = time.perf_counter() - t
        report(progress, 1, n_stages, "tangent vectors")

        energy = QuadraticEnergy(topology, reference_vertices=X_ref, weights=weights, bending_weight=bending_weight)
        w = energy.residual_weights
        Vt = wrap_angles(Z - mean_z, topology)  # (4.18)
        t_dec = t_solve = 0.0
        projector = None
        if tangent == "projected":  # (4.17)
            t = time.perf_counter()
            projector = TangentProjector(mean_z, topology, metric_weights=w, metric=projection_metric, solver=solver)
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
        if not np.all(np.isfinite(K)):
            L = Z[:, :topology.n_edges]
            raise ShapeModelError(f"the training meshes' edge lengths ({np.min(L):.3g} to {np.max(L):.3g}) are too "
                                  "large or too small for the model's weights and variances in double precision: "
                                  "scale the meshes toward unit size")
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
                    bending_weight=bending_weight, weights=weights, method=method, timings=timings,
                    mean_result=mean_result, all_eigenvalues=lam_all)
        model._projector = projector
        model._solver = solver
        return model

    # ------------------------------------------------------------------ using the model
    def tangent_projector(self):
        """The :class:`TangentProjector` at the mean (built on first use, e.g. after :meth:`load`)."""
        if self._projector is None:
            self._projector = TangentProjector(self.mean_z, self.topology, metric_weights=self.metric_weights,
                                               metric=self.projection_metric, solver=self._solver)
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

    def synthesize(self, coefficients, method=None, initial_vertices=None, progress=None, return_results=False,
                   min_length_ratio=0.01, **reconstruct_options):
        """Poses of the model, ``P_Z[zbar + sum_j alpha_j u_j]`` (4.19), as vertices.

        Parameters
        ----------
        coefficients : (J,) or (K, J) array_like
        method : str, optional
            Reconstruction method (default :attr:`method`), see :func:`lacore.reconstruct`.
        initial_vertices : (V, 3) array_like, optional
            Gauss-Newton start (default the mean's vertices, for every pose).
        progress : callable, optional
            ``progress(done, total, message)`` per pose.
        return_results : bool
            Also return the :class:`~lacore.reconstruction.ReconstructionResult` of every pose.
        min_length_ratio : float
            Lengths of ``zbar + sum_j alpha_j u_j`` below this fraction of the
            mean's length of the same edge are raised to it before the
            projection (a length varying strongly over the training set, e.g.
            in a skin crease, becomes negative a few standard deviations out);
            :attr:`last_clamped_lengths` counts them per pose.
        **reconstruct_options
            Passed on to :func:`lacore.reconstruct` (tolerances, ``max_iterations`` ...).
            Default for Gauss-Newton: ``geodesic_acceleration=False`` (measured: at +-2
            standard deviations of the body's modes the accelerated iteration stops at 1.5-5x
            higher energies).

        Returns
        -------
        vertices : (V, 3) or (K, V, 3) ndarray
            In the frame of the reference mesh.
        results : ReconstructionResult or list of them (only with ``return_results``)
        """
        a = self._check_coefficients(coefficients)
        single = a.ndim == 1
        A = np.atleast_2d(a)
        method = self.method if method is None else method
        X0 = self.mean_vertices if initial_vertices is None else initial_vertices
        out = np.empty((len(A), self.topology.n_vertices, 3))
        results = []
        zs = self.z_of(A)
        # far along a mode (or with extreme coefficients) a length can reach zero or below: clamp it
        E = self.topology.n_edges
        floor = float(min_length_ratio) * self.mean_z[:E]
        clamped = zs[:, :E] < floor
        zs[:, :E] = np.maximum(zs[:, :E], floor)
        self.last_clamped_lengths = np.count_nonzero(clamped, axis=1)
        opts = {"geodesic_acceleration": False} if method in ("gn", "hybrid") else {}  # see fit_z
        opts.update(reconstruct_options)
        growth = np.max(zs[:, :E] / self.mean_z[:E], axis=1)  # NaN for non-finite targets
        overflow = np.flatnonzero(~(growth < _MAX_LENGTH_GROWTH))
        if overflow.size:
            k = int(overflow[0])
            raise ShapeModelError(f"pose {k + 1} of {len(A)} is too far from the training poses: its lengths reach "
                                  f"{growth[k]:.3g} times the mean's, beyond what double precision can reconstruct "
                                  "(use coefficients of a few standard deviations)")
        L = zs[:, :E][:, self.topology.face_edges]  # (K, F, 3) target lengths per face
        broken = np.count_nonzero(2.0 * L.max(axis=2) >= L.sum(axis=2), axis=1)
        far = np.flatnonzero(2 * broken > self.topology.n_faces)
        if far.size:  # as reconstruct() refuses them, but named as what they are here
            k = int(far[0])
            raise ShapeModelError(f"pose {k + 1} of {len(A)} is too far from the training poses: its lengths violate "
                                  f"the triangle inequality at {broken[k]} of {self.topology.n_faces} faces, no mesh "
                                  "has them (use coefficients of a few standard deviations)")
        for k, zk in enumerate(zs):
            report(progress, k, len(A), f"pose {k + 1} of {len(A)}")
            res = reconstruct(zk, self.topology, self.reference_vertices, method=method,
                              bending_weight=self.bending_weight, weights=self.weights, initial_vertices=X0,
                              solver=self._solver, **opts)
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

        Returns
        -------
        vertices : (K, V, 3) ndarray
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
        """Write the model to one ``.npz`` file, atomically (:func:`lacore.io.atomic.save_npz_atomic`).

        ``.npz`` is appended to a name without it (as :func:`numpy.savez`
        does); the path written is returned.  Keys: ``format``,
        ``format_version``, ``faces``, ``edges``, ``reference_vertices``,
        ``mean_z``, ``mean_vertices``, ``linear_mean_z``, ``modes``,
        ``variances``, ``explained_variance_ratio``, ``total_variance``,
        ``training_coefficients``, ``all_eigenvalues``, ``metric_weights``,
        ``bending_weight``, ``weights``, ``tangent``, ``projection_metric``,
        ``method``.
        """
        data = {
            "format": np.array(FORMAT), "format_version": np.array(FORMAT_VERSION),
            "faces": self.faces, "edges": self.edges, "reference_vertices": self.reference_vertices,
            "mean_z": self.mean_z, "mean_vertices": self.mean_vertices, "linear_mean_z": self.linear_mean_z,
            "modes": self.modes, "variances": self.variances,
            "explained_variance_ratio": self.explained_variance_ratio,
            "total_variance": np.array(self.total_variance), "training_coefficients": self.training_coefficients,
            "all_eigenvalues": (self.all_eigenvalues if self.all_eigenvalues is not None else np.zeros(0)),
            "metric_weights": self.metric_weights, "bending_weight": np.array(self.bending_weight),
            "weights": np.array(self.weights), "tangent": np.array(self.tangent),
            "projection_metric": np.array(self.projection_metric), "method": np.array(self.method),
        }
        return save_npz_atomic(path, **data)

    @classmethod
    def load(cls, path, faces=None):
        """Read a model written by :meth:`save`.

        Every field is checked (types, shapes, finite values, positive
        variances, known settings); a file that fails raises one
        :class:`ShapeModelError` naming the file and the field.

        Parameters
        ----------
        path : str or path-like
        faces : (F, 3) array_like, optional
            If given, the model must have exactly these faces.

        Raises
        ------
        ShapeModelError
            Not a shape-model file, another format version, invalid or
            inconsistent fields, or other faces than ``faces``.
        FileNotFoundError
        """
        with open_npz(path, "shape model", ShapeModelError) as npz:
            keys = set(npz.files)
            fmt = _read_field(npz, "format", path) if "format" in keys else None
            if fmt is None or fmt.shape != () or fmt.dtype.kind != "U" or str(fmt) != FORMAT:
                raise ShapeModelError(f"{path} is not a lacore shape model (no format entry {FORMAT!r})")
            version = _read_field(npz, "format_version", path) if "format_version" in keys else np.array(-1)
            if version.shape != () or version.dtype.kind not in "iu" or int(version) != FORMAT_VERSION:
                raise ShapeModelError(f"{path} has shape-model format version {version.tolist()!r}; this lacore reads "
                                      f"version {FORMAT_VERSION}")
            need = ["faces", "edges", "reference_vertices", "mean_z", "mean_vertices", "linear_mean_z", "modes",
                    "variances", "explained_variance_ratio", "total_variance", "training_coefficients",
                    "metric_weights", "bending_weight", "weights", "tangent", "projection_metric", "method"]
            missing = [k for k in need if k not in keys]
            if missing:
                raise ShapeModelError(f"{path} is a corrupt shape model: missing {', '.join(missing)}")
            d = {k: _read_field(npz, k, path) for k in need + (["all_eigenvalues"] if "all_eigenvalues" in keys
                                                                 else [])}
        d = _check_model_fields(path, d)
        try:
            topology = MeshTopology.from_faces(d["faces"], edges=d["edges"], n_vertices=len(d["reference_vertices"]))
        except MeshError as exc:
            raise ShapeModelError(f"{path} is a corrupt shape model: {exc}") from None
        E2 = 2 * topology.n_edges
        V = topology.n_vertices
        J = d["modes"].shape[0]
        shapes = {"reference_vertices": (V, 3), "mean_vertices": (V, 3), "mean_z": (E2,), "linear_mean_z": (E2,),
                  "modes": (J, E2), "variances": (J,), "explained_variance_ratio": (J,), "metric_weights": (E2,)}
        for k, shape in shapes.items():
            if d[k].shape != shape:
                raise ShapeModelError(f"{path} is a corrupt shape model: {k} has shape {d[k].shape}, expected {shape}")
        if d["training_coefficients"].shape[1] != J:
            raise ShapeModelError(f"{path} is a corrupt shape model: training_coefficients has shape "
                                  f"{d['training_coefficients'].shape}, expected (N, {J})")
        if np.any(d["mean_z"][:E2 // 2] <= 0):
            raise ShapeModelError(f"{path} is a corrupt shape model: mean_z has lengths <= 0")
        try:
            model = cls(topology=topology, reference_vertices=d["reference_vertices"], mean_z=d["mean_z"],
                        mean_vertices=d["mean_vertices"], linear_mean_z=d["linear_mean_z"], modes=d["modes"],
                        variances=d["variances"], explained_variance_ratio=d["explained_variance_ratio"],
                        total_variance=d["total_variance"], training_coefficients=d["training_coefficients"],
                        tangent=d["tangent"], projection_metric=d["projection_metric"],
                        bending_weight=d["bending_weight"], weights=d["weights"], method=d["method"],
                        all_eigenvalues=d.get("all_eigenvalues"))
        except InputError as exc:  # e.g. a reference mesh with degenerate triangles
            raise ShapeModelError(f"{path} is a corrupt shape model: {exc}") from None
        if not np.allclose(model.metric_weights, d["metric_weights"], rtol=1e-12, atol=0):
            raise ShapeModelError(f"{path} is a corrupt shape model: its metric weights do not match its reference "
                                  "mesh")
        if faces is not None:
            model.check_mesh(faces=faces)
        return model


def _read_field(npz, key, path):
    """One array of an open model file; ShapeModelError if it cannot be read (object arrays, a damaged archive)."""
    return read_array(npz, key, path, "shape model", ShapeModelError)


def _check_model_fields(path, d):
    """Types, ranks and values of the fields of a model file; returns them converted (floats, ints, str).

    One :class:`ShapeModelError` naming the file and the first bad field: integer
    faces and edges, finite real arrays, positive variances, explained-variance
    ratios in [0, 1], a positive total variance, a finite non-negative bending
    weight and known settings.
    """
    def bad(key, what):
        return ShapeModelError(f"{path} is a corrupt shape model: {key} {what}")

    out = {}
    for key in ("faces", "edges"):
        a = d[key]
        if a.dtype.kind not in "iu" or a.ndim != 2:
            raise bad(key, f"must be a 2-d integer array, got {a.dtype} {a.shape}")
        out[key] = a.astype(np.int64)
    ranks = {"reference_vertices": 2, "mean_vertices": 2, "mean_z": 1, "linear_mean_z": 1, "modes": 2,
             "variances": 1, "explained_variance_ratio": 1, "training_coefficients": 2, "metric_weights": 1,
             "total_variance": 0, "bending_weight": 0}
    for key, ndim in ranks.items():
        a = d[key]
        if a.dtype.kind not in "fiu" or a.ndim != ndim:
            raise bad(key, f"must be a {ndim}-d array of real numbers, got {a.dtype} {a.shape}")
        a = a.astype(float)
        if not np.all(np.isfinite(a)):
            raise bad(key, "has NaN or infinite entries")
        out[key] = a
    if out["modes"].shape[0] < 1:
        raise bad("modes", "is empty: the model has no modes")
    if np.any(out["variances"] <= 0):
        raise bad("variances", f"must be positive, got {np.min(out['variances']):g}")
    ratio = out["explained_variance_ratio"]
    if np.any(ratio < 0) or np.sum(ratio) > 1.0 + 1e-9:
        raise bad("explained_variance_ratio", "must be in [0, 1] with a sum of at most 1")
    if out["total_variance"] <= 0:
        raise bad("total_variance", f"must be positive, got {float(out['total_variance']):g}")
    if out["bending_weight"] < 0:
        raise bad("bending_weight", f"must be >= 0, got {float(out['bending_weight']):g}")
    out["total_variance"] = float(out["total_variance"])
    out["bending_weight"] = float(out["bending_weight"])
    for key, known in (("tangent", TANGENTS), ("projection_metric", PROJECTION_METRICS), ("method", METHODS),
                       ("weights", WEIGHTS)):
        a = d[key]
        if a.dtype.kind != "U" or a.shape != () or str(a) not in known:
            raise bad(key, f"must be one of {', '.join(known)}, got {a.tolist()!r}")
        out[key] = str(a)
    if "all_eigenvalues" in d:
        a = d["all_eigenvalues"]
        if a.dtype.kind not in "fiu" or a.ndim != 1 or not np.all(np.isfinite(a)):
            raise bad("all_eigenvalues", "must be a 1-d array of finite numbers")
        out["all_eigenvalues"] = a.astype(float)
    return out


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
    if isinstance(vertices, np.ndarray) and vertices.ndim == 3:
        poses = list(vertices)
    else:
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
