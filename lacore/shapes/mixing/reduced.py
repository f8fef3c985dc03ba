"""The reduced energy of the shape mixer: ``W_q`` (3.19) on a subspace, summed over a weighted subset of edges.

Vertices are ``X(q) = x0 + U q`` in the canonical coordinates of a
:class:`~lacore.reconstruction.ReconstructionContext` (the fixed face in the 3-2-1 position, so
rigid motions are gone from the problem; ``U`` is ``(3V, r)``, orthonormal, zero on the fixed
coordinates).  Every edge ``e`` contributes its length and dihedral-angle residuals through its
*stencil*, the edge's two vertices and the two opposite ones.  The energy of the weights ``w``::

    E(q; w) = sum_{e in S} c_e ( wl_e (l_e(q) - l*_e(w))^2 + wt_e (theta_e(q) - theta*_e(w))^2 )

with ``l*(w) = max(l0 + w @ dl, floor)`` and ``theta*(w) = theta0 + w @ dtheta`` (the blend of
:func:`~lacore.shapes.mixing.mixer.blend_targets`), residual weights of ``W_q``, and cubature
weights ``c_e`` on a subset ``S`` of the edges (all edges with ``c = 1``: the exact reduced energy;
a sparse subset: a cost independent of the mesh size).  Gradient and Gauss-Newton matrix are
analytic (the element gradients of :func:`element_eval`).
"""

import numpy as np

from ...geometry.lengths_angles import cross_rows as _cross
from ...geometry.lengths_angles import wrap_angle

__all__ = ["edge_stencils", "element_eval", "ReducedEnergy"]


def edge_stencils(topology):
    """``(E, 4)`` vertices per edge: its ends ``x0, x1`` and the opposite vertices ``x2`` (left), ``x3`` (right).

    A boundary edge repeats its one opposite vertex (its angle has weight 0).
    """
    opp = topology.edge_opposite_vertices
    x3 = np.where(opp[:, 1] >= 0, opp[:, 1], opp[:, 0])
    return np.stack([topology.edges[:, 0], topology.edges[:, 1], opp[:, 0], x3], 1)


def element_eval(P, gradients=True):
    """Length and dihedral angle of stencils, and their gradients.

    Parameters
    ----------
    P : (12, n) ndarray
        Stencil coordinates: rows ``x0.xyz, x1.xyz, x2.xyz, x3.xyz``.
    gradients : bool

    Returns
    -------
    l, theta : (n,) ndarrays
        Edge length and dihedral angle (the conventions of :func:`lacore.lengths_and_angles`).
    gl : (6, n) ndarray or None
        ``dl / d(x0, x1)``.
    gt : (12, n) ndarray or None
        ``dtheta / d(x0, x1, x2, x3)``.
    """
    x0, x1, x2, x3 = P[0:3], P[3:6], P[6:9], P[9:12]
    e = x1 - x0
    a = x2 - x0
    b = x3 - x0
    n0 = _cross(e, a)
    n1 = _cross(b, e)
    l = np.sqrt((e * e).sum(0))
    theta = np.arctan2(-l * (n0 * b).sum(0), (n0 * n1).sum(0))
    if not gradients:
        return l, theta, None, None
    u = e / l
    gl = np.concatenate([-u, u])
    g2 = -l * n0 / (n0 * n0).sum(0)
    g3 = -l * n1 / (n1 * n1).sum(0)
    il2 = 1.0 / (l * l)
    t2 = (a * e).sum(0) * il2
    t3 = (b * e).sum(0) * il2
    g1 = -t2 * g2 - t3 * g3
    g0 = (t2 - 1.0) * g2 + (t3 - 1.0) * g3
    return l, theta, gl, np.concatenate([g0, g1, g2, g3])


