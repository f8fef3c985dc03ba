"""The global integrability conditions of Theorem 3.2: holonomy and accumulated translation of the homology loops.

For every loop of :func:`~lacore.integrability.homology.homology_basis`:

* the **holonomy** is the product of the induced transition rotations (3.10)
  along the loop's corridor (its dual loop), as a rotation vector ``(3,)``
  (axis times angle, angle in ``[0, pi]``): zero iff the frames close around
  the loop (condition (ii));
* the **accumulated translation** (Definition 3.10) is the sum of the loop's
  edge vectors, each carried into the corridor's first frame by the transition
  rotations before it, divided by the loop's length (so it is scale-free: the
  gap relative to the loop length): zero iff the positions close around the
  loop (condition (iii)).

Together with the condition at every interior vertex
(:mod:`lacore.integrability.local`) and the triangle inequalities they are all
of Theorem 3.2: ``z`` is the lengths and angles of a mesh iff all are met.

Frames and factors
------------------
A corridor visits faces ``A_0, A_1, ...`` and crosses edge ``c_x`` from ``A_x``
to ``A_{x+1}`` (cyclically).  In face ``A_x`` the frame is the standard frame
turned so that its first axis runs along the edge it was entered by,
``c_{x-1}``, in that edge's stored orientation (``topology.edges``); its third
axis is the face normal.  Going on to ``A_{x+1}`` is the factor::

    q_x = Rz(beta_x) Rx(sigma_x theta_{c_x})

with ``beta_x`` the angle in ``A_x`` from ``c_{x-1}`` to ``c_x`` (a sum of
``+-pi`` and the face's interior angles, :func:`~lacore.integrability.local.edge_frame_angles`)
and ``sigma_x = +1`` when leaving the edge's left face (``F_right = F_left R``,
(3.10)).  The holonomy is ``q_0 q_1 ... q_{C-1}`` in the frame of ``A_0``.  Loop
edge ``i`` lies in the face reached after ``x(i)`` crossings; its edge vector
there is ``l_i (cos delta_i, sin delta_i, 0)`` with ``delta_i`` its angle to the
frame's first axis, and the accumulated translation is
``sum_i l_i R(q_0 ... q_{x(i)-1}) (cos delta_i, sin delta_i, 0) / sum_i l_i``.

Implementation
--------------
Rotations are unit quaternions as complex pairs ``alpha = w + i z``,
``beta = x + i y`` (as in :mod:`lacore.reconstruction.frame_based`); a factor is
``exp(i beta_x / 2) (cos(phi / 2), sin(phi / 2))`` with ``phi = sigma_x theta``.
The half-angle phasors ``exp(i gamma / 2)`` come from the edge lengths without
trigonometric calls (``cos(gamma_i / 2) = sqrt(p t_i / (4 l_j l_k))``,
``sin(gamma_i / 2) = sqrt(t_j t_k / (4 l_j l_k))``, ``t_i = l_j + l_k - l_i``
evaluated as ``(max(l_j, l_k) - l_i) + min(l_j, l_k)``, ``p`` the perimeter).
The prefix products of all loops are one scan: the factors of every loop are
laid out in rows of ``W`` entries (a power of two, identities as padding),
each row is scanned in place (Hillis-Steele for small layouts, Blelloch's
up- and down-sweep otherwise), then the rows of a loop are chained the same
way.  Every index array depends on the connectivity only and is cached on the
topology.

Jacobians: a factor's angle ``psi`` enters as a rotation about a world axis
``omega`` (``R(P) e_z`` for ``beta_x``, ``R(P Rz(beta_x)) e_x`` for ``phi``,
``P`` the product before the factor), so the holonomy moves by
``J_l^{-1}(h) omega`` (the inverse left Jacobian of SO(3) at the rotation
vector ``h``) and the translation by ``omega x S / L`` with ``S`` the sum of
the edge vectors placed after the factor.  The turn angles' derivatives by the
edge lengths are those of the interior angles (appendix A.1).  The triangle
inequality is handled as in :mod:`lacore.integrability.local`: a violating
triangle gets interior angles 0.
"""

import numpy as np
import scipy.sparse as sp

from ..geometry.lengths_angles import check_z, safe_scaled
from ..geometry.trigonometry import interior_angle_jacobian, interior_angles
from .homology import homology_basis
from .local import euler_integrability_jacobian, euler_integrability_map

