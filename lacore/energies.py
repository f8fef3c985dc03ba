"""Deformation energies on lengths and angles (thesis section 3.3, Definitions 3.11-3.14).

An energy ``W[z_a, z_b]`` compares two lengths-and-angles vectors ``z = (l, theta)``
of shape ``(2E,)`` (layout of :mod:`lacore.lengths_angles`: ``z[:E]`` edge lengths,
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

Derivatives
-----------
Every energy has ``value``, ``gradient`` and ``hessian``; ``argument`` selects
the differentiated slot: ``0`` (``z_a``), ``1`` (``z_b``) or ``(0, 1)`` for the
mixed block ``d^2 W / dz_a dz_b`` (rows ``z_a``, columns ``z_b``; ``(1, 0)`` is
its transpose).  Hessians are ``(2E, 2E)`` CSR matrices assembled from small
per-element blocks (per face, per interior edge); the sparsity pattern and the
duplicate-summing map are computed once per topology and element type
(cached on the :class:`~lacore.topology.MeshTopology`), so later calls only
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
Kahan's formula (:func:`lacore.trigonometry.triangle_areas`) and ``C`` as
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
(:mod:`lacore.lengths_angles`), so their bending terms carry no information:
their bending weight is 0 in both energies (also for user-given weights).
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .errors import LengthsAnglesError, MeshError, format_indices
from .lengths_angles import lengths_and_angles, lengths_and_angles_jacobian
from .topology import check_vertices
from .trigonometry import triangle_area_gradient, triangle_areas, triangle_inequality_margin

__all__ = [
    "DeformationEnergy",
    "QuadraticEnergy",
    "ThinShellsEnergy",
    "EnergyInVertices",
    "quadratic_weights",
    "edge_areas",
    "membrane_density",
]

_M = np.ones((3, 3)) - 2.0 * np.eye(3)  # p^T M p = 16 area^2 (Heron in squared lengths)
_WEIGHT_SCHEMES = ("frohlich_botsch", "heeren", "uniform")


# --------------------------------------------------------------------------- helpers
def _as_z(z, topology, name):
    """``z`` as float ``(2E,)``; LengthsAnglesError for a wrong shape or non-finite entries."""
    z = np.asarray(z, dtype=float)
    E = topology.n_edges
    if z.shape != (2 * E,):
        raise LengthsAnglesError(f"{name} must have shape ({2 * E},) = 2 x {E} edges of the energy's mesh, "
                                 f"got {z.shape}")
    bad = np.flatnonzero(~np.isfinite(z))
    if bad.size:
        where = [f"{'length' if i < E else 'angle'} of edge {i % E}" for i in bad[:5]]
        raise LengthsAnglesError(f"{name} has NaN or infinite entries ({bad.size}): " + ", ".join(where))
    return z


def _parse_argument(argument):
    """``0``, ``1`` or the mixed block ``(0, 1)`` / ``(1, 0)``."""
    if isinstance(argument, (int, np.integer)) and not isinstance(argument, bool) and argument in (0, 1):
        return int(argument)
    if isinstance(argument, (tuple, list)) and tuple(argument) in ((0, 1), (1, 0)):
        return tuple(int(a) for a in argument)
    raise ValueError(f"argument must be 0, 1, (0, 1) or (1, 0), got {argument!r}")


def _scatter(index, values, n):
    """Sum ``values`` into a length-``n`` vector at ``index`` (same shapes)."""
    return np.bincount(np.ravel(index), weights=np.ravel(values), minlength=n)


def _project_psd(H):
    """Clamp the negative eigenvalues of every symmetric block of ``H (n, k, k)`` to 0."""
    if H.shape[0] == 0:
        return H
    lam, V = np.linalg.eigh(H)
    return (V * np.maximum(lam, 0.0)[:, None, :]) @ np.swapaxes(V, 1, 2)


@dataclass
class _Blocks:
    """Per-element dense blocks of a sparse matrix.

    ``vals[n]`` is added at ``(rows[n, i], cols[n, j])``.  ``key`` names the
    (topology-only) index structure; equal keys must mean equal ``rows``/``cols``.
    ``vertices (n, m)`` are the element's vertices (used by the Gauss-Newton
    Hessian in vertex coordinates; ``None`` for mixed blocks).
    """

    key: str
    rows: np.ndarray
    cols: np.ndarray
    vals: np.ndarray
    vertices: np.ndarray = None


def _assemble(topology, key, index_fn, vals, shape):
    """Sum element values into a CSR matrix with a cached symbolic pattern.

    Parameters
    ----------
    topology : MeshTopology
        Owner of the cache.
    key : str
        Unique name of the index structure returned by ``index_fn``.
    index_fn : callable
        ``() -> (rows, cols)`` flat int arrays matching ``vals.ravel()``; called once per topology and key.
    vals : ndarray
    shape : (int, int)
    """
    def compute():
        rows, cols = index_fn()
        flat = np.ravel(rows).astype(np.int64) * shape[1] + np.ravel(cols)
        uniq, inverse = np.unique(flat, return_inverse=True)
        r = uniq // shape[1]
        indptr = np.r_[0, np.cumsum(np.bincount(r, minlength=shape[0]))]
        return {"inverse": inverse.ravel(), "indices": (uniq % shape[1]).astype(np.int32),
                "indptr": indptr.astype(np.int32), "nnz": len(uniq)}
    pat = topology._cached("energies:" + key, compute)
    data = np.bincount(pat["inverse"], weights=np.ravel(vals), minlength=pat["nnz"])
    return sp.csr_matrix((data, pat["indices"].copy(), pat["indptr"].copy()), shape=shape)


def _assemble_blocks(topology, blocks, shape, prefix):
    """Assemble a list of :class:`_Blocks` into one CSR matrix of ``shape``."""
    key = prefix + "|" + "+".join(b.key for b in blocks)

    def index_fn():
        rows = [np.broadcast_to(b.rows[:, :, None], b.vals.shape).ravel() for b in blocks]
        cols = [np.broadcast_to(b.cols[:, None, :], b.vals.shape).ravel() for b in blocks]
        return np.concatenate(rows), np.concatenate(cols)
    vals = np.concatenate([b.vals.ravel() for b in blocks])
    return _assemble(topology, key, index_fn, vals, shape)


def _interior_quads(topology):
    """``(E_int, 4)`` vertices ``(a, b, left opposite, right opposite)`` of the interior edges."""
    def compute():
        ie = topology.interior_edges
        return np.column_stack([topology.edges[ie], topology.edge_opposite_vertices[ie]])
    return topology._cached("energies:interior_quads", compute)


def edge_areas(lengths, topology):
    """Edge-associated areas ``d_e = (a_f + a_f') / 3`` (Def. 1.29), ``(E,)``.

    Boundary edges have one face: ``d_e = a_f / 3``.  Areas by Kahan's formula
    from the per-edge ``lengths (E,)``.
    """
    A = triangle_areas(np.asarray(lengths, float)[topology.face_edges])
    return _scatter(topology.face_edges, np.repeat(A / 3.0, 3), topology.n_edges)


def quadratic_weights(reference_lengths, topology, scheme="frohlich_botsch"):
    """Per-edge weights ``(w_s, w_b)`` of the quadratic energy (3.19).

    Parameters
    ----------
    reference_lengths : (E,) array_like
        Edge lengths ``lbar`` of the reference configuration.
    topology : MeshTopology
    scheme : {"frohlich_botsch", "heeren", "uniform"}
        ``"frohlich_botsch"`` (3.20): ``w_s = 1 / lbar^2``, ``w_b = lbar^2 / dbar``;
        ``"heeren"`` (3.21): ``w_s = dbar / lbar^2``, ``w_b = lbar^2 / dbar``;
        ``"uniform"``: ``w_s = w_b = 1``.  ``dbar`` from :func:`edge_areas`.

    Returns
    -------
    w_s, w_b : (E,) ndarray
        ``w_b`` is 0 on boundary edges (their angle is 0 by convention).
    """
    if scheme not in _WEIGHT_SCHEMES:
        raise ValueError(f"unknown weight scheme {scheme!r}; use one of {_WEIGHT_SCHEMES}")
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


def membrane_density(trace, det, mu=1.0, lam=1.0):
    """Membrane energy density ``W_mem(A)`` from ``tr A`` and ``det A`` (1.23), Def. 3.12.

    ``mu/2 tr A + lam/4 det A - (mu/2 + lam/4) log det A - mu - lam/4`` (see the
    module docstring for the log coefficient); ``+inf`` where ``det A <= 0``.
    """
    trace, det = np.asarray(trace, float), np.asarray(det, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (0.5 * mu * trace + 0.25 * lam * det - (0.5 * mu + 0.25 * lam) * np.log(det) - mu - 0.25 * lam)
    return np.where(det > 0, out, np.inf)


def _area_hessian(L, A):
    """Hessian of the triangle area with respect to its edge lengths, ``(F, 3, 3)``.

    With ``p = L^2``: ``dA/dp = M p / (16 A)``,
    ``d^2A/dp^2 = M / (16 A) - (M p)(M p)^T / (256 A^3)``, then
    ``d^2A/dl_i dl_j = 4 l_i l_j d^2A/dp_i dp_j + 2 delta_ij dA/dp_i``.
    """
    p = L * L
    Mp = p.sum(1, keepdims=True) - 2.0 * p
    Ap = Mp / (16.0 * A[:, None])
    App = _M / (16.0 * A[:, None, None]) - Mp[:, :, None] * Mp[:, None, :] / (256.0 * A[:, None, None] ** 3)
    H = 4.0 * L[:, :, None] * L[:, None, :] * App
    H[:, [0, 1, 2], [0, 1, 2]] += 2.0 * Ap
    return H


# --------------------------------------------------------------------------- base class
class DeformationEnergy:
    """Common interface of the deformation energies ``W[z_a, z_b]`` on lengths and angles.

    Subclasses implement ``value``, ``gradient`` and ``_hessian_blocks``;
    :meth:`hessian` assembles the blocks.
    """

    def __init__(self, topology):
        self.topology = topology

    @property
    def n_edges(self):
        return self.topology.n_edges

    def _pair(self, z_a, z_b):
        return _as_z(z_a, self.topology, "z_a"), _as_z(z_b, self.topology, "z_b")

    def value(self, z_a, z_b):
        raise NotImplementedError

    def gradient(self, z_a, z_b, argument=1):
        raise NotImplementedError

    def _hessian_blocks(self, z_a, z_b, argument, project):
        raise NotImplementedError

    def hessian(self, z_a, z_b, argument=1, project=False):
        """Hessian ``d^2 W`` with respect to ``argument`` as a ``(2E, 2E)`` CSR matrix.

        Parameters
        ----------
        z_a, z_b : (2E,) array_like
        argument : 0, 1, (0, 1) or (1, 0)
            Differentiated slot(s); ``(0, 1)`` is ``d^2 W / dz_a dz_b`` (rows ``z_a``).
        project : bool
            Clamp the negative eigenvalues of every element block to 0, giving a
            positive semi-definite approximation (only for ``argument`` 0 or 1).
        """
        z_a, z_b = self._pair(z_a, z_b)
        arg = _parse_argument(argument)
        if project and isinstance(arg, tuple):
            raise ValueError("project=True needs a symmetric Hessian block (argument 0 or 1)")
        if arg == (1, 0):
            return self.hessian(z_a, z_b, (0, 1)).T.tocsr()
        blocks = self._hessian_blocks(z_a, z_b, arg, project)
        n = 2 * self.n_edges
        return _assemble_blocks(self.topology, blocks, (n, n), f"z{arg}")


# --------------------------------------------------------------------------- quadratic energy
class QuadraticEnergy(DeformationEnergy):
    """Quadratic deformation energy on lengths and angles, Definition 3.11.

    ``W_q[z_a, z_b] = sum_e w_s,e (l_a - l_b)_e^2 + eta sum_e w_b,e (theta_a - theta_b)_e^2``  (3.19)

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
        Weight scheme, see :func:`quadratic_weights`.
    membrane_weights, bending_weights : (E,) array_like, optional
        Custom ``w_s`` / ``w_b`` overriding the scheme (non-negative, finite).
        Bending weights of boundary edges are set to 0 (angle 0 by convention).
    bending_weight : float
        ``eta >= 0``.

    Attributes
    ----------
    membrane_weights, bending_weights : (E,) ndarray
        ``w_s`` and ``w_b`` (without ``eta``).
    residual_weights : (2E,) ndarray
        ``w = (w_s, eta w_b)`` so that ``W_q = sum_i w_i (z_a - z_b)_i^2``;
        Gauss-Newton uses the residual ``sqrt(w) (z_a - z_b)``.
    """

    def __init__(self, topology, reference_vertices=None, reference_z=None, weights="frohlich_botsch",
                 membrane_weights=None, bending_weights=None, bending_weight=1e-3):
        super().__init__(topology)
        if weights not in _WEIGHT_SCHEMES:
            raise ValueError(f"unknown weight scheme {weights!r}; use one of {_WEIGHT_SCHEMES}")
        if not (np.isfinite(bending_weight) and bending_weight >= 0):
            raise ValueError(f"bending_weight must be finite and >= 0, got {bending_weight!r}")
        if reference_vertices is not None and reference_z is not None:
            raise ValueError("give reference_vertices or reference_z, not both")
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
            raise ValueError(f"weights={weights!r} need a reference configuration: pass reference_vertices or "
                             "reference_z (or custom membrane_weights and bending_weights)")
        if need_reference:
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

    def value(self, z_a, z_b):
        """``W_q[z_a, z_b]`` (3.19), a float."""
        z_a, z_b = self._pair(z_a, z_b)
        d = z_a - z_b
        return float(np.dot(self.residual_weights, d * d))

    def residual(self, z_a, z_b):
        """``r = sqrt(w) (z_b - z_a)``, ``(2E,)``, with ``W_q = r . r``."""
        z_a, z_b = self._pair(z_a, z_b)
        return np.sqrt(self.residual_weights) * (z_b - z_a)

    def gradient(self, z_a, z_b, argument=1):
        """``dW_q/dz_b = -2 w (z_a - z_b)`` (``argument=1``) or ``dW_q/dz_a = 2 w (z_a - z_b)``, ``(2E,)``."""
        z_a, z_b = self._pair(z_a, z_b)
        arg = _parse_argument(argument)
        if isinstance(arg, tuple):
            raise ValueError("the gradient takes argument 0 or 1")
        g = 2.0 * self.residual_weights * (z_a - z_b)
        return g if arg == 0 else -g

    def hessian(self, z_a, z_b, argument=1, project=False):
        """``2 diag(w)`` for argument 0 or 1, ``-2 diag(w)`` for the mixed block, ``(2E, 2E)`` CSR.

        ``project`` is accepted for interface compatibility (the Hessian is already PSD).
        """
        self._pair(z_a, z_b)
        arg = _parse_argument(argument)
        if project and isinstance(arg, tuple):
            raise ValueError("project=True needs a symmetric Hessian block (argument 0 or 1)")
        sign = -2.0 if isinstance(arg, tuple) else 2.0
        return sp.diags(sign * self.residual_weights, format="csr")

    def _hessian_blocks(self, z_a, z_b, arg, project):
        """Per-edge blocks: ``(l_e, theta_e)`` on interior edges, ``l_e`` on boundary edges."""
        if isinstance(arg, tuple):
            raise ValueError("Gauss-Newton blocks are symmetric (argument 0 or 1)")
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


# --------------------------------------------------------------------------- thin shells energy
class _MembraneFaces:
    """Per-face quantities of the membrane energy (3.22), (3.23) for lengths ``La`` (undeformed), ``Lb``.

    Scalar partial derivatives of the per-face energy
    ``e(s, t, C) = 1/4 [mu C/r - mu r + lam/4 t/r - lam/4 r - k r log(t/s)]``, ``r = sqrt(s)``,
    ``k = mu/2 + lam/4`` (``e = a_f W_mem(G)`` with ``a_f = r/4``, ``tr G = 2C/s``, ``det G = t/s``).
    """

    def __init__(self, La, Lb, mu, lam):
        self.La, self.Lb, self.mu, self.lam = La, Lb, mu, lam
        self.k = 0.5 * mu + 0.25 * lam
        self.Aa, self.Ab = triangle_areas(La), triangle_areas(Lb)
        self.valid_a = (self.Aa > 0) & (triangle_inequality_margin(La) > 0) & (La > 0).all(1)
        self.valid_b = (self.Ab > 0) & (triangle_inequality_margin(Lb) > 0) & (Lb > 0).all(1)
        p, q = La * La, Lb * Lb
        self.p, self.q = p, q
        self.Mp = p.sum(1, keepdims=True) - 2.0 * p
        self.Mq = q.sum(1, keepdims=True) - 2.0 * q
        d = q - p
        Md = d.sum(1, keepdims=True) - 2.0 * d
        self.pMd = np.einsum("ij,ij->i", p, Md)  # C - s, accurate near q = p
        self.s = 16.0 * self.Aa**2
        self.t = 16.0 * self.Ab**2
        self.C = self.s + self.pMd

    def check(self):
        """Raise LengthsAnglesError naming the faces that violate the triangle inequality."""
        for valid, name in ((self.valid_a, "z_a"), (self.valid_b, "z_b")):
            bad = np.flatnonzero(~valid)
            if bad.size:
                raise LengthsAnglesError(f"{name} has triangles violating the triangle inequality (or degenerate): "
                                         f"faces {format_indices(bad)}; the thin shells energy is +inf there")

    def energies(self):
        """Per-face ``a_f W_mem(G_f)``, ``(F,)``; ``+inf`` on invalid faces."""
        mu, lam, k = self.mu, self.lam, self.k
        valid = self.valid_a & self.valid_b
        out = np.full(len(valid), np.inf)
        Aa, Ab, s = self.Aa[valid], self.Ab[valid], self.s[valid]
        det_minus_1 = (Ab - Aa) * (Ab + Aa) / Aa**2
        out[valid] = Aa * (mu * self.pMd[valid] / s + 0.25 * lam * det_minus_1 - 2.0 * k * np.log(Ab / Aa))
        return out

    def trace_det(self):
        """``tr G`` and ``det G`` per face (3.22); NaN on invalid faces."""
        valid = self.valid_a & self.valid_b
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(valid, 2.0 * self.C / self.s, np.nan), np.where(valid, self.t / self.s, np.nan)

    # partial derivatives of e(s, t, C)
    def partials(self):
        mu, lam, k = self.mu, self.lam, self.k
        s, t, C = self.s, self.t, self.C
        r = np.sqrt(s)
        logts = 2.0 * np.log(self.Ab / self.Aa)
        P = {}
        P["C"] = mu / (4.0 * r)
        P["t"] = 0.25 * (0.25 * lam / r - k * r / t)
        P["s"] = (-mu * C / s - mu - 0.25 * lam * t / s - 0.25 * lam + k * (2.0 - logts)) / (8.0 * r)
        P["Cs"] = -mu / (8.0 * r**3)
        P["tt"] = k * r / (4.0 * t**2)
        P["ts"] = -(0.25 * lam / s + k / t) / (8.0 * r)
        P["ss"] = (0.75 * mu * C / s + 0.25 * mu + 0.1875 * lam * t / s + 0.0625 * lam + 0.25 * k * logts) \
            / (4.0 * r**3)
        return P

    def grad(self, arg):
        """Gradient of the per-face energy with respect to the lengths of ``arg`` (0: La, 1: Lb), ``(F, 3)``."""
        P = self.partials()
        if arg == 1:
            gq = 2.0 * P["t"][:, None] * self.Mq + P["C"][:, None] * self.Mp
            return 2.0 * self.Lb * gq
        gp = 2.0 * P["s"][:, None] * self.Mp + P["C"][:, None] * self.Mq
        return 2.0 * self.La * gp

    def hess(self, arg):
        """Hessian blocks ``(F, 3, 3)`` in lengths: ``arg`` 0, 1 or ``(0, 1)`` (rows La, columns Lb)."""
        P = self.partials()
        Mp, Mq, La, Lb = self.Mp, self.Mq, self.La, self.Lb

        def outer(a, b):
            return a[:, :, None] * b[:, None, :]

        def col(x):
            return x[:, None, None]
        if arg == 1:
            Hqq = 4.0 * col(P["tt"]) * outer(Mq, Mq) + 2.0 * col(P["t"]) * _M
            gq = 2.0 * P["t"][:, None] * Mq + P["C"][:, None] * Mp
            H = 4.0 * outer(Lb, Lb) * Hqq
            H[:, [0, 1, 2], [0, 1, 2]] += 2.0 * gq
            return H
        if arg == 0:
            Hpp = (4.0 * col(P["ss"]) * outer(Mp, Mp) + 2.0 * col(P["Cs"]) * (outer(Mp, Mq) + outer(Mq, Mp))
                   + 2.0 * col(P["s"]) * _M)
            gp = 2.0 * P["s"][:, None] * Mp + P["C"][:, None] * Mq
            H = 4.0 * outer(La, La) * Hpp
            H[:, [0, 1, 2], [0, 1, 2]] += 2.0 * gp
            return H
        Hpq = 4.0 * col(P["ts"]) * outer(Mp, Mq) + 2.0 * col(P["Cs"]) * outer(Mp, Mp) + col(P["C"]) * _M
        return 4.0 * outer(La, Lb) * Hpq


class ThinShellsEnergy(DeformationEnergy):
    """Thin shells energy on lengths and angles, Definition 3.14.

    ``W_TS[z_a, z_b] = W_mem[z_a, z_b] + eta W_bend[z_a, z_b]``  (3.25), with
    ``z_a`` the undeformed and ``z_b`` the deformed configuration:

    * ``W_mem = sum_f a_f W_mem(G_f)``  (3.23), ``G_f`` from (3.22) and the trace
      formula before Def. 3.12, density (1.23) (see the module docstring);
    * ``W_bend = sum_{e interior} (theta_a - theta_b)_e^2 l_a,e^2 / d_a,e``  (3.24),
      ``d_e = (a_f + a_f') / 3``, lengths and areas of ``z_a``.

    ``value`` is ``+inf`` if a triangle of ``z_a`` or ``z_b`` violates the triangle
    inequality; ``gradient``/``hessian`` then raise LengthsAnglesError.

    Parameters
    ----------
    topology : MeshTopology
    bending_weight : float
        ``eta >= 0`` (squared shell thickness).
    mu, lam : float
        Positive material constants of the membrane density.
    """

    def __init__(self, topology, bending_weight=1e-3, mu=1.0, lam=1.0):
        super().__init__(topology)
        for name, v in (("mu", mu), ("lam", lam)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive material constant, got {v!r}")
        if not (np.isfinite(bending_weight) and bending_weight >= 0):
            raise ValueError(f"bending_weight must be finite and >= 0, got {bending_weight!r}")
        self.bending_weight = float(bending_weight)
        self.mu, self.lam = float(mu), float(lam)

    def _faces(self, z_a, z_b):
        fe = self.topology.face_edges
        E = self.n_edges
        return _MembraneFaces(z_a[:E][fe], z_b[:E][fe], self.mu, self.lam)

    # ---------------------------------------------------------------- values
    def distortion_invariants(self, z_a, z_b):
        """``tr G_f`` and ``det G_f`` of the distortion tensors ``G_f = g_a^{-1} g_b`` (3.22), each ``(F,)``.

        ``tr G = 2 p^T M q / p^T M p`` (formula before Def. 3.12), ``det G = (ã_f / a_f)^2``.
        """
        z_a, z_b = self._pair(z_a, z_b)
        return self._faces(z_a, z_b).trace_det()

    def membrane_energies(self, z_a, z_b):
        """Per-face membrane terms ``a_f W_mem(G_f)`` of (3.23), ``(F,)``; ``+inf`` on invalid faces."""
        z_a, z_b = self._pair(z_a, z_b)
        return self._faces(z_a, z_b).energies()

    def membrane_value(self, z_a, z_b):
        """``W_mem[z_a, z_b]`` (3.23); ``+inf`` for invalid triangles."""
        z_a, z_b = self._pair(z_a, z_b)
        return float(self._faces(z_a, z_b).energies().sum())

    def bending_value(self, z_a, z_b):
        """``W_bend[z_a, z_b]`` (3.24) (without ``eta``); ``+inf`` if ``z_a`` has invalid triangles."""
        z_a, z_b = self._pair(z_a, z_b)
        E = self.n_edges
        ie = self.topology.interior_edges
        d = edge_areas(z_a[:E], self.topology)[ie]
        if np.any(~(d > 0)):
            return np.inf
        delta = z_a[E + ie] - z_b[E + ie]
        return float(np.sum(delta**2 * z_a[ie] ** 2 / d))

    def value(self, z_a, z_b):
        """``W_TS[z_a, z_b]`` (3.25), a float (``+inf`` for invalid triangles)."""
        mem = self.membrane_value(z_a, z_b)
        if not np.isfinite(mem):
            return np.inf
        return mem + self.bending_weight * self.bending_value(z_a, z_b)

    # ---------------------------------------------------------------- bending terms
    def _bending_local(self, z_a, z_b, faces):
        """Bending terms of the interior edges as functions of 8 local slots.

        Slots ``(theta_a,e, l_a,e, L_a(f), L_a(f'))`` (``f, f'`` left/right face,
        ``L(f)`` the face's three edge lengths; ``l_e`` occurs three times, the
        chain rule sums the copies).  Returns slot z-indices ``(n, 8)``, gradient
        ``(n, 8)`` and Hessian ``(n, 8, 8)`` of ``eta (theta_a - theta_b)^2 l^2 / d``,
        ``d = (A_f + A_f') / 3``.
        """
        topo = self.topology
        E = self.n_edges
        ie = topo.interior_edges
        f, g = topo.edge_faces[ie, 0], topo.edge_faces[ie, 1]
        fe = topo.face_edges
        slots = np.column_stack([E + ie, ie, fe[f], fe[g]])
        eta = self.bending_weight
        delta = z_a[E + ie] - z_b[E + ie]
        lv = z_a[ie]
        d = (faces.Aa[f] + faces.Aa[g]) / 3.0
        gA = triangle_area_gradient(faces.La, faces.Aa)
        HA = _area_hessian(faces.La, faces.Aa)
        n = len(ie)
        Ju = np.zeros((n, 3, 8))
        Ju[:, 0, 0] = 1.0
        Ju[:, 1, 1] = 1.0
        Ju[:, 2, 2:5] = gA[f] / 3.0
        Ju[:, 2, 5:8] = gA[g] / 3.0
        bu = eta * np.column_stack([2.0 * delta * lv**2 / d, 2.0 * delta**2 * lv / d, -(delta * lv / d) ** 2])
        B = np.empty((n, 3, 3))
        B[:, 0, 0] = 2.0 * lv**2 / d
        B[:, 0, 1] = B[:, 1, 0] = 4.0 * delta * lv / d
        B[:, 0, 2] = B[:, 2, 0] = -2.0 * delta * lv**2 / d**2
        B[:, 1, 1] = 2.0 * delta**2 / d
        B[:, 1, 2] = B[:, 2, 1] = -2.0 * delta**2 * lv / d**2
        B[:, 2, 2] = 2.0 * delta**2 * lv**2 / d**3
        B *= eta
        grad = np.einsum("nij,ni->nj", Ju, bu)
        H = np.swapaxes(Ju, 1, 2) @ B @ Ju
        H[:, 2:5, 2:5] += (bu[:, 2] / 3.0)[:, None, None] * HA[f]
        H[:, 5:8, 5:8] += (bu[:, 2] / 3.0)[:, None, None] * HA[g]
        return slots, grad, H

    # ---------------------------------------------------------------- derivatives
    def gradient(self, z_a, z_b, argument=1):
        """Gradient of ``W_TS`` with respect to ``z_b`` (``argument=1``) or ``z_a`` (``0``), ``(2E,)``."""
        z_a, z_b = self._pair(z_a, z_b)
        arg = _parse_argument(argument)
        if isinstance(arg, tuple):
            raise ValueError("the gradient takes argument 0 or 1")
        topo = self.topology
        E = self.n_edges
        ie = topo.interior_edges
        faces = self._faces(z_a, z_b)
        faces.check()
        g = _scatter(topo.face_edges, faces.grad(arg), 2 * E)
        if arg == 1:
            d = (faces.Aa[topo.edge_faces[ie, 0]] + faces.Aa[topo.edge_faces[ie, 1]]) / 3.0
            g[E + ie] += -2.0 * self.bending_weight * (z_a[E + ie] - z_b[E + ie]) * z_a[ie] ** 2 / d
        else:
            slots, gb, _ = self._bending_local(z_a, z_b, faces)
            g += _scatter(slots, gb, 2 * E)
        return g

    def _hessian_blocks(self, z_a, z_b, arg, project):
        topo = self.topology
        E = self.n_edges
        ie = topo.interior_edges
        fe = topo.face_edges
        faces = self._faces(z_a, z_b)
        faces.check()
        Hm = faces.hess(arg)
        quads = _interior_quads(topo)
        if arg == 1:
            d = (faces.Aa[topo.edge_faces[ie, 0]] + faces.Aa[topo.edge_faces[ie, 1]]) / 3.0
            Hb = (2.0 * self.bending_weight * z_a[ie] ** 2 / d)[:, None, None]
            if project:
                Hm = _project_psd(Hm)
            zb = (E + ie)[:, None]
            return [_Blocks("ts.mem.11", fe, fe, Hm, topo.faces), _Blocks("ts.bend.11", zb, zb, Hb, quads)]
        slots, _, Hb = self._bending_local(z_a, z_b, faces)
        if arg == 0:
            if project:
                Hm, Hb = _project_psd(Hm), _project_psd(Hb)
            return [_Blocks("ts.mem.00", fe, fe, Hm, topo.faces), _Blocks("ts.bend.00", slots, slots, Hb, quads)]
        # mixed (0, 1): theta_b enters only through theta_a - theta_b
        return [_Blocks("ts.mem.01", fe, fe, Hm), _Blocks("ts.bend.01", slots, (E + ie)[:, None], -Hb[:, :, :1])]


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
    return topology._cached("energies:z_support", compute)


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
    return topology._cached("energies:gn_gather:" + block.key, compute)


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
    (:func:`~lacore.lengths_angles.lengths_and_angles_jacobian`), shape ``(3V,)``,
    entry ``3 v + c`` for coordinate ``c`` of vertex ``v``.

    Gauss-Newton Hessian: ``J^T H_z J`` dropping the curvature term
    ``sum_i dW/dz_i d^2 z_i / dX^2``.  ``H_z`` is a sum of per-element blocks
    (per face for the membrane, per interior edge for bending and ``W_q``);
    with ``project=True`` (default) every block's negative eigenvalues are
    clamped to 0 (``W_TS`` can have indefinite blocks away from ``z_a = z_b``),
    so the result is symmetric positive semi-definite.  The ``X``-blocks
    ``J_e^T H_e J_e`` are formed per element and summed with a cached sparsity
    pattern.
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
            raise ValueError(f"argument must be 0 or 1, got {argument!r}")
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
        """``r = sqrt(w) (Z[X] - z_fixed)``, ``(2E,)``, with ``W_q = r . r`` (QuadraticEnergy only)."""
        q = self._quadratic()
        return np.sqrt(q.residual_weights) * (self.z(X) - self.z_fixed)

    def residual_and_jacobian(self, X):
        """Residual ``r (2E,)`` and its Jacobian ``sqrt(w) J`` (``(2E, 3V)`` CSR, pattern of ``J``).

        The Gauss-Newton Hessian of ``W_q`` is ``2 (sqrt(w) J)^T (sqrt(w) J)``.
        """
        sw = np.sqrt(self._quadratic().residual_weights)
        J, z = lengths_and_angles_jacobian(self._X(X), self.topology, return_z=True)
        J.data *= np.repeat(sw, np.diff(J.indptr))
        return sw * (z - self.z_fixed), J
