"""The discrete path energy in lengths and angles and its quadratic model (thesis 2.2, eq. 2.7, 4.9).

A discrete ``K``-path is a sequence ``z_0, ..., z_K`` of lengths-and-angles
vectors (shape ``(K+1, 2E)``, see :mod:`lacore.geometry.lengths_angles`).  Its discrete
path energy (2.7) for a deformation energy ``W`` is::

    E^K[z_0..z_K] = K * sum_{i=0}^{K-1} W[z_i, z_{i+1}]

:func:`path_energy` and :func:`path_energy_profile` evaluate it for any energy
with ``value(z_a, z_b)``; :func:`linear_path` is its unconstrained minimizer for
``W_q`` (4.9).  The geodesic solvers (:mod:`lacore.shapes.geodesic_solvers`)
use a quadratic energy in closed form: ``W = sum_j w_j (z_a - z_b)_j^2`` with
the ``residual_weights`` ``w`` of :class:`lacore.energies.QuadraticEnergy`
(:func:`default_energy`, :func:`quadratic_energy_weights`), whose path energy
:class:`QuadraticPathModel` gives with its gradient and its block-tridiagonal
Hessian in the interior points.
"""

import numpy as np
import scipy.sparse as sp

from ..energies import QuadraticEnergy
from ..errors import InputError, LengthsAnglesError
from ..geometry.lengths_angles import wrap_angle
from ..reconstruction import ReconstructionSettings

__all__ = ["default_energy", "path_energy", "path_energy_profile", "linear_path", "QuadraticPathModel",
           "quadratic_energy_weights"]


def default_energy(topology, reference, settings=None):
    """The quadratic energy ``W_q`` (3.19) with weights from ``reference``.

    Parameters
    ----------
    topology : MeshTopology
    reference : (V, 3) vertices or (2E,) lengths and angles
        Reference configuration of the weights (3.20)/(3.21).
    settings : ReconstructionSettings, optional
        Its ``weights`` and ``bending_weight`` (``eta`` in (3.19)); default the defaults.

    Returns
    -------
    lacore.energies.QuadraticEnergy

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.shapes.path_energy import default_energy
    >>> X = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2]])
    >>> topo = MeshTopology.from_faces([[0, 1, 2], [2, 1, 3]])
    >>> W = default_energy(topo, X)
    >>> W.bending_weight, W.residual_weights.shape
    (0.001, (10,))
    """
    settings = settings if settings is not None else ReconstructionSettings()
    reference = np.asarray(reference, float)
    kw = {"weights": settings.weights, "bending_weight": settings.bending_weight}
    if reference.ndim == 2:
        return QuadraticEnergy(topology, reference_vertices=reference, **kw)
    return QuadraticEnergy(topology, reference_z=reference, **kw)


def quadratic_energy_weights(energy, dim):
    """The residual weights ``w (dim,)`` of a quadratic energy ``W = sum_j w_j (z_a - z_b)_j^2``, checked.

    Raises
    ------
    TypeError
        ``energy`` has no ``residual_weights`` (not a quadratic energy).
    LengthsAnglesError, InputError
        Weights of the wrong shape, negative or not finite.
    """
    w = getattr(energy, "residual_weights", None)
    if w is None:
        raise TypeError(f"{type(energy).__name__} is not supported by the geodesic solvers: they need a quadratic "
                        "energy with a 'residual_weights' attribute (W = sum_j w_j (z_a - z_b)_j^2), "
                        "e.g. lacore.energies.QuadraticEnergy")
    w = np.asarray(w, float)
    if w.shape != (dim,):
        raise LengthsAnglesError(f"energy.residual_weights has shape {w.shape}, expected ({dim},)")
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise InputError("energy.residual_weights must be finite and non-negative")
    return w


def path_energy_profile(zs, energy):
    """Energies of the steps of a discrete path, ``W[z_i, z_{i+1}]``.

    Parameters
    ----------
    zs : (K+1, 2E) array_like
        Discrete path (K >= 1).
    energy : object with ``value(z_a, z_b)``
        Deformation energy ``W`` (e.g. :class:`lacore.energies.QuadraticEnergy`).

    Returns
    -------
    (K,) ndarray
        For a discrete geodesic the entries are (nearly) equal: its points are
        equidistributed (section 2.2, figures 4.1/4.2).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import lengths_and_angles, path_energy_profile
    >>> from lacore.shapes.path_energy import default_energy, linear_path
    >>> zs = linear_path(lengths_and_angles(bar_pose(X, 0.5, 0.0), topo), lengths_and_angles(X, topo), 4)
    >>> print(np.round(path_energy_profile(zs, default_energy(topo, X)), 6))   # equal steps of W_q
    [0.002165 0.002165 0.002165 0.002165]
    """
    zs = _check_path(zs)
    return np.array([float(energy.value(zs[i], zs[i + 1])) for i in range(len(zs) - 1)])


