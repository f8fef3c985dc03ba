"""Fitting a shape model: extrinsic mean, tangent vectors and PCA in the metric ``g`` (thesis 4.3, (4.14)-(4.18)).

:func:`fit` and :func:`fit_z` are :meth:`ShapeModel.fit <lacore.models.shape_model.ShapeModel.fit>`
and :meth:`~lacore.models.shape_model.ShapeModel.fit_z`; the steps are described
in :mod:`lacore.models.shape_model`.
"""

import time

import numpy as np
import scipy.linalg

from ..energies import QuadraticEnergy
from ..errors import LengthsAnglesError, MeshError
from ..geometry.lengths_angles import check_nondegenerate, check_z, lengths_and_angles
from ..geometry.topology import MeshTopology, check_vertices
from ..progress import report
from ..reconstruction import METHODS
from ..shapes.projection import project
from .settings import DEFAULT_TANGENT, MODEL_OPTIONS, MODEL_SETTINGS, PROJECTION_METRICS, TANGENTS, ShapeModelError
from .tangent import TangentProjector, wrap_angles

__all__ = ["fit", "fit_z"]

#: Eigenvalues below this fraction of the largest are treated as zero variance.
_RANK_TOL = 1e-12


def fit(cls, vertices, topology, *, reference_vertices=None, n_modes=None, tangent=DEFAULT_TANGENT,
        projection_metric=PROJECTION_METRICS[0], method="gn", settings=None, options=None, progress=None):
    """Fit a model to ``N`` meshes in dense correspondence.

    Parameters
    ----------
    vertices : (N, V, 3) array_like or sequence of (V, 3) arrays
        Training poses with the connectivity of ``topology`` (any rigid
        placement).
    topology : MeshTopology or (F, 3) array_like of faces
    reference_vertices : (V, 3) array_like, optional
        Reference mesh (weights of ``W_q``, output frame); default the first pose.
    n_modes, tangent, projection_metric, method, settings, options, progress
        As for :meth:`fit_z`.

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
    model = cls.fit_z(Z, topology, reference, n_modes=n_modes, tangent=tangent, projection_metric=projection_metric,
                      method=method, settings=settings, options=options, progress=progress)
    model.timings["encode"] = t_encode
    model.timings["total"] += t_encode
    return model


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
                settings=settings, method=method, timings=timings, mean_result=mean_result,
                all_eigenvalues=lam_all)
    model._projector = projector
    return model



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