__all__ = ["loop_holonomy", "loop_translation", "global_integrability_map", "global_integrability_jacobian",
           "admissibility_map", "admissibility_jacobian", "GLOBAL_SCAN_WIDTH"]

#: Entries per row of the scan layout (a power of two).
GLOBAL_SCAN_WIDTH = 128
#: Layouts of at most this many entries are scanned by Hillis-Steele (fewer, larger steps), larger ones by Blelloch.
_SMALL_SCAN = 1024

# direction angle of half-edge i in its face's standard frame: const + c0 gamma_0 + c1 gamma_1
# (edge_frame_angles: pi - gamma_1, pi + gamma_0, 0)
_PHI_CONST = np.array([np.pi, np.pi, 0.0])
_PHI_G0 = np.array([0, 1, 0])
_PHI_G1 = np.array([-1, 0, 0])


def _direction(topology, f, e, along):
    """Angle of edge ``e`` in face ``f``'s standard frame, traversed along its orientation where ``along``:
    ``(const, c0, c1)`` with ``angle = const + c0 gamma_0 + c1 gamma_1``."""
    i = np.argmax(topology.face_edges[f] == e[:, None], axis=1)
    same = topology.face_edge_is_left[f, i] == along
    return _PHI_CONST[i] + np.where(same, 0.0, np.pi), _PHI_G0[i], _PHI_G1[i]


def _turn(topology, f, e1, along1, e2, along2):
    """Angle in face ``f`` from edge ``e1`` to edge ``e2`` as ``(const mod 4 pi, c0, c1)``."""
    c1, a1, b1 = _direction(topology, f, e1, along1)
    c2, a2, b2 = _direction(topology, f, e2, along2)
    return np.mod(c2 - c1, 4.0 * np.pi), a2 - a1, b2 - b1


def _pow2(n):
    return 1 << max(0, int(n - 1).bit_length())


def _qmul(a1, b1, a2, b2):
    """Hamilton product of complex-pair quaternions ``(a1, b1) (a2, b2)``."""
    return a1 * a2 - b1 * np.conj(b2), a1 * b2 + b1 * np.conj(a2)


def _scan_rows(a, b):
    """In place: inclusive prefix products of complex-pair quaternions along axis 1 (width a power of two)."""
    W = a.shape[1]
    if a.size <= _SMALL_SCAN:
        d = 1
        while d < W:
            a[:, d:], b[:, d:] = _qmul(a[:, :-d], b[:, :-d], a[:, d:], b[:, d:])
            d *= 2
        return
    d = 1
    while d < W:                                              # up-sweep
        lft, rgt = slice(d - 1, None, 2 * d), slice(2 * d - 1, None, 2 * d)
        a[:, rgt], b[:, rgt] = _qmul(a[:, lft], b[:, lft], a[:, rgt], b[:, rgt])
        d *= 2
    d = W // 4
    while d >= 1:                                             # down-sweep
        lft, rgt = slice(2 * d - 1, W - d, 2 * d), slice(3 * d - 1, None, 2 * d)
        a[:, rgt], b[:, rgt] = _qmul(a[:, lft], b[:, lft], a[:, rgt], b[:, rgt])
        d //= 2


