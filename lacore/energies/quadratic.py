"""The quadratic energy W_q on lengths and angles (thesis Definition 3.11, weights (3.20), (3.21))."""

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, LengthsAnglesError, format_indices
from ..geometry.lengths_angles import lengths_and_angles, wrap_angle
from ._common import (DEFAULT_BENDING_WEIGHT, DEFAULT_WEIGHTS, WEIGHT_SCHEMES, DeformationEnergy, _as_z, _Blocks,
                      _interior_quads, _parse_argument, edge_areas)

__all__ = ["QuadraticEnergy", "quadratic_weights"]


def quadratic_weights(reference_lengths, topology, scheme=DEFAULT_WEIGHTS):
    """Per-edge weights ``(w_s, w_b)`` of the quadratic energy (3.19).

    Parameters
    ----------
    reference_lengths : (E,) array_like
        Edge lengths ``lbar`` of the reference configuration.
    topology : MeshTopology
    scheme : {"frohlich_botsch", "heeren", "uniform"}
        Default :data:`~lacore.energies.DEFAULT_WEIGHTS`.
        ``"frohlich_botsch"`` (3.20): ``w_s = 1 / lbar^2``, ``w_b = lbar^2 / dbar``;
        ``"heeren"`` (3.21): ``w_s = dbar / lbar^2``, ``w_b = lbar^2 / dbar``;
        ``"uniform"``: ``w_s = w_b = 1``.  ``dbar`` from :func:`edge_areas`.

    Returns
    -------
    w_s, w_b : (E,) ndarray
        ``w_b`` is 0 on boundary edges (their angle is 0 by convention).
    """
    if scheme not in WEIGHT_SCHEMES:
        raise InputError(f"unknown weight scheme {scheme!r}; use one of {WEIGHT_SCHEMES}")
    E = topology.n_edges
    if scheme == "uniform":
        w_s, w_b = np.ones(E), np.ones(E)
    else:
        lbar = np.asarray(reference_lengths, float)
        if lbar.shape != (E,):
            raise LengthsAnglesError(f"reference lengths must have shape ({E},), got {lbar.shape}")
        dbar = edge_areas(lbar, topology)
        bad = np.flatnonzero(~(lbar > 0) | ~(dbar > 0))
        if bad.size:
            raise LengthsAnglesError("the reference configuration has zero lengths or degenerate triangles at "
                                     f"edges {format_indices(bad)}")
        w_b = lbar**2 / dbar
        w_s = 1.0 / lbar**2 if scheme == "frohlich_botsch" else dbar / lbar**2
    w_b = np.where(topology.is_boundary_edge, 0.0, w_b)
    return w_s, w_b


