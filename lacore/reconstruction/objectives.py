"""Objectives of the Gauss-Newton reconstruction: ``X -> W[z*, Z(X)]`` with gradient and Gauss-Newton matrix.

An objective has ``energy(X)``, ``value_z(z)``, ``linearize(X) -> (energy,
gradient (3V,), matrix)`` (``matrix()`` returns the Gauss-Newton matrix values
in the order of :func:`~lacore.reconstruction.assembly.gauss_newton_pattern`,
``matrix.dot(v)`` multiplies without assembling) and ``noise_floor()``.

:class:`QuadraticObjective`
    ``W_q`` (3.19): the nonlinear least-squares problem
    ``sum_j w_j (Z_j(X) - z*_j)^2`` (angle differences on the circle) with the residual weights of
    :class:`lacore.energies.QuadraticEnergy`; Gauss-Newton matrix
    ``2 J^T W J`` (``J = dZ/dX``), the full Hessian
    ``2 J^T W J + 2 sum_j w_j r_j d2 Z_j`` (``second_order=True``, per-edge
    blocks of :mod:`lacore.geometry.hessians`, same sparsity pattern) and the right-hand
    side of the geodesic acceleration (``acceleration_gradient``).
:class:`ShellsObjective`
    ``W_TS`` (3.25) through :class:`lacore.energies.EnergyInVertices`: matrix
    ``J^T (d^2W/dz^2) J`` with the element blocks projected to be positive
    semi-definite.
"""

import numpy as np
import scipy.sparse as sp

from ..energies import EnergyInVertices, QuadraticEnergy, ThinShellsEnergy
from ..geometry.hessians import ANGLE_PAIRS, LENGTH_PAIRS, residual_curvature_values
from ..geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian, wrap_angle
from ..geometry.trigonometry import triangle_areas
from .assembly import upper_outer
from .pcg import dot

__all__ = ["QuadraticObjective", "ShellsObjective", "QuadraticGNMatrix", "AssembledGNMatrix", "reference_weights"]

_EPS = np.finfo(float).eps


def reference_weights(reference_vertices, topology, weights, bending_weight):
    """Residual weights ``(2E,)`` of ``W_q`` from :class:`lacore.energies.QuadraticEnergy`."""

    energy = QuadraticEnergy(topology, reference_vertices=reference_vertices, weights=weights,
                             bending_weight=bending_weight)
    return np.asarray(energy.residual_weights, float)


class QuadraticObjective:
    """``W_q[z*, Z(X)]``: value, gradient and Gauss-Newton matrix values in the pattern's order."""

    name = "quadratic"
    #: The matrix can include the second-order term (Newton steps).
    second_order = True

    def __init__(self, z_target, residual_weights, topology, pattern, buffer=None):
        self.z_target = z_target
        self.w = residual_weights
        self.topology = topology
        self.pattern = pattern
        E = topology.n_edges
        self._w2_len = 2.0 * residual_weights[:E]
        self._w2_ang = 2.0 * residual_weights[E + topology.interior_edges]
        self._n_len = 6 * E
        self._vals = np.empty(len(pattern["slots"])) if buffer is None else buffer

    def residual(self, z):
        """``z - z*`` with the angle differences on the circle (:func:`~lacore.geometry.lengths_angles.wrap_angle`)."""
        r = z - self.z_target
        E = self.topology.n_edges
        r[E:] = wrap_angle(r[E:])
        return r

    def value_z(self, z):
        r = self.residual(z)
        return dot(self.w * r, r)

    def energy(self, X):
        return self.value_z(lengths_and_angles(X, self.topology, check=False))

    def linearize(self, X):
        """Energy, gradient ``(3V,)`` and a function returning the Gauss-Newton matrix values at ``X``."""
        J, z = lengths_and_angles_jacobian(X, self.topology, return_z=True)
        r = self.residual(z)
        wr = self.w * r
        energy = dot(wr, r)
        grad = 2.0 * (J.T @ wr)
        return energy, grad, QuadraticGNMatrix(self, J, z, X)

    def acceleration_gradient(self, X, d, matrix, h):
        """``2 J^T W r_vv``: right-hand side of the geodesic acceleration for the direction ``d`` (``(3V,)``).

        ``r_vv`` is the second directional derivative of the residual
        ``Z(X) - z*`` along ``d``, by the finite difference
        ``(2 / h) ((Z(X + h d) - Z(X)) / h - J d)`` (one evaluation of ``Z``).
        """
        zh = lengths_and_angles(X + h * d.reshape(-1, 3), self.topology, check=False)
        dz = zh - matrix.z
        E = self.topology.n_edges
        dz[E:] = wrap_angle(dz[E:])                        # an angle that crossed the branch cut at +-pi
        rvv = (2.0 / h) * (dz / h - matrix.J @ d)
        return 2.0 * (matrix.J.T @ (self.w * rvv))

    def noise_floor(self):
        """``W_q`` of a perturbation of 16 ulp of every entry of ``z*`` (angles: of pi)."""
        E = self.topology.n_edges
        scale = np.concatenate([np.abs(self.z_target[:E]), np.full(E, np.pi)])
        return float(np.sum(self.w * (16 * _EPS * scale) ** 2))