class ReducedEnergy:
    """``E(q; w)`` of the module docstring on the edges ``edges`` with cubature weights ``c``.

    Parameters
    ----------
    stencils : (E, 4) int ndarray
        :func:`edge_stencils` of the whole mesh.
    x0 : (3V,) ndarray
        Origin of the subspace (canonical coordinates).
    U : (3V, r) ndarray
        Basis of the subspace.
    residual_weights : (2E,) ndarray
        Weights of ``W_q`` (0 for the angles of boundary edges).
    z0 : (2E,) ndarray
        Lengths and angles of the basis key.
    dz : (m, 2E) ndarray
        ``z_k - z_0`` of the other keys (angles wrapped).
    floor : (E,) ndarray
        Lowest target length per edge.
    edges : (n,) int ndarray, optional
        The edges summed (default all).
    c : (n,) ndarray, optional
        Their cubature weights (default 1).
    """

    def __init__(self, stencils, x0, U, residual_weights, z0, dz, floor, edges=None, c=None):
        E = len(stencils)
        edges = np.arange(E) if edges is None else np.asarray(edges, np.int64)
        self.edges = edges
        self.c = np.ones(len(edges)) if c is None else np.asarray(c, float)
        cols = (3 * stencils[edges][:, :, None] + np.arange(3)).reshape(len(edges), 12)
        self._cols, self._x0 = cols, x0
        self._USn = np.ascontiguousarray(U[cols])                          # (n, 12, r)
        self._xb = self._US = None
        self.wl = residual_weights[edges] * self.c
        self.wt = residual_weights[E + edges] * self.c
        self._w2 = np.stack([self.wl, self.wt], 1).ravel()               # (2n,): wl, wt interleaved
        self._sqrt_w = np.sqrt(self._w2)
        self.l0, self.t0 = z0[edges], z0[E + edges]
        self.dl, self.dt = dz[:, edges], dz[:, E + edges]
        self.floor = floor[edges]
        self.r = U.shape[1]
        # many edges (more stencil coordinates than vertex coordinates): a stencil is gathered from the vertices
        # x0 + U q, which reads U once instead of its (12, n, r) copy per edge
        self._gather = (x0, U, np.ascontiguousarray(cols.T)) if 12 * len(edges) >= 2 * len(x0) else None

    @property
    def xb(self):
        """``(12, n)`` stencil coordinates of ``x0`` (made on first use)."""
        if self._xb is None:
            self._xb = np.ascontiguousarray(self._x0[self._cols].T)
        return self._xb

    @property
    def US(self):
        """``(12, n, r)`` rows of ``U`` of the stencil coordinates (made on first use)."""
        if self._US is None:
            self._US = np.ascontiguousarray(self._USn.transpose(1, 0, 2))
        return self._US

    def stencil(self, q):
        if self._gather is not None:
            x0, U, cols = self._gather
            return (x0 + U @ q)[cols]
        return self.xb + self.US @ q

    def targets(self, w):
        """Target lengths and angles ``(n,), (n,)`` of the edges for the weights ``w``."""
        return np.maximum(self.l0 + w @ self.dl, self.floor), self.t0 + w @ self.dt

    def _residuals(self, q, w, gradients):
        l, th, gl, gt = element_eval(self.stencil(q), gradients)
        lt, tt = self.targets(w)
        return l - lt, wrap_angle(th - tt), gl, gt

    def energy(self, q, w, shift=None):
        """``E(q; w)``, plus ``2 shift . q`` when a gradient correction ``shift`` ``(r,)`` is given."""
        rl, rt, _, _ = self._residuals(q, w, False)
        e = float(self.wl @ (rl * rl) + self.wt @ (rt * rt))
        return e if shift is None else e + 2.0 * float(shift @ q)

    def linearize(self, q, w, shift=None):
        """``E``, gradient ``(r,)`` and Gauss-Newton matrix ``(r, r)`` at ``q`` (with ``2 shift . q``, see
        :meth:`energy`)."""
        rl, rt, gl, gt = self._residuals(q, w, True)
        n = len(rl)
        g = np.zeros((n, 2, 12))                                          # per edge: dl/dstencil (6), dtheta/dstencil
        g[:, 0, :6] = gl.T
        g[:, 1] = gt.T
        G = np.matmul(g, self._USn).reshape(2 * n, -1)                    # (2n, r): dl/dq, dtheta/dq interleaved
        A = self._sqrt_w[:, None] * G
        energy = float(self.wl @ (rl * rl) + self.wt @ (rt * rt))
        grad = 2.0 * (G.T @ (self._w2 * np.stack([rl, rt], 1).ravel()))
        H = 2.0 * (A.T @ A)
        if shift is not None:
            energy += 2.0 * float(shift @ q)
            grad = grad + 2.0 * shift
        return energy, grad, H

    def solve(self, w, q0, max_iterations=50, step_tol=0.0, ftol=1e-12, shift=None):
        """Minimize ``E(.; w)`` from ``q0`` by Gauss-Newton with a short backtracking line search, then
        Levenberg-Marquardt damping when that fails.

        Stops when a step is shorter than ``step_tol`` (Euclidean norm of ``q``, the norm of the
        vertex displacement), the predicted decrease is below ``ftol`` times the energy, or after
        ``max_iterations``.  ``shift``: a gradient correction (see :meth:`energy`).  Returns
        ``(q, energy, iterations)`` (the energy without the correction's term).
        """
        q = np.array(q0, float)
        energy, g, H = self.linearize(q, w, shift)
        lam = 0.0
        its = 0
        dH = np.diag(H).copy()
        scale = max(float(dH.max()), 1e-300)
        while its < max_iterations:
            its += 1
            try:
                A = H + lam * np.diag(np.maximum(dH, 1e-12 * scale))
                L = np.linalg.cholesky(A)
                d = -np.linalg.solve(L.T, np.linalg.solve(L, g))
            except np.linalg.LinAlgError:
                lam = max(10.0 * lam, 1e-8)
                continue
            slope = float(g @ d)
            if -slope <= ftol * energy or not np.isfinite(slope):
                break
            t = 1.0
            small = float(np.linalg.norm(d)) <= step_tol
            # a full step is usually taken: linearize there at once (its energy decides), unless it is the last
            full = None if small else self.linearize(q + d, w, shift)
            trial = self.energy(q + d, w, shift) if full is None else full[0]
            while trial > energy + 1e-4 * t * slope and t > 0.1:  # backtrack a little before damping
                t *= 0.5
                full = None
                trial = self.energy(q + t * d, w, shift)
            if trial <= energy + 1e-4 * t * slope:
                d = t * d
                q = q + d
                lam = 0.0 if lam < 1e-6 else 0.25 * lam
                if small:
                    energy = trial
                    break
                energy, g, H = full if full is not None else self.linearize(q, w, shift)
                dH = np.diag(H).copy()
            else:
                lam = max(10.0 * lam, 1e-6)
                if lam > 1e10:
                    break
        return q, (energy if shift is None else energy - 2.0 * float(shift @ q)), its

    def gradient_pieces(self, q):
        """Per-edge pieces of the gradient, affine in ``w``: ``(m+1, r, n)``.

        Piece 0 is the gradient at ``w = 0`` and piece ``k`` minus the derivative by ``w_k``
        (ignoring the floor of the lengths): the gradient at ``q`` for ``w`` is
        ``2 (piece_0 - sum_k w_k piece_k) @ c`` summed over the edges.
        """
        l, th, gl, gt = element_eval(self.stencil(q))
        Gl = np.einsum("in,inr->rn", gl, self.US[:6])
        Gt = np.einsum("in,inr->rn", gt, self.US)
        out = [self.wl * (l - self.l0) * Gl + self.wt * wrap_angle(th - self.t0) * Gt]
        for k in range(self.dl.shape[0]):
            out.append(self.wl * self.dl[k] * Gl + self.wt * self.dt[k] * Gt)
        return np.array(out)