class _Tables:
    """Index arrays and turn coefficients of the corridors (z-independent, cached on the topology)."""

    def __init__(self, topology, basis):
        self.basis = basis
        self.n = n = basis.n_loops
        self.E = topology.n_edges
        if n == 0:
            return
        dptr = basis.dual_ptr
        C = np.diff(dptr)
        N = int(dptr[-1])
        xl = np.repeat(np.arange(n), C)
        x = np.arange(N)
        xloc = x - dptr[xl]
        prev = np.where(xloc > 0, x - 1, dptr[xl + 1] - 1)
        A, c = basis.dual_faces, basis.dual_edges
        true_x = np.ones(N, bool)
        const, c0, c1 = _turn(topology, A, c[prev], true_x, c, true_x)
        el = np.repeat(np.arange(n), np.diff(basis.ptr))
        before = basis.crossings_before
        entry = dptr[el] + np.mod(before - 1, C[el])
        econst, e0, e1 = _turn(topology, basis.edge_faces, c[entry], np.ones(len(el), bool), basis.edges,
                               basis.forward)
        # row layout of the scan
        W = min(GLOBAL_SCAN_WIDTH, _pow2(C.max()))
        rows = -(-C // W)
        row_start = np.r_[0, np.cumsum(rows)[:-1]]
        self.W, self.n_rows, self.C = W, int(rows.sum()), C
        self.slot = row_start[xl] * W + xloc
        self.last = row_start * W + C - 1
        self.Rpad = _pow2(int(rows.max()))
        rl = np.repeat(np.arange(n), rows)
        self.row_loop, self.row_pos = rl, np.arange(self.n_rows) - row_start[rl]
        self.later = np.flatnonzero(self.row_pos > 0)
        # gathers of exclusive prefixes from [identity, scanned layout]: 0 is the identity
        self.x_gather = np.where(xloc > 0, self.slot, 0)
        self.e_gather = np.where(before > 0, row_start[el] * W + before, 0)
        # faces whose angles enter: their edges, and per factor / edge the index of its phasor
        self.faces, inv = np.unique(np.r_[A, basis.edge_faces], return_inverse=True)
        nf = len(self.faces)
        self.face_edges = np.ascontiguousarray(topology.face_edges[self.faces].T)      # (3, nf)
        self.lengths5 = np.ascontiguousarray(self.face_edges[[0, 1, 2, 0, 1]])          # l0 l1 l2 l0 l1
        self.inv_x, self.inv_e = inv[:N], inv[N:]
        # phasor table (2 angles, [conj(h), 1, h], nf) flattened: angle a with coefficient c of face k
        self.ix0, self.ix1 = (1 + c0) * nf + self.inv_x, 3 * nf + (1 + c1) * nf + self.inv_x
        self.ie0, self.ie1 = (1 + e0) * nf + self.inv_e, 3 * nf + (1 + e1) * nf + self.inv_e
        self.kx, self.ke = np.exp(0.5j * const), np.exp(0.5j * econst)
        self.const, self.c0, self.c1 = const, c0.astype(float), c1.astype(float)
        self.econst, self.e0, self.e1 = econst, e0.astype(float), e1.astype(float)
        self.half_sign = 0.5 * basis.dual_sign
        self.edge, self.sign = c, basis.dual_sign
        self.xl, self.el, self.xloc, self.before = xl, el, xloc, before
        self.emit_starts = basis.ptr[:-1]
        for value in vars(self).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    # ------------------------------------------------------------------ evaluation
    def phasors(self, lengths):
        """The phasor table ``[conj(h), 1, h]`` of ``h = exp(i gamma_0 / 2)`` and of ``h = exp(i gamma_1 / 2)``
        per face, flat ``(2 * 3 * nf,)``, and the faces violating the triangle inequality (module docstring)."""
        L = lengths.take(self.lengths5)                       # rows l0 l1 l2 l0 l1
        t = np.maximum(L[1:4], L[2:5])                        # t_i = (max(l_j, l_k) - l_i) + min(l_j, l_k)
        t -= L[0:3]
        t += np.minimum(L[1:4], L[2:5])
        bad = ~((t[0] > 0) & (t[1] > 0) & (t[2] > 0))
        nf = L.shape[1]
        H = np.empty((2, 3, nf), complex)
        h = H[:, 2]
        with np.errstate(invalid="ignore"):
            r = 0.25 / (L[1:3] * L[2:4])                      # 1 / (4 l_j l_k) for i = 0, 1
            h.real = np.sqrt((L[0] + L[1] + L[2]) * t[0:2] * r)
            h.imag = np.sqrt(t[1:3] * t[np.array([2, 0])] * r)
        if bad.any():
            h[:, bad] = 1.0
        np.conj(h, out=H[:, 0])
        H[:, 1] = 1.0
        return H.ravel(), bad

    def prefixes(self, z):
        """Inclusive prefix products on the flat layout, preceded by the identity (index 0), and the phasors."""
        E, W = self.E, self.W
        H, bad = self.phasors(z[:E])
        ph = self.kx * H.take(self.ix0) * H.take(self.ix1)
        half = z[E:].take(self.edge) * self.half_sign
        A = np.ones(1 + self.n_rows * W, complex)
        B = np.zeros(1 + self.n_rows * W, complex)
        A[1 + self.slot] = ph * np.cos(half)
        B[1 + self.slot] = ph * np.sin(half)
        A2, B2 = A[1:].reshape(-1, W), B[1:].reshape(-1, W)
        _scan_rows(A2, B2)
        if self.Rpad > 1:
            TA = np.ones((self.n, self.Rpad), complex)
            TB = np.zeros((self.n, self.Rpad), complex)
            TA[self.row_loop, self.row_pos] = A2[:, -1]
            TB[self.row_loop, self.row_pos] = B2[:, -1]
            _scan_rows(TA, TB)
            lt = self.later
            pa = TA[self.row_loop[lt], self.row_pos[lt] - 1][:, None]
            pb = TB[self.row_loop[lt], self.row_pos[lt] - 1][:, None]
            A2[lt], B2[lt] = _qmul(pa, pb, A2[lt], B2[lt])
        return A, B, H, bad

    def _scaled(self, z):
        """``(z, k)``: the lengths scaled by ``2^-k`` into the safe range (both conditions are scale-invariant)."""
        lengths, k = safe_scaled(z[:self.E])
        return (np.concatenate([lengths, z[self.E:]]), k) if k else (z, 0)

    def evaluate(self, z):
        """``(holonomy (n, 3), translation (n, 3), loops touching a triangle-inequality violation (n,) bool)``."""
        n = self.n
        if n == 0:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool)
        z, _ = self._scaled(z)
        A, B, H, bad = self.prefixes(z)
        hol = _log(A.take(1 + self.last), B.take(1 + self.last))
        a, b = A.take(self.e_gather), B.take(self.e_gather)
        zeta = self.ke * H.take(self.ie0) * H.take(self.ie1)
        zeta *= zeta                                          # exp(i delta)
        le = z.take(self.basis.edges)
        zeta *= le
        g = a * zeta
        xy = a * g
        xy += b * b * np.conj(zeta)
        zc = (b * np.conj(g)).imag
        st = self.emit_starts
        sxy, sz, L = np.add.reduceat(xy, st), np.add.reduceat(zc, st), np.add.reduceat(le, st)
        tau = np.empty((n, 3))
        tau[:, 0], tau[:, 1], tau[:, 2] = sxy.real / L, sxy.imag / L, -2.0 * sz / L
        invalid = np.zeros(n, bool)
        if bad.any():
            invalid[self.xl[bad[self.inv_x]]] = True
            invalid[self.el[bad[self.inv_e]]] = True
        return hol, tau, invalid

    def jacobian(self, z):
        """``(J (6 n, 2E) CSR, value (6 n,))``, rows: the holonomies, then the translations (3 per loop)."""
        n, E = self.n, self.E
        if n == 0:
            return sp.csr_matrix((0, 2 * E)), np.zeros(0)
        z, k = self._scaled(z)  # length derivatives of the scaled problem scale by 2^-k
        hol, tau, _ = self.evaluate(z)
        A, B, _, _ = self.prefixes(z)
        L3 = z[:E].take(self.face_edges).T                    # (nf, 3)
        gamma = interior_angles(L3)
        Jg = interior_angle_jacobian(L3)                       # d gamma_a / d l_b
        xl, el = self.xl, self.el
        N = len(xl)
        beta = self.const + self.c0 * gamma[self.inv_x, 0] + self.c1 * gamma[self.inv_x, 1]
        xa, xb = A.take(self.x_gather), B.take(self.x_gather)
        om_b = _rotate_ez(xa, xb)                              # axis of beta_x
        om_p = _rotate_inplane(xa, xb, np.exp(1j * beta))      # axis of phi_x
        Ji = _jl_inv(hol)[xl]
        dh_b = np.einsum("nij,nj->ni", Ji, om_b)
        dh_p = np.einsum("nij,nj->ni", Ji, om_p)
        ea, eb = A.take(self.e_gather), B.take(self.e_gather)
        delta = self.econst + self.e0 * gamma[self.inv_e, 0] + self.e1 * gamma[self.inv_e, 1]
        u = _rotate_inplane(ea, eb, np.exp(1j * delta))        # unit edge directions in the first frame
        le = z[self.basis.edges]
        Lk = np.add.reduceat(le, self.emit_starts)
        # S_x: edge vectors placed after crossing x (emission slots 0 .. C per loop)
        off = self.basis.dual_ptr[:-1] + np.arange(n)
        G = np.zeros((N + n + 1, 3))
        np.add.at(G, off[el] + self.before, le[:, None] * u)
        rc = np.cumsum(G[::-1], axis=0)[::-1]
        S = rc[off[xl] + self.xloc + 1] - rc[off[xl] + self.C[xl] + 1]
        inv_L = 1.0 / Lk
        dt_b = np.cross(om_b, S) * inv_L[xl, None]
        dt_p = np.cross(om_p, S) * inv_L[xl, None]
        dt_d = np.cross(_rotate_ez(ea, eb), le[:, None] * u) * inv_L[el, None]
        direct = (u - tau[el]) * inv_L[el, None]
        db_dl = self.c0[:, None] * Jg[self.inv_x, 0] + self.c1[:, None] * Jg[self.inv_x, 1]
        dd_dl = self.e0[:, None] * Jg[self.inv_e, 0] + self.e1[:, None] * Jg[self.inv_e, 1]
        fe = self.face_edges.T
        cols_x, cols_e, theta_cols = fe[self.inv_x], fe[self.inv_e], E + self.edge
        rows, cols, vals = [], [], []

        def add(offset, loops, c, dv, chain):
            for r in range(3):
                if c.ndim == 1:
                    rows.append(offset + 3 * loops + r)
                    cols.append(c)
                    vals.append(dv[:, r] * chain)
                else:
                    rows.append(np.repeat(offset + 3 * loops + r, 3))
                    cols.append(c.ravel())
                    vals.append((dv[:, r, None] * chain).ravel())
        add(0, xl, cols_x, dh_b, db_dl)
        add(0, xl, theta_cols, dh_p, self.sign)
        add(3 * n, xl, cols_x, dt_b, db_dl)
        add(3 * n, xl, theta_cols, dt_p, self.sign)
        add(3 * n, el, cols_e, dt_d, dd_dl)
        add(3 * n, el, self.basis.edges, direct, np.ones(len(el)))
        cols, vals = np.concatenate(cols), np.concatenate(vals)
        if k:
            vals[cols < E] = np.ldexp(vals[cols < E], -k)
        J = sp.csr_matrix((vals, (np.concatenate(rows), cols)), shape=(6 * n, 2 * E))
        return J, np.concatenate([hol.ravel(), tau.ravel()])