class QuadraticGNMatrix:
    """The Gauss-Newton matrix ``2 J^T W J`` of ``W_q`` at one point, or the full Hessian.

    Calling it returns the values in the pattern's order (for a factorization);
    :meth:`dot` multiplies without assembling (two sparse products with ``J``).
    With ``second_order=True`` both include ``S = 2 sum_j w_j r_j d2 Z_j``
    (``r = Z(X) - z*``), the term Gauss-Newton drops: the Hessian of ``W_q``.
    """

    def __init__(self, objective, J, z, X=None):
        self.objective = objective
        self.J = J
        self.z = z
        self.X = X
        self._w2 = 2.0 * objective.w
        self._second = None

    def second_order_values(self):
        """Per-element upper triangles of ``S``: ``(21, E)`` (lengths) and ``(78, E_int)`` (angles), cached."""
        if self._second is None:
            obj = self.objective
            topo = obj.topology
            E = topo.n_edges
            r = obj.residual(self.z)
            self._second = residual_curvature_values(self.X, topo, obj._w2_len * r[:E],
                                                     obj._w2_ang * r[E + topo.interior_edges])
        return self._second

    def __call__(self, second_order=False):
        obj, J = self.objective, self.J
        local = J.data[obj.pattern["local_order"]]
        gl = local[: obj._n_len].reshape(6, -1)
        ga = local[obj._n_len:].reshape(12, -1)
        vals = obj._vals  # reused buffer: no page faults for a fresh multi-MB array per iteration
        m = 21 * gl.shape[1]
        upper_outer(gl, gl * obj._w2_len, vals[:m].reshape(21, -1))
        upper_outer(ga, ga * obj._w2_ang, vals[m:].reshape(78, -1))
        if second_order:
            s_len, s_ang = self.second_order_values()
            vals[:m] += s_len.ravel()
            vals[m:] += s_ang.ravel()
        return np.bincount(obj.pattern["slots"], weights=vals, minlength=obj.pattern["nnz"])

    def dot(self, v, second_order=False):
        """``2 J^T W J v`` (plus ``S v`` with ``second_order``) for ``v`` of shape ``(3V,)``."""
        out = self.J.T @ (self._w2 * (self.J @ v))
        if second_order:
            out += self._second_order_dot(v)
        return out

    def _second_order_dot(self, v):
        """``S v`` element by element from the upper-triangle values (no assembly)."""
        pat = self.objective.pattern
        s_len, s_ang = self.second_order_values()
        out = np.zeros_like(v)
        for cols, vals, (ii, jj) in ((pat["len_cols"], s_len, LENGTH_PAIRS), (pat["ang_cols"], s_ang, ANGLE_PAIRS)):
            local = v[cols]                                   # (k, m): local coordinates of every element
            y = np.zeros_like(local)
            for p, (i, j) in enumerate(zip(ii, jj, strict=True)):
                y[i] += vals[p] * local[j]
                if i != j:
                    y[j] += vals[p] * local[i]
            out += np.bincount(cols.ravel(), weights=y.ravel(), minlength=len(v))
        return out


class AssembledGNMatrix:
    """A Gauss-Newton matrix given by a function returning its lower-triangle values (pattern order).

    :meth:`dot` assembles once and multiplies with the symmetric matrix.
    """

    def __init__(self, values, pattern):
        self._values = values
        self._pattern = pattern
        self._lower = None

    def __call__(self):
        return self._values()

    def dot(self, v):
        """Product of the symmetric matrix with ``v`` of shape ``(n,)``."""
        if self._lower is None:
            p = self._pattern
            self._lower = sp.csc_matrix((self._values(), p["indices"], p["indptr"]), shape=(p["n"], p["n"]))
        L = self._lower
        return L @ v + L.T @ v - L.diagonal() * v


class ShellsObjective:
    """``W_TS[z*, Z(X)]`` through :class:`lacore.energies.EnergyInVertices`.

    ``value_exponent`` ``e``: values, gradients and matrices are those of the
    energy times ``2^e`` (exact), the units of a scaled context
    (:mod:`lacore.reconstruction.context`, "Units").
    """

    name = "shells"

    def __init__(self, z_target, topology, bending_weight, solver, pattern, value_exponent=0):

        self.shells = ThinShellsEnergy(topology, bending_weight=bending_weight)
        self.model = EnergyInVertices(self.shells, z_target, topology)
        self.z_target = z_target
        self.topology = topology
        self.solver = solver
        self.pattern = pattern
        self.value_exponent = int(value_exponent)

    def _scaled(self, x):
        return np.ldexp(x, self.value_exponent) if self.value_exponent else x

    def value_z(self, z):
        return float(self._scaled(float(self.shells.value(self.z_target, z))))

    def energy(self, X):
        return self.value_z(lengths_and_angles(X, self.topology, check=False))

    def linearize(self, X):
        value, grad = self.model.value_and_gradient(X)

        def values():
            return self._scaled(self.solver.values_from_matrix(self.model.gauss_newton_hessian(X)))
        return (float(self._scaled(float(value))), self._scaled(np.asarray(grad, float).ravel()),
                AssembledGNMatrix(values, self.pattern))

    def noise_floor(self):
        """Round-off level of ``W_TS`` near ``z*``: ``16 eps (mu + lam) * total area``.

        The membrane density cancels terms of size ``mu``, ``lam`` per unit area
        at ``G = I``, so its value carries an absolute error of that order.
        """

        area = float(np.sum(triangle_areas(self.z_target[: self.topology.n_edges][self.topology.face_edges])))
        return float(self._scaled(16 * _EPS * (self.shells.mu + self.shells.lam) * area))

