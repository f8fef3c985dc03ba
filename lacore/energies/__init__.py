"""Deformation energies on lengths and angles (thesis section 3.3, Definitions 3.11-3.14).

An energy ``W[z_a, z_b]`` compares two lengths-and-angles vectors ``z = (l, theta)``
of shape ``(2E,)`` (layout of :mod:`lacore.geometry.lengths_angles`: ``z[:E]`` edge lengths,
``z[E:]`` signed dihedral angles).  ``z_a`` is the first argument (*argument 0*),
``z_b`` the second (*argument 1*); for :class:`ThinShellsEnergy` ``z_a`` is the
undeformed (reference) and ``z_b`` the deformed configuration.

Energies
--------
:class:`QuadraticEnergy`
    ``W_q`` (3.19) with the weights (3.20) of [FB11] or (3.21) of [HRS+16]: a
    weighted sum of squares ``sum_i w_i (z_a - z_b)_i^2`` with constant weights.
:class:`ThinShellsEnergy`
    ``W_TS = W_mem + eta W_bend`` (3.25): the nonlinear membrane energy (3.23)
    with the density (1.23) applied to the distortion tensor ``G = g_a^{-1} g_b``
    (1.33), written in squared edge lengths only, plus the *Discrete Shells*
    bending energy (3.24).
:class:`EnergyInVertices`
    ``X -> W[z_fixed, Z[X]]`` (or ``W[Z[X], z_fixed]``): value, gradient
    ``J^T dW/dz`` and a positive semi-definite Gauss-Newton Hessian in vertex
    coordinates, plus the residual form ``r = sqrt(w) (Z[X] - z_fixed)`` of ``W_q``.

Defaults
--------
:data:`DEFAULT_WEIGHTS` and :data:`DEFAULT_BENDING_WEIGHT` are the weight scheme and
``eta`` of every energy built without them, and the defaults of
:class:`lacore.reconstruction.ReconstructionSettings`, which every other part of
lacore takes them from.

Derivatives
-----------
Every energy has ``value``, ``gradient`` and ``hessian``; ``argument`` selects
the differentiated slot: ``0`` (``z_a``), ``1`` (``z_b``) or ``(0, 1)`` for the
mixed block ``d^2 W / dz_a dz_b`` (rows ``z_a``, columns ``z_b``; ``(1, 0)`` is
its transpose).  Hessians are ``(2E, 2E)`` CSR matrices assembled from small
per-element blocks (per face, per interior edge); the sparsity pattern and the
duplicate-summing map are computed once per topology and element type
(cached on the :class:`~lacore.geometry.topology.MeshTopology`), so later calls only
compute the block values and one ``bincount``.

Membrane energy in squared lengths
----------------------------------
For a face with squared edge lengths ``p = l_a^2`` (undeformed) and
``q = l_b^2`` (deformed), ``p[i]`` opposite local vertex ``i``, let
``M = 1 1^T - 2 I`` (3 x 3).  In the frame ``(X_1 - X_0, X_2 - X_0)`` the first
fundamental form (1.13) is ``g = [[p_2, c], [c, p_1]]`` with
``c = (p_1 + p_2 - p_0) / 2`` (law of cosines (3.2)), and the formula before
Definition 3.12 becomes::

    s = p^T M p = 16 a_f^2 = 4 det g_a,    t = q^T M q = 16 ã_f^2,    C = p^T M q
    tr G = 2 C / s,                         det G = t / s   (3.22)

(``s`` is Heron's formula (3.3) in squared lengths).  All three are quadratic
forms in the squared lengths, so gradients and Hessians follow from the chain
rule through ``(s, t, C)``.  For accuracy ``a_f`` and ``ã_f`` are computed with
Kahan's formula (:func:`lacore.geometry.trigonometry.triangle_areas`) and ``C`` as
``s + p^T M (q - p)``, so that ``W[z, z] = 0`` exactly.

The density is (1.23) rewritten for the metric distortion ``A = G``
(``|D phi|_F^2 = tr A``, ``(det D phi)^2 = det A``,
``log det D phi = 1/2 log det A``)::

    W_mem(A) = mu/2 tr A + lam/4 det A - (mu/2 + lam/4) log det A - mu - lam/4

which is the density of [HRWW12].  Note that the display in Definition 3.12
writes the log coefficient as ``mu + lam/2``; with that coefficient the identity
would not be a critical point (``dW/dA (I) = -(mu/2 + lam/4) I``), contradicting
the requirement of section 1.3 that isometries are minimizers with ``W = 0``,
so we follow (1.23).  With eigenvalues ``s_1, s_2 > 0`` of ``A``,
``W_mem = mu/2 sum (s_i - log s_i - 1) + lam/4 (det A - log det A - 1) >= 0``,
with equality exactly for ``A = I``.

Invalid triangles
-----------------
A face whose lengths (in either argument of :class:`ThinShellsEnergy`) violate
the strict triangle inequality (3.6) or have zero area has ``log det G = -inf``
or undefined distortion: ``value`` returns ``+inf`` (so line searches reject
such steps) while ``gradient`` and ``hessian`` raise
:class:`~lacore.errors.LengthsAnglesError` naming the faces.

Boundary edges
--------------
Dihedral angles of boundary edges are 0 by convention
(:mod:`lacore.geometry.lengths_angles`), so their bending terms carry no information:
their bending weight is 0 in both energies (also for user-given weights).
"""

from ._common import DEFAULT_BENDING_WEIGHT, DEFAULT_WEIGHTS, WEIGHT_SCHEMES, DeformationEnergy, edge_areas
from .in_vertices import EnergyInVertices
from .quadratic import QuadraticEnergy, quadratic_weights
from .thin_shells import ThinShellsEnergy, membrane_density

__all__ = [
    "DeformationEnergy",
    "QuadraticEnergy",
    "ThinShellsEnergy",
    "EnergyInVertices",
    "quadratic_weights",
    "edge_areas",
    "membrane_density",
    "WEIGHT_SCHEMES",
    "DEFAULT_WEIGHTS",
    "DEFAULT_BENDING_WEIGHT",
]