def _rotate_inplane(a, b, zeta):
    """In-plane vectors ``zeta = x + i y`` rotated by complex-pair quaternions, ``(n, 3)``."""
    g = a * zeta
    xy = a * g + b * b * np.conj(zeta)
    return np.stack([xy.real, xy.imag, -2.0 * (b * np.conj(g)).imag], 1)


def _rotate_ez(a, b):
    """Third columns of the rotations of complex-pair quaternions, ``(n, 3)``."""
    w, zq, x, y = a.real, a.imag, b.real, b.imag
    return np.stack([2 * (x * zq + w * y), 2 * (y * zq - w * x), 1 - 2 * (x * x + y * y)], 1)


def _log(a, b):
    """Rotation vectors (angle in ``[0, pi]``) of complex-pair quaternions, ``(n, 3)``."""
    w = a.real
    v = np.stack([b.real, b.imag, a.imag], 1)
    s = np.sqrt(np.einsum("ij,ij->i", v, v))
    aw = np.abs(w)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(s < 1e-8, 2.0 / aw * (1.0 - s * s / (3.0 * aw * aw)), 2.0 * np.arctan2(s, aw) / s)
    return v * np.where(w < 0, -f, f)[:, None]


def _jl_inv(phi):
    """Inverse left Jacobians of SO(3) at rotation vectors ``phi`` ``(n, 3)``, ``(n, 3, 3)``."""
    th = np.linalg.norm(phi, axis=1)
    K = np.zeros((len(phi), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(th > 1e-4, 1.0 / th ** 2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th)),
                     1.0 / 12.0 + th ** 2 / 720.0)
    return np.eye(3) - 0.5 * K + c[:, None, None] * (K @ K)


