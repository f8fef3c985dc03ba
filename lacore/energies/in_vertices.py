"""Energies composed with X -> Z[X]: value, gradient and Gauss-Newton Hessian in vertex positions."""

import numpy as np

from ..errors import InputError, MeshError
from ..geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian
from ..geometry.topology import check_vertices
from ._common import DeformationEnergy, _as_z, _assemble_blocks, _Blocks, _interior_quads
from .quadratic import QuadraticEnergy

__all__ = ["EnergyInVertices"]


# --------------------------------------------------------------------------- composition with X -> Z[X]
def _z_support(topology):
    """Vertices carrying the gradient of each entry of ``z``: ``(2E, 4)`` indices and a ``(2E, 4)`` mask.

    Lengths: ``(a, b, -, -)``; interior angles: ``(a, b, left opposite, right
    opposite)``; boundary angles (constant 0): no vertex.  Masked-out slots
    repeat ``a, b`` and carry zero gradients.
    """
    def compute():
        E = topology.n_edges
        ie = topology.interior_edges
        ab = np.tile(topology.edges, (1, 2))
        ang = ab.copy()
        ang[ie] = _interior_quads(topology)
        mask = np.zeros((2 * E, 4), bool)
        mask[:E, :2] = True
        mask[E + ie] = True
        return np.concatenate([ab, ang]), mask
    return topology.cache.get((__name__, "z_support"), compute)


def _z_local_gradients(J, topology):
    """Rows of ``dZ/dX`` as ``(2E, 4, 3)`` gradients on the vertices of :func:`_z_support`."""
    support, _ = _z_support(topology)
    counts = np.diff(J.indptr)
    rows = np.repeat(np.arange(J.shape[0]), counts)
    v, c = np.divmod(J.indices, 3)
    hit = support[rows] == v[:, None]
    slot = np.argmax(hit, axis=1)
    inside = hit.any(1)
    if not inside.all():  # explicit zeros of the pattern (e.g. boundary angle rows) are fine
        if np.any(J.data[~inside] != 0):
            raise RuntimeError("lengths_and_angles_jacobian has nonzero entries outside the expected stencil")
        rows, slot, c = rows[inside], slot[inside], c[inside]
    grads = np.zeros((J.shape[0], 4, 3))
    grads[rows, slot, c] = J.data[inside] if not inside.all() else J.data
    return grads


def _element_gather(topology, block):
    """Index maps filling the element Jacobians of a symmetric block from :func:`_z_local_gradients`.

    Returns ``(src, dst)``: ``Jl.reshape(n * k * m, 3)[dst] = grads.reshape(2E * 4, 3)[src]``
    gives ``Jl (n, k, m, 3)``, the gradients of the block's ``k`` z-entries on its ``m`` element vertices.
    """
    def compute():
        support, mask = _z_support(topology)
        sup, msk = support[block.rows], mask[block.rows]  # (n, k, 4)
        ev = block.vertices
        hit = sup[..., None] == ev[:, None, None, :]
        if not hit.any(-1)[msk].all():
            raise RuntimeError(f"element vertices of {block.key} do not cover the stencils of its z-entries")
        pos = np.argmax(hit, axis=-1)
        n, k, _ = sup.shape
        m = ev.shape[1]
        dst = (np.arange(n * k).reshape(n, k, 1) * m + pos)[msk]
        src = (block.rows[..., None] * 4 + np.arange(4))[msk]
        return src, dst
    return topology.cache.get((__name__, "gn_gather", block.key), compute)