# --------------------------------------------------------------------------- quadratic energy
class QuadraticEnergy(DeformationEnergy):
    """Quadratic deformation energy on lengths and angles, Definition 3.11.

    ``W_q[z_a, z_b] = sum_e w_s,e (l_a - l_b)_e^2 + eta sum_e w_b,e (theta_a - theta_b)_e^2``  (3.19)

    with ``theta_a - theta_b`` on the circle (wrapped to ``(-pi, pi]``: two edges folded to ``+-3.1``
    differ by 0.08), which is the thesis' difference wherever it is below ``pi``.

    Parameters
    ----------
    topology : MeshTopology
    reference_vertices : (V, 3) array_like, optional
        Reference configuration ``Xbar`` for the weights (3.20)/(3.21).
    reference_z : (2E,) array_like, optional
        Alternatively its lengths and angles (only the lengths are used).
        Give at most one of the two; none is needed for ``weights="uniform"`` or
        when both weight arrays are given.
    weights : {"frohlich_botsch", "heeren", "uniform"}
        Weight scheme, see :func:`quadratic_weights` (default :data:`~lacore.energies.DEFAULT_WEIGHTS`).
    membrane_weights, bending_weights : (E,) array_like, optional
        Custom ``w_s`` / ``w_b`` overriding the scheme (non-negative, finite).
        Bending weights of boundary edges are set to 0 (angle 0 by convention).
    bending_weight : float
        ``eta >= 0`` (default :data:`~lacore.energies.DEFAULT_BENDING_WEIGHT`).

    Attributes
    ----------
    membrane_weights, bending_weights : (E,) ndarray
        ``w_s`` and ``w_b`` (without ``eta``).
    residual_weights : (2E,) ndarray
        ``w = (w_s, eta w_b)`` so that ``W_q = sum_i w_i (z_a - z_b)_i^2``;
        Gauss-Newton uses the residual ``sqrt(w) (z_a - z_b)``.

    Examples
    --------
    ``W_q`` between the rest pose and a bent pose, with the weights (3.20) of the rest pose:

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import QuadraticEnergy
    >>> W = QuadraticEnergy(topo, reference_vertices=X)
    >>> za, zb = lengths_and_angles(X, topo), lengths_and_angles(bar_pose(X, 0.5, 0.0), topo)
    >>> W.value(za, za), round(W.value(za, zb), 6)
    (0.0, 0.034635)
    >>> g = W.gradient(za, zb)                       # d W / d z_b
    >>> e = np.zeros_like(zb); e[topo.n_edges + 5] = 1e-6
    >>> bool(abs((W.value(za, zb + e) - W.value(za, zb - e)) / 2e-6 - g[topo.n_edges + 5]) < 1e-8)
    True
    """

    def __init__(self, topology, reference_vertices=None, reference_z=None, weights=DEFAULT_WEIGHTS,
                 membrane_weights=None, bending_weights=None, bending_weight=DEFAULT_BENDING_WEIGHT):
        super().__init__(topology)
        if weights not in WEIGHT_SCHEMES:
            raise InputError(f"unknown weight scheme {weights!r}; use one of {WEIGHT_SCHEMES}")
        try:
            valid = np.isfinite(float(bending_weight)) and float(bending_weight) >= 0
        except (TypeError, ValueError):
            valid = False
        if not valid:
            raise InputError(f"bending_weight must be finite and >= 0, got {bending_weight!r}")
        if reference_vertices is not None and reference_z is not None:
            raise InputError("give reference_vertices or reference_z, not both")
        E = topology.n_edges
        self.bending_weight = float(bending_weight)
        self.weight_scheme = weights
        need_reference = weights != "uniform" and (membrane_weights is None or bending_weights is None)
        lbar = None
        if reference_vertices is not None:
            lbar = lengths_and_angles(reference_vertices, topology)[:E]
        elif reference_z is not None:
            lbar = _as_z(reference_z, topology, "reference_z")[:E]
        elif need_reference:
            raise InputError(f"weights={weights!r} need a reference configuration: pass reference_vertices or "
                             "reference_z (or custom membrane_weights and bending_weights)")
        if need_reference or weights == "uniform":
            w_s, w_b = quadratic_weights(lbar, topology, weights)
        else:
            w_s = w_b = None
        self.membrane_weights = self._custom(membrane_weights, "membrane_weights") if membrane_weights is not None \
            else w_s
        w_b = self._custom(bending_weights, "bending_weights") if bending_weights is not None else w_b
        self.bending_weights = np.where(topology.is_boundary_edge, 0.0, w_b)
        self.residual_weights = np.concatenate([self.membrane_weights, self.bending_weight * self.bending_weights])

    def _custom(self, w, name):
        w = np.asarray(w, float)
        E = self.n_edges
        if w.shape != (E,):
            raise LengthsAnglesError(f"{name} must have shape ({E},) (one per edge), got {w.shape}")
        bad = np.flatnonzero(~(np.isfinite(w) & (w >= 0)))
        if bad.size:
            raise LengthsAnglesError(f"{name} must be finite and >= 0; bad at edges {format_indices(bad)}")
        return w.copy()

    def difference(self, z_a, z_b):
        """``z_a - z_b``, ``(2E,)``, the angle differences on the circle
        (:func:`~lacore.geometry.lengths_angles.wrap_angle`)."""
        z_a, z_b = self._pair(z_a, z_b)
        d = z_a - z_b
        d[self.n_edges:] = wrap_angle(d[self.n_edges:])
        return d

    def value(self, z_a, z_b):
        """``W_q[z_a, z_b]`` (3.19), a float (angle differences on the circle)."""
        d = self.difference(z_a, z_b)
        return float(np.dot(self.residual_weights, d * d))

    def residual(self, z_a, z_b):
        """``r = sqrt(w) (z_b - z_a)``, ``(2E,)``, with ``W_q = r . r``."""
        return -np.sqrt(self.residual_weights) * self.difference(z_a, z_b)

    def gradient(self, z_a, z_b, argument=1):
        """``dW_q/dz_b = -2 w (z_a - z_b)`` (``argument=1``) or ``dW_q/dz_a = 2 w (z_a - z_b)``, ``(2E,)``."""
        arg = _parse_argument(argument)
        if isinstance(arg, tuple):
            raise InputError("the gradient takes argument 0 or 1")
        g = 2.0 * self.residual_weights * self.difference(z_a, z_b)
        return g if arg == 0 else -g

    def hessian(self, z_a, z_b, argument=1, project=False):
        """``2 diag(w)`` for argument 0 or 1, ``-2 diag(w)`` for the mixed block, ``(2E, 2E)`` CSR.

        ``project`` is accepted for interface compatibility (the Hessian is already PSD).
        """
        self._pair(z_a, z_b)
        arg = _parse_argument(argument)
        if project and isinstance(arg, tuple):
            raise InputError("project=True needs a symmetric Hessian block (argument 0 or 1)")
        sign = -2.0 if isinstance(arg, tuple) else 2.0
        return sp.diags(sign * self.residual_weights, format="csr")

    def _hessian_blocks(self, z_a, z_b, arg, project):
        """Per-edge blocks: ``(l_e, theta_e)`` on interior edges, ``l_e`` on boundary edges."""
        if isinstance(arg, tuple):
            raise InputError("Gauss-Newton blocks are symmetric (argument 0 or 1)")
        topo = self.topology
        E = self.n_edges
        ie, be = topo.interior_edges, topo.boundary_edges
        w = self.residual_weights
        Hi = np.zeros((len(ie), 2, 2))
        Hi[:, 0, 0] = 2.0 * w[ie]
        Hi[:, 1, 1] = 2.0 * w[E + ie]
        zi = np.column_stack([ie, E + ie])
        blocks = [_Blocks("q.int", zi, zi, Hi, _interior_quads(topo))]
        if be.size:
            zb = be[:, None]
            blocks.append(_Blocks("q.bnd", zb, zb, (2.0 * w[be])[:, None, None], topo.edges[be]))
        return blocks