def _tables(topology):
    return topology.cache.get((__name__, "tables"), lambda: _Tables(topology, homology_basis(topology)))


def _z(z, topology):
    z = np.asarray(z, dtype=np.float64)
    E = topology.n_edges
    if z.shape == (2 * E,) and np.isfinite(z).all() and (E == 0 or z[:E].min() > 0):
        return z
    return check_z(z, topology)


def loop_holonomy(z, topology):
    """Holonomy of every homology loop as a rotation vector, ``(n_loops, 3)``; zero for admissible ``z``.

    The product of the transition rotations (3.10) along the loop's corridor,
    in the frame of its first face (module docstring); its norm is the angle
    (radians, ``[0, pi]``) by which the frames fail to close around the loop.
    Like any chart of SO(3) it is smooth for angles below ``pi`` (its Jacobian
    uses the inverse left Jacobian of SO(3), singular at ``pi``).

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, loop_holonomy
    >>> from lacore.samples.surfaces import developed_cone
    >>> faces, z, deficit = developed_cone()       # a cone frustum's lengths on an annulus, all angles 0
    >>> angle = np.linalg.norm(loop_holonomy(z, MeshTopology.from_faces(faces)), axis=1)
    >>> print(np.round(angle, 4), round(deficit, 4))   # the frames turn by the cone's angle deficit
    [1.8403] 1.8403
    """
    return _tables(topology).evaluate(_z(z, topology))[0]


