"""The thin-shells energy W_TS on lengths and angles (thesis Definitions 3.12-3.14, (3.23)-(3.25))."""

import numpy as np

from ..errors import InputError, LengthsAnglesError, format_indices
from ..geometry.lengths_angles import wrap_angle
from ..geometry.trigonometry import triangle_area_gradient, triangle_areas, triangle_inequality_margin
from ._common import (DEFAULT_BENDING_WEIGHT, DeformationEnergy, _Blocks, _interior_quads, _parse_argument,
                      _project_psd, _scatter, edge_areas)

__all__ = ["ThinShellsEnergy", "membrane_density"]


_M = np.ones((3, 3)) - 2.0 * np.eye(3)  # p^T M p = 16 area^2 (Heron in squared lengths)


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
        ``eta >= 0`` (squared shell thickness; default :data:`~lacore.energies.DEFAULT_BENDING_WEIGHT`).
    mu, lam : float
        Positive material constants of the membrane density.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import ThinShellsEnergy
    >>> W = ThinShellsEnergy(topo)
    >>> za, zb = lengths_and_angles(X, topo), lengths_and_angles(bar_pose(X, 0.5, 0.0), topo)
    >>> W.value(za, za), round(W.value(za, zb), 6)
    (0.0, 0.086207)
    >>> stretched = za.copy(); stretched[:topo.n_edges] *= 1.01
    >>> round(W.membrane_value(za, stretched), 6)
    0.0104
    """

    def __init__(self, topology, bending_weight=DEFAULT_BENDING_WEIGHT, mu=1.0, lam=1.0):
        super().__init__(topology)
        for name, v in (("mu", mu), ("lam", lam)):
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive material constant, got {v!r}")
        if not (np.isfinite(bending_weight) and bending_weight >= 0):
            raise InputError(f"bending_weight must be finite and >= 0, got {bending_weight!r}")
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
        delta = wrap_angle(z_a[E + ie] - z_b[E + ie])  # on the circle
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
        delta = wrap_angle(z_a[E + ie] - z_b[E + ie])  # on the circle
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
            raise InputError("the gradient takes argument 0 or 1")
        topo = self.topology
        E = self.n_edges
        ie = topo.interior_edges
        faces = self._faces(z_a, z_b)
        faces.check()
        g = _scatter(topo.face_edges, faces.grad(arg), 2 * E)
        if arg == 1:
            d = (faces.Aa[topo.edge_faces[ie, 0]] + faces.Aa[topo.edge_faces[ie, 1]]) / 3.0
            g[E + ie] += -2.0 * self.bending_weight * wrap_angle(z_a[E + ie] - z_b[E + ie]) * z_a[ie] ** 2 / d
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
