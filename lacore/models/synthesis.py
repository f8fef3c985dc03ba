"""Poses from a shape model: ``P_Z[zbar + sum_j alpha_j u_j]`` (thesis (4.19)) and sweeps along a mode (Figure 4.4).

:func:`synthesize`, :func:`synthesis_targets` and :func:`mode_sweep` are the
methods of the same names of :class:`~lacore.models.shape_model.ShapeModel`.
Synthesis reads the model and changes nothing in it.
"""

import warnings
from dataclasses import replace

import numpy as np

from ..errors import ReconstructionWarning
from ..progress import report
from ..reconstruction import reconstruct
from .settings import MIN_LENGTH_RATIO, MODEL_OPTIONS, ShapeModelError

__all__ = ["synthesize", "synthesis_targets", "mode_sweep"]

#: Largest ratio of a synthesized length to the mean's: the squared residuals of longer ones overflow.
_MAX_LENGTH_GROWTH = 1e100


def _check_reachable(model, zs):
    """ShapeModelError naming the first target (``zs (K, 2E)``) that no reconstruction can reach: lengths beyond
    double precision's reach, or the triangle inequality broken at most faces (as :func:`reconstruct` refuses)."""
    E = model.topology.n_edges
    growth = np.max(zs[:, :E] / model.mean_z[:E], axis=1)  # NaN for non-finite targets
    overflow = np.flatnonzero(~(growth < _MAX_LENGTH_GROWTH))
    if overflow.size:
        k = int(overflow[0])
        raise ShapeModelError(f"the pose of coefficient row {k} (of {len(zs)}) is too far from the training "
                              f"poses: its lengths reach "
                              f"{growth[k]:.3g} times the mean's, beyond what double precision can reconstruct "
                              "(use coefficients of a few standard deviations)")
    L = zs[:, :E][:, model.topology.face_edges]  # (K, F, 3) target lengths per face
    broken = np.count_nonzero(2.0 * L.max(axis=2) >= L.sum(axis=2), axis=1)
    far = np.flatnonzero(2 * broken > model.topology.n_faces)
    if far.size:
        k = int(far[0])
        raise ShapeModelError(f"the pose of coefficient row {k} (of {len(zs)}) is too far from the training "
                              f"poses: its lengths violate "
                              f"the triangle inequality at {broken[k]} of {model.topology.n_faces} faces, no mesh "
                              "has them (use coefficients of a few standard deviations)")


def synthesis_targets(model, coefficients, min_length_ratio=MIN_LENGTH_RATIO):
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
    z = model.z_of(coefficients)
    E = model.topology.n_edges
    if not 0.0 <= float(min_length_ratio) < 1.0:
        raise ShapeModelError(f"min_length_ratio must be a number in [0, 1), got {min_length_ratio!r}")
    floor = float(min_length_ratio) * model.mean_z[:E]
    clamped = z[..., :E] < floor
    z[..., :E] = np.maximum(z[..., :E], floor)
    return z, clamped


def _warn_failed(results, stacklevel):
    """A :class:`~lacore.errors.ReconstructionWarning` naming the poses that failed their checks by their rows of
    the coefficients (from 0, as the CLI numbers its files)."""
    failed = [k for k, res in enumerate(results) if not res.success]
    if failed:
        shown = ", ".join(str(k) for k in failed[:8]) + (" ..." if len(failed) > 8 else "")
        warnings.warn(f"{len(failed)} of {len(results)} poses failed their checks (coefficient rows {shown}): "
                      f"{results[failed[0]].message}; use coefficients of a few standard deviations, or "
                      "return_results=True to inspect them", ReconstructionWarning, stacklevel=stacklevel)


def synthesize(model, coefficients, *, method=None, options=None, hybrid=None, initial_vertices=None,
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
        Also return the :class:`~lacore.reconstruction.ReconstructionResult` of every pose.  Without them,
        poses that fail their checks (coefficients far beyond the training range fold the mesh) are returned
        with a :class:`~lacore.errors.ReconstructionWarning` naming them and the first failure.

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
    a = model.check_coefficients(coefficients)
    single = a.ndim == 1
    A = np.atleast_2d(a)
    method = model.method if method is None else method
    options = MODEL_OPTIONS if options is None else options
    X0 = model.mean_vertices if initial_vertices is None else initial_vertices
    zs, clamped = synthesis_targets(model, A, min_length_ratio)
    _check_reachable(model, zs)
    out = np.empty((len(A), model.topology.n_vertices, 3))
    results = []
    for k, zk in enumerate(zs):
        report(progress, k, len(A), f"pose {k + 1} of {len(A)}")
        res = reconstruct(zk, model.topology, model.reference_vertices, method=method, settings=model.settings,
                          options=options, hybrid=hybrid, initial_vertices=X0)
        n = int(np.count_nonzero(clamped[k]))
        if n:
            res = replace(res, notes=res.notes + [f"{n} target lengths below {min_length_ratio:g} of the mean's "
                                                  "were raised to that floor"])
        out[k] = res.vertices
        results.append(res)
    report(progress, len(A), len(A), "done")
    if not return_results:
        _warn_failed(results, stacklevel=3)
    if single:
        out, results = out[0], results[0]
    return (out, results) if return_results else out


def mode_sweep(model, mode, t_range=(-2.0, 2.0), n_frames=5, in_std=True, progress=None, **synthesize_options):
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
    if int(mode) != mode or not 0 <= mode < model.n_modes:
        raise ShapeModelError(f"mode must be an integer from 0 to {model.n_modes - 1}, got {mode}")
    if int(n_frames) != n_frames or n_frames < 1:
        raise ShapeModelError(f"n_frames must be a positive integer, got {n_frames}")
    t = np.linspace(float(t_range[0]), float(t_range[1]), int(n_frames))
    A = np.zeros((len(t), model.n_modes))
    A[:, int(mode)] = t * (model.standard_deviations[int(mode)] if in_std else 1.0)
    return_results = synthesize_options.pop("return_results", False)
    X, results = model.synthesize(A, progress=progress, return_results=True, **synthesize_options)
    if not return_results:
        _warn_failed(results, stacklevel=3)
    return ((X, results) if return_results else X), t