def loop_translation(z, topology):
    """Accumulated translation (Definition 3.10) of every homology loop over its length, ``(n_loops, 3)``.

    Scale-free: the norm is the gap by which the positions fail to close
    around the loop, relative to the loop's length; zero for admissible ``z``.
    Expressed in the frame of the loop's corridor's first face.

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology, loop_translation
    >>> from lacore.samples.surfaces import flat_torus
    >>> faces, z = flat_torus()       # a flat parallelogram's lengths on a torus: frames close, positions do not
    >>> print(np.round(np.linalg.norm(loop_translation(z, MeshTopology.from_faces(faces)), axis=1), 3))
    [0.893 0.728]
    """
    return _tables(topology).evaluate(_z(z, topology))[1]


def global_integrability_map(z, topology):
    """The global conditions as one vector, ``(6 n_loops,)``: all holonomies, then all translations (3 per loop).

    Zero for admissible ``z``; rows as :func:`global_integrability_jacobian`.
    """
    hol, tau, _ = _tables(topology).evaluate(_z(z, topology))
    return np.concatenate([hol.ravel(), tau.ravel()])


def global_integrability_jacobian(z, topology, return_value=False):
    """Analytic Jacobian of :func:`global_integrability_map`, ``(6 n_loops, 2E)`` CSR.

    Row ``3 k + j`` is component ``j`` of loop ``k``'s holonomy, row
    ``3 n + 3 k + j`` that of its translation (module docstring for the derivation).

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    return_value : bool
        Also return the map's value.
    """
    J, value = _tables(topology).jacobian(_z(z, topology))
    return (J, value) if return_value else J


def admissibility_map(z, topology):
    """All integrability conditions of Theorem 3.2 as one vector, ``(3 V_int + 6 n_loops,)``.

    The Euler integrability map (3.13) of every interior vertex, then
    :func:`global_integrability_map` (holonomy and scale-free translation of
    every homology loop).  Zero exactly for admissible ``z`` (with the triangle
    inequalities, which are not equalities).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.integrability import admissibility_map
    >>> from lacore.samples.surfaces import flat_torus
    >>> faces, z = flat_torus()      # closes at every vertex, not around the handles
    >>> topo = MeshTopology.from_faces(faces)
    >>> c = admissibility_map(z, topo)
    >>> bool(np.abs(c[:3 * len(topo.interior_vertices)]).max() < 1e-12), bool(np.abs(c).max() > 0.1)
    (True, True)
    """
    return np.concatenate([euler_integrability_map(z, topology), global_integrability_map(z, topology)])


def admissibility_jacobian(z, topology, return_value=False):
    """Analytic Jacobian of :func:`admissibility_map`, ``(3 V_int + 6 n_loops, 2E)`` CSR.

    The Euler Jacobian (:func:`~lacore.integrability.local.euler_integrability_jacobian`)
    stacked on :func:`global_integrability_jacobian`; the tangent space of the
    admissible set (4.4) on a mesh of any genus is its kernel.

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    return_value : bool
        Also return the map's value.
    """
    J, value = euler_integrability_jacobian(z, topology, return_value=True)
    if homology_basis(topology).n_loops:
        Jg, vg = global_integrability_jacobian(z, topology, return_value=True)
        J, value = sp.vstack([J, Jg], format="csr"), np.concatenate([value, vg])
    else:
        J = J.tocsr()
    return (J, value) if return_value else J