class EnergyInVertices:
    """A deformation energy composed with ``X -> Z[X]`` (3.5), one argument fixed.

    ``f(X) = W[z_fixed, Z[X]]`` for ``argument=1`` (``X`` is the deformed shape
    of :class:`ThinShellsEnergy`) or ``f(X) = W[Z[X], z_fixed]`` for ``argument=0``.

    Parameters
    ----------
    energy : DeformationEnergy
    z_fixed : (2E,) array_like
        The other argument.
    topology : MeshTopology, optional
        Must be the energy's topology (checked); defaults to it.
    argument : {0, 1}
        The slot ``Z[X]`` takes.

    Notes
    -----
    Gradient: ``grad f = J^T dW/dz`` with the analytic ``J = dZ/dX``
    (:func:`~lacore.geometry.lengths_angles.lengths_and_angles_jacobian`), shape ``(3V,)``,
    entry ``3 v + c`` for coordinate ``c`` of vertex ``v``.

    Gauss-Newton Hessian: ``J^T H_z J`` dropping the curvature term
    ``sum_i dW/dz_i d^2 z_i / dX^2``.  ``H_z`` is a sum of per-element blocks
    (per face for the membrane, per interior edge for bending and ``W_q``);
    with ``project=True`` (default) every block's negative eigenvalues are
    clamped to 0 (``W_TS`` can have indefinite blocks away from ``z_a = z_b``),
    so the result is symmetric positive semi-definite.  The ``X``-blocks
    ``J_e^T H_e J_e`` are formed per element and summed with a cached sparsity
    pattern.

    Examples
    --------
    ``X -> W_q[z*, Z(X)]``, the objective of the Gauss-Newton reconstruction (3.26):

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import EnergyInVertices, QuadraticEnergy
    >>> target = lengths_and_angles(bar_pose(X, 0.5, 0.0), topo)
    >>> f = EnergyInVertices(QuadraticEnergy(topo, reference_vertices=X), target)
    >>> round(f.value(X), 6), f.gradient(X).shape
    (0.034635, (66,))
    >>> f.value(bar_pose(X, 0.5, 0.0)) < 1e-20
    True
    """

    def __init__(self, energy, z_fixed, topology=None, argument=1):
        if not isinstance(energy, DeformationEnergy):
            raise TypeError(f"energy must be a DeformationEnergy, got {type(energy).__name__}")
        if topology is not None and topology is not energy.topology:
            if (topology.n_vertices != energy.topology.n_vertices
                    or not np.array_equal(topology.edges, energy.topology.edges)
                    or not np.array_equal(topology.faces, energy.topology.faces)):
                raise MeshError("the topology differs from the energy's topology")
        if argument not in (0, 1) or isinstance(argument, bool):
            raise InputError(f"argument must be 0 or 1, got {argument!r}")
        self.energy = energy
        self.topology = energy.topology
        self.argument = int(argument)
        self.z_fixed = _as_z(z_fixed, self.topology, "z_fixed").copy()
        self.z_fixed.setflags(write=False)

    def _args(self, z):
        return (self.z_fixed, z) if self.argument == 1 else (z, self.z_fixed)

    def _X(self, X):
        return check_vertices(X, self.topology.n_vertices)

    def z(self, X):
        """``Z[X]``, ``(2E,)``."""
        return lengths_and_angles(self._X(X), self.topology)

    def value(self, X):
        """``f(X)``, a float."""
        return self.energy.value(*self._args(self.z(X)))

    def gradient(self, X):
        """``J^T dW/dz``, ``(3V,)``."""
        J, z = lengths_and_angles_jacobian(self._X(X), self.topology, return_z=True)
        return J.T @ self.energy.gradient(*self._args(z), argument=self.argument)

    def value_and_gradient(self, X):
        """``(f(X), grad f(X))`` sharing one Jacobian evaluation."""
        J, z = lengths_and_angles_jacobian(self._X(X), self.topology, return_z=True)
        args = self._args(z)
        return self.energy.value(*args), J.T @ self.energy.gradient(*args, argument=self.argument)

    def gauss_newton_hessian(self, X, project=True):
        """Gauss-Newton Hessian ``J^T H_z J`` as a symmetric ``(3V, 3V)`` CSR matrix.

        Parameters
        ----------
        X : (V, 3) array_like
        project : bool
            Use the PSD part of every element block of ``H_z`` (default), making
            the result positive semi-definite; with False it equals ``J^T H_z J``.
        """
        topo = self.topology
        J, z = lengths_and_angles_jacobian(self._X(X), topo, return_z=True)
        grads = _z_local_gradients(J, topo)
        blocks = self.energy._hessian_blocks(*self._args(z), self.argument, project)
        xblocks = []
        for b in blocks:
            n, k = b.rows.shape
            m = b.vertices.shape[1]
            src, dst = _element_gather(topo, b)
            Jl = np.zeros((n * k * m, 3))
            Jl[dst] = grads.reshape(-1, 3)[src]
            Jl = Jl.reshape(n, k, 3 * m)
            Hx = np.swapaxes(Jl, 1, 2) @ (b.vals @ Jl)
            xi = (3 * b.vertices[:, :, None] + np.arange(3)).reshape(n, 3 * m)
            xblocks.append(_Blocks(b.key, xi, xi, Hx))
        n = 3 * topo.n_vertices
        return _assemble_blocks(topo, xblocks, (n, n), f"x{self.argument}")

    # ---------------------------------------------------------------- residual form of W_q
    def _quadratic(self):
        if not isinstance(self.energy, QuadraticEnergy):
            raise TypeError("the residual form exists only for QuadraticEnergy")
        return self.energy

    def residual(self, X):
        """``r = sqrt(w) (Z[X] - z_fixed)``, ``(2E,)`` (angle differences on the circle), with ``W_q = r . r``
        (QuadraticEnergy only)."""
        q = self._quadratic()
        return np.sqrt(q.residual_weights) * q.difference(self.z(X), self.z_fixed)

    def residual_and_jacobian(self, X):
        """Residual ``r (2E,)`` and its Jacobian ``sqrt(w) J`` (``(2E, 3V)`` CSR, pattern of ``J``).

        The Gauss-Newton Hessian of ``W_q`` is ``2 (sqrt(w) J)^T (sqrt(w) J)``.
        """
        q = self._quadratic()
        sw = np.sqrt(q.residual_weights)
        J, z = lengths_and_angles_jacobian(self._X(X), self.topology, return_z=True)
        J.data *= np.repeat(sw, np.diff(J.indptr))
        return sw * q.difference(z, self.z_fixed), J