def path_energy(zs, energy):
    """Discrete path energy ``E^K = K sum_i W[z_i, z_{i+1}]`` (2.7) of a path ``(K+1, 2E)``."""
    profile = path_energy_profile(zs, energy)
    return len(profile) * float(profile.sum())


def _check_path(zs):
    zs = np.asarray(zs, float)
    if zs.ndim != 2 or zs.shape[0] < 2:
        raise LengthsAnglesError(f"a discrete path must have shape (K+1, 2E) with K >= 1, got {zs.shape}")
    if not np.all(np.isfinite(zs)):
        raise LengthsAnglesError("the discrete path has NaN or infinite entries")
    return zs


def linear_path(z_start, z_end, n_steps):
    """Equidistant linear path ``z_i = (1 - i/K) z_0 + (i/K) z_K``, shape ``(K+1, 2E)``.

    For ``W_q`` this is the unconstrained discrete geodesic (4.9).  Angles turn the short way round the
    circle (the end's angles moved by multiples of ``2 pi`` to within ``pi`` of the start's).
    """
    z0, z1 = np.asarray(z_start, float), np.array(z_end, float)
    E = z0.shape[-1] // 2
    z1[E:] = z0[E:] + wrap_angle(z1[E:] - z0[E:])
    t = np.linspace(0.0, 1.0, int(n_steps) + 1)[:, None]
    return (1.0 - t) * z0[None] + t * z1[None]


def _time_laplacian_inverse(m):
    """Inverse of ``T = tridiag(-1, 2, -1)`` of size ``m``: ``min(i, j) (m + 1 - max(i, j)) / (m + 1)`` (1-based)."""
    i = np.arange(1, m + 1)
    return np.minimum.outer(i, i) * (m + 1 - np.maximum.outer(i, i)) / (m + 1.0)


class QuadraticPathModel:
    """Path energy ``K sum_i sum_j w_j (z_{i+1} - z_i)_j^2`` as a function of the interior points.

    Its Hessian in the interior points ``(z_1..z_{K-1})`` is ``kron(T, diag(2 K w))``
    with ``T = tridiag(-1, 2, -1)`` of size ``K - 1``.
    """

    def __init__(self, weights, n_steps):
        self.w = weights
        self.K = n_steps
        self.m = n_steps - 1
        m = max(self.m, 1)  # K = 1 has no unknowns; keep valid (unused) operators
        self.T = sp.diags([-np.ones(m - 1), 2.0 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1], format="csr")
        self.T_inv = _time_laplacian_inverse(m)

    def steps(self, zs):
        """``z_{i+1} - z_i``, ``(K, 2E)``, the angle differences on the circle."""
        d = np.diff(zs, axis=0)
        E = d.shape[1] // 2
        d[:, E:] = wrap_angle(d[:, E:])
        return d

    def value(self, zs):
        d = self.steps(zs)
        return self.K * float(np.sum(self.w * d * d))

    def gradient(self, zs):
        """``(K-1, 2E)``: ``2 K w (2 z_i - z_{i-1} - z_{i+1})`` (differences on the circle)."""
        d = self.steps(zs)
        return 2.0 * self.K * self.w * (d[:-1] - d[1:])

    def hessian_diagonal(self, columns=None):
        """``2 K w`` restricted to ``columns``: the diagonal factor ``D`` of ``H = kron(T, D)``."""
        return 2.0 * self.K * (self.w if columns is None else self.w[columns])

    def apply_hessian(self, P, d, damping=0.0):
        """``H p`` for ``p`` of shape ``(K-1, n)`` and the diagonal factor ``d`` (n,).

        With ``damping = mu > 0`` the damped ``kron(T + mu I, D)``.
        """
        return (self.T @ P + damping * P) * d

    def solve_hessian(self, R, d, damping=0.0):
        """``H^-1 r`` (or the damped ``kron(T + mu I, D)^-1 r``) for ``r`` of shape ``(K-1, n)``."""
        return (self.time_inverse(damping) @ R) / d

    def time_inverse(self, damping=0.0):
        """``(T + mu I)^-1``, dense ``(K-1, K-1)``."""
        if damping == 0.0:
            return self.T_inv
        return np.linalg.inv(self.T.toarray() + damping * np.eye(self.T.shape[0]))
