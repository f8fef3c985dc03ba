"""The mixer's reduced space: keys, derivatives of the projection and Krylov (chord) vectors.

All in the canonical coordinates of the reconstruction context (:mod:`lacore.reconstruction.context`):
the fixed face sits in the 3-2-1 position, so the rigid motions, to which lengths and angles are
blind, are not in the problem, and every vector below vanishes on the fixed coordinates.

* **Keys.** ``X_k - X_0``: the mix at ``w = e_k`` is key ``k`` (its lengths and angles are
  admissible, so their projection is the key itself).
* **First derivatives** of the projection ``X(w)`` at every key: the minimizer of
  ``W_q[z(w), Z(X)]`` moves by ``dX/dw_j = H^{-1} 2 J^T W dz_j`` (implicit function theorem on the
  gradient ``2 J^T W (Z(X) - z(w))``; at a key the residual vanishes and the Gauss-Newton matrix
  ``H = 2 J^T W J`` is the Hessian).  They matter at every key: with them at the basis only, the
  largest error on the box bar grew from 0.05 % to 0.15 % in ``[0, 1]^2`` and from 0.39 % to 1.5 %
  in ``[-0.5, 1.5]^2``.
* **Second derivatives** along ``e_a`` and ``e_a + e_b``: ``X'' = -H^{-1} c`` with ``c`` the second
  derivative of the gradient along the path ``(X + t X', w + t v)`` (a central difference of
  analytic gradients).  Keys with first and second derivatives give Taylor predictions of the mix.
* **Newton vectors** (:func:`newton_vectors`): at candidate weights away from the keys
  (:func:`candidate_weights`: all ones, the centre, pairs of keys, the corners of the accurate box,
  a few more in ``[0, 1]^m``) the minimizer in the current space is found (Gauss-Newton with the full
  Jacobian), and one full Gauss-Newton step from it (a fresh factorization) joins the space: the part
  of the projection the space misses, to first order; not where the step would gain next to nothing.
  The candidates are taken in turn, the farthest from the centre of ``[0, 1]^(K-1)`` first, each in the
  space the ones before it enlarged.  On the box bar (4.6k
  vertices, K = 3) this brings the largest RMS error in ``[-0.5, 1.5]^2`` from 1.9 % to 0.44 % of the
  diagonal with one factorization per candidate (all candidates in one space: 0.98 %; two such
  rounds, the second at half of the candidates: 0.37 %, with half as many factorizations more).
  The factorization of each Newton vector also gives, for ``K-1`` more right-hand sides, the first
  derivatives of the projection by the weights there (the formula at the keys, at the reduced
  minimizer): the space then follows the projection between the candidates to first order.  The
  space's energy gap (the full energy of the exact minimizer in the space over that of converged
  Gauss-Newton) is what keeps a mix's energy above Gauss-Newton's, far more than the cubature or the
  reduced solver; on the 5k bar these derivatives bring its median in ``[0, 1]^2`` from ~1.5 to ~1.04.
  Where a space with derivatives at every point would be too large (``K >= 4``), they are taken at a few
  points only: new weights of the half grid (:func:`exploration_weights`) where :func:`space_indicator`
  finds the space worst after the first round (``derivatives`` of :func:`newton_vectors` per start).
* **Chord vectors** (optional, ``chord_steps``): steps ``d = -H_k^{-1} g`` from the best Taylor
  prediction with the Hessian of a key (no new factorization).  They did not improve the space on the
  bar (the keys' Hessians precondition the soft bending modes far from the keys badly) and are off by
  default.

The keys' vectors, each scaled to unit length, are orthonormalized by an SVD, which drops the
numerically dependent ones; the Newton vectors extend those columns one start at a time
(:func:`newton_vectors` returns the grown basis), and only a ``reduced_size`` below their number
takes an SVD of all vectors again (:func:`orthonormal_basis`).
"""

import contextlib
import itertools

import numpy as np
import scipy.sparse as sp

from ...geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian, wrap_angle
from ...linalg.sparse_cholesky import NotPositiveDefiniteError
from ...progress import report
from ...reconstruction.objectives import QuadraticGNMatrix
from ...reconstruction.pcg import preconditioned_cg

__all__ = ["FullProblem", "build_space", "candidate_weights", "exploration_weights", "space_indicator", "relative_rms"]

#: Up to this many non-basis keys every corner of the accurate box is a Newton candidate (8 for ``K = 4``); with more
#: the corners would be ``2^(K-1)`` factorizations, and only the two diagonal corners and each key alone at either
#: end are (:func:`candidate_weights`).  On the CC0 body (13k vertices) with 6 pose keys all 64 corners made a build
#: of 138 s, 6.4 GB and 26 ms per mix (reduced size 144), the 14 of now 47 s, 2.4 GB and 14 ms (94), with mixes within
#: 0.03 % of the diagonal of the polished projection in ``[0, 1]^6`` and 0.8 % outside; with 4 keys all 16 corners
#: against these 10 (``benchmarks/bench_mixer_keys.py``, ``human13k_k5``): build 15.4 against 11.7 s CPU, 7.5
#: against 5.3 ms per mix, largest RMS 0.063 against 0.038 % of the diagonal in ``[0, 1]^4`` and 0.74 against 0.78 %
#: outside, 2 against 1 of 10 weights within 2 % of the energy.
FULL_CORNERS = 3

#: Half grids ``{0, 1/2, 1}^m`` up to this many points are listed whole by :func:`exploration_weights`; larger ones
#: are drawn from point by point.
GRID_ENUMERATION = 3 ** 8


class FullProblem:
    """``W_q[z(w), Z(X)]`` on canonical coordinates ``(3V,)`` in the context's units, with its derivatives."""

    def __init__(self, context, z_keys, dz, floor, weights):
        self.ctx = context
        self.topology = context.topology
        self.E = self.topology.n_edges
        self.z0 = z_keys[0]
        self.dz = dz
        self.floor = floor
        self.w = weights
        self.weighted_dz = weights[:, None] * dz.T               # (2E, m): W dz^T
        self.fixed = context.fixed_dofs

    def target(self, wk):
        z = self.z0 + np.asarray(wk, float) @ self.dz
        z[:self.E] = np.maximum(z[:self.E], self.floor)
        return z

    def _residual(self, z, wk):
        r = z - self.target(wk)
        r[self.E:] = wrap_angle(r[self.E:])
        return r

    def energy(self, x, wk):
        return self.energy_z(lengths_and_angles(x.reshape(-1, 3), self.topology, check=False), wk)

    def energy_z(self, z, wk):
        """The energy from the lengths and angles ``z = Z(x)`` ``(2E,)``."""
        r = self._residual(z, wk)
        return float(np.dot(self.w * r, r))

    def linearize(self, x):
        """The Jacobian ``J`` (CSR ``(2E, 3V)``) and ``z = Z(x)``, from the same intermediates."""
        return lengths_and_angles_jacobian(x.reshape(-1, 3), self.topology, return_z=True)

    def training_terms(self, J, z):
        """What the cubature's training (``ShapeMixer._training``) needs of the full problem at a point with
        Jacobian ``J`` and ``z = Z(x)``: ``J^T C`` ``(3V, m+1)`` with ``C = W [r_0, dz^T]`` (``r_0 = z - z_0``,
        angles wrapped: the gradient pieces of every edge, summed), the row norms of ``J`` ``(2E,)`` and the first
        column ``W r_0`` of ``C`` (the others, :attr:`weighted_dz`, are the same at every point)."""
        r0 = z - self.z0
        r0[self.E:] = wrap_angle(r0[self.E:])
        C = np.empty((len(r0), 1 + len(self.dz)))
        np.multiply(self.w, r0, out=C[:, 0])
        C[:, 1:] = self.weighted_dz
        rown = np.zeros(J.shape[0])
        rows = np.diff(J.indptr) > 0          # (the angles of boundary edges have empty rows, the last ones too)
        if rows.any():
            rown[rows] = np.sqrt(np.add.reduceat(J.data ** 2, J.indptr[:-1][rows]))
        return J.T @ C, rown, C[:, 0].copy()

    def gradient(self, x, wk):
        return self.energy_and_gradient(x, wk)[1]

    def energy_and_gradient(self, x, wk):
        """``(W_q, g)`` at ``x`` from one linearization; ``g = 2 J^T W r`` with the fixed coordinates 0."""
        J, z = self.linearize(x)
        r = self._residual(z, wk)
        g = 2.0 * (J.T @ (self.w * r))
        g[self.fixed] = 0.0
        return float(np.dot(self.w * r, r)), g

    def factorize(self, x, wk, linearized=None):
        """Factorize the Gauss-Newton matrix at ``x`` in the context's solver; returns the Jacobian.

        ``linearized``: ``(J, z)`` at ``x`` (:meth:`linearize`) when the caller has them (no second
        evaluation of the Jacobian); the matrix values are the same.
        """
        obj = self.ctx.objective(self._external_target(wk))
        if linearized is None:
            _, _, mat = obj.linearize(x.reshape(-1, 3))
        else:
            mat = QuadraticGNMatrix(obj, linearized[0], linearized[1], x.reshape(-1, 3))
        vals = self.ctx.eliminate_fixed(mat(second_order=False))
        try:
            self.ctx.solver.factorize(vals, regularize=False)
        except NotPositiveDefiniteError:
            self.ctx.solver.factorize(vals, regularize=True)
        return mat.J

    def _external_target(self, wk):
        z = self.target(wk).copy()
        k = self.ctx.scale_exponent
        if k:
            z[:self.E] = np.ldexp(z[:self.E], k)
        return z

    def solve(self, b):
        b = np.array(b, float)
        b[self.fixed] = 0.0
        x = self.ctx.solver.solve(b)
        x[self.fixed] = 0.0
        return x

    def first_derivatives(self, J):
        """``dX/dw_j`` ``(m, 3V)`` with the current factorization (of the Hessian at a key)."""
        B = 2.0 * (J.T @ (self.w[:, None] * self.dz.T))          # (3V, m)
        B[self.fixed] = 0.0
        X = self.ctx.solver.solve(B)
        X[self.fixed] = 0.0
        return np.asarray(X).T.reshape(len(self.dz), -1)

    def newton_step(self, J, x, wk, derivatives=False, z=None):
        """The Gauss-Newton step ``-H^{-1} g`` at ``x`` and, with ``derivatives``, the first derivatives
        ``H^{-1} 2 J^T W dz_j`` of the projection there: one solve with ``m + 1`` right-hand sides (the current
        factorization, of ``H`` at ``x``; ``J`` the Jacobian at ``x``, ``z = Z(x)`` when known).  A list of 1 or
        ``m + 1`` arrays ``(3V,)``."""
        if z is None:
            z = lengths_and_angles(x.reshape(-1, 3), self.topology, check=False)
        r = self._residual(z, wk)
        C = self.w[:, None] * np.column_stack([-r] + ([self.dz.T] if derivatives else []))   # (2E, 1 or m+1)
        B = 2.0 * (J.T @ C)
        B[self.fixed] = 0.0
        X = np.asarray(self.ctx.solver.solve(B))
        X[self.fixed] = 0.0
        return list(X.T)

    def second_derivative(self, x, wk, a, v, size):
        """``X''`` along ``(x + t a, w + t v)`` through a key: ``-H^{-1} c``, ``c`` the second difference of the
        gradient."""
        h = 1e-3 * size / max(float(np.abs(a).max()), 1e-300)
        gp = self.gradient(x + h * a, wk + h * v)
        gm = self.gradient(x - h * a, wk - h * v)
        g0 = self.gradient(x, wk)
        return self.solve(-(gp + gm - 2.0 * g0) / (h * h))


def _no_stage(name):
    return contextlib.nullcontext()


def candidate_weights(m, low, high):
    """Weights of the Newton (and chord) vectors: all ones, all halves, pairs ``e_a + e_b`` (``m > 2``), the box
    corners, and inside ``[0, 1]^m`` for ``m = 2`` the midpoints ``(1, 1/2)``, ``(1/2, 1)`` of the unit square's
    far edges, for ``m > 2`` the halves ``e_a / 2`` of the keys' own paths (keys and duplicates left out).

    The corners are all ``2^m`` of them up to :data:`FULL_CORNERS` keys; beyond, ``2 m + 2``: all ``low``, all
    ``high`` and each key alone at ``low`` and at ``high``, so that the count grows as ``m^2 / 2`` (the pairs):
    ``m = 6`` gives 37 candidates, not 87.

    The ones inside ``[0, 1]^m`` were chosen by the energy of the exact minimizer in the final space over that
    of converged Gauss-Newton (median at ``benchmarks/bench_mixer.py``'s weights in ``[0, 1]^m``).  On the CC0
    body (13k, K = 4) the halves took it from 1.21 to 1.04 (3 factorizations, 3 columns more); the six facet
    centres of ``[0, 1]^3`` instead, 1.05; the halves and the six ``e_a + e_b / 2`` together, 1.035 for a
    build of 5 s.  On the 5k bar (K = 3, with a second round of Newton vectors) the halves
    ``(1/2, 0)``, ``(0, 1/2)`` as well brought the median ``energy_goal`` from 0.45 to 0.21 (before the
    cubature's gradient rows), for two factorizations more than the 50k bar's 30 s allow.

    Examples
    --------
    >>> [w.tolist() for w in candidate_weights(2, -0.5, 1.5)]
    [[1.0, 1.0], [0.5, 0.5], [-0.5, -0.5], [-0.5, 1.5], [1.5, -0.5], [1.5, 1.5], [1.0, 0.5], [0.5, 1.0]]
    >>> len(candidate_weights(3, -0.5, 1.5)), len(candidate_weights(6, -0.5, 1.5))
    (16, 37)
    """
    out = [np.ones(m), np.full(m, 0.5)]
    out += [np.eye(m)[a] + np.eye(m)[b] for a in range(m) for b in range(a + 1, m) if m > 2]
    if m <= FULL_CORNERS:
        out += [np.array(c, float) for c in itertools.product([low, high], repeat=m)]
    else:  # 2 m + 2 corners, not 2^m: all low, all high, each key alone at low and at high
        out += [np.full(m, low), np.full(m, high)]
        out += [v * np.eye(m)[a] for a in range(m) for v in (low, high)]
    if m == 2:
        out += [np.array([1.0, 0.5]), np.array([0.5, 1.0])]
    elif m > 2:
        out += [0.5 * np.eye(m)[a] for a in range(m)]
    keys = [np.zeros(m)] + list(np.eye(m))
    uniq = []
    for w in out:
        if all(np.abs(w - k).max() > 1e-12 for k in keys + uniq):
            uniq.append(w)
    return uniq


def exploration_weights(m, known, max_points=24):
    """The points of the half grid ``{0, 1/2, 1}^m`` that are not in ``known`` (the keys' and the candidates'
    weights), in lexicographic order; where there are more than ``max_points``, a seeded draw of that many (for
    ``3^m`` above :data:`GRID_ENUMERATION`, drawn point by point without listing the grid).

    The pool of :func:`space_indicator`: where the first round of Newton vectors fills the build's points
    (``K >= 4``) and no point can be revisited, the space is enlarged where the indicator ranks it worst among
    these.

    Examples
    --------
    >>> [w.tolist() for w in exploration_weights(2, candidate_weights(2, -0.5, 1.5) + [np.zeros(2), np.eye(2)[0],
    ...                                                                                np.eye(2)[1]])]
    [[0.0, 0.5], [0.5, 0.0]]
    """
    known = {tuple(np.round(2.0 * np.asarray(k, float)).astype(int)) for k in known
             if np.abs(2.0 * np.asarray(k, float) - np.round(2.0 * np.asarray(k, float))).max() <= 1e-12}
    if 3 ** m <= GRID_ENUMERATION:
        out = [np.array(g, float) for g in itertools.product([0.0, 0.5, 1.0], repeat=m)]
        out = [w for w in out if tuple(np.round(2.0 * w).astype(int)) not in known]
        if len(out) > max_points:
            pick = np.sort(np.random.default_rng(0).choice(len(out), max_points, replace=False))
            out = [out[i] for i in pick]
        return out
    rng, seen = np.random.default_rng(0), set()   # too many to list: seeded draws of the grid itself
    while len(seen) < max_points:
        g = tuple(int(v) for v in rng.integers(0, 3, m))
        if g not in known:
            seen.add(g)
    return [0.5 * np.array(g, float) for g in sorted(seen)]


def space_indicator(problem, x0, U, starts, minimize):
    """How far the space ``x0 + U q`` is from the projection at each ``(w, q0)`` of ``starts``, to rank weights.

    ``q = minimize(w, q0)`` approximates the minimizer in the space (the mixer passes Gauss-Newton on the reduced
    energy of a random sample of edges, :meth:`ShapeMixer._screening_energy`); the indicator is ``|g|^2 / W_q`` there,
    ``g = 2 J^T W r`` the full gradient (the fixed coordinates left out), whose component in the space is about 0:
    what is left points out of the space.  A ratio of two sums over the same mesh, so only its order among weights of
    one build means something (it has the units of an inverse squared length).

    Returns ``(indicator (len(starts),), [q])``.

    The rank correlation with the Newton step's own relative gain (``g^T H^{-1} g / (2 W_q)``, ``H`` factorized at
    the point, the quantity :func:`newton_vectors` reports), over the 15 weights of :func:`exploration_weights` on
    the CC0 body (13k vertices, K = 4): 0.93 from the minimizer of two reduced Gauss-Newton steps with the full
    Jacobian (66 ms a weight), 0.66-0.86 from the minimizer of 2000 sampled edges (two seeds, 11-14 ms a weight;
    both seeds' three largest are those of the gains), but 0.14 after a single full reduced step (the reduced
    problem is not converged, and its own gradient dominates).  Against the energy gap of the space at 34 weights
    with converged Gauss-Newton references (the exact minimizer in the space over Gauss-Newton) the two-step
    indicator's correlation is 0.81, the Newton gain's 0.90, and the model decrease with the factorization of the
    basis key or of the build's last point instead of a fresh one 0.14 and 0.22 (useless).  The sample matters:
    over six draws of 2000 edges the rank correlation with the gains was 0.46-0.92 and the three largest were the
    gains' three in four of them; one full reduced step after the sampled minimizer makes it 0.94-0.96 with the
    right three in all six, for 32 instead of 12 ms a weight (the CC0 body's build 0.5 s longer, over its budget).
    """
    out, qs = np.zeros(len(starts)), []
    for i, (wk, q0) in enumerate(starts):
        q = minimize(wk, q0)
        e, g = problem.energy_and_gradient(x0 + U @ q, wk)
        out[i] = float(g @ g) / e if e > 0 else 0.0
        qs.append(q)
    return out, qs


class Expansion:
    """A point of the weight space with its shape ``x`` and optionally first (``D1 (m, 3V)``) and second
    derivatives (``T (m, m, 3V)``, symmetric)."""

    def __init__(self, w, x, D1=None, T=None):
        self.w, self.x, self.D1, self.T = np.asarray(w, float), x, D1, T

    def predict(self, wk, order=2):
        d = np.asarray(wk, float) - self.w
        out = self.x.copy()
        if self.D1 is not None and order >= 1:
            out += d @ self.D1
        if self.T is not None and order >= 2:
            out += 0.5 * np.einsum("a,b,abx->x", d, d, self.T)
        return out


def build_space(problem, key_x, low, high, *, second_order=True, chord_steps=0, size=1.0, progress=None,
                stage=None):
    """Vectors spanning the reduced space and the expansions of the keys.

    Parameters
    ----------
    problem : FullProblem
    key_x : (K, 3V) ndarray
        Canonical coordinates of the keys.
    low, high : float
        The accurate box of weights (its corners are chord candidates).
    second_order : bool
    chord_steps : int
        Chord steps per candidate (0: none).
    size : float
        Bounding-box diagonal (context units), the scale of finite differences.
    stage : callable, optional
        ``stage(name)`` -> context manager timing a stage (``"derivatives"``, ``"chord_vectors"``).

    Returns
    -------
    vectors : list of (3V,) ndarrays
    expansions : list of Expansion
        The keys (with derivatives) and the candidates (their last chord iterate).
    """
    stage = _no_stage if stage is None else stage
    K, m = len(key_x), len(key_x) - 1
    keys_w = [np.zeros(m)] + list(np.eye(m))
    x0 = key_x[0]
    vectors = [key_x[k] - x0 for k in range(1, K)]
    exps = []
    cands = candidate_weights(m, low, high) if chord_steps > 0 else []
    total = 2 * K + len(cands)
    timer = stage("derivatives")
    timer.__enter__()
    for k in range(K):
        report(progress, k, total, f"derivatives at key {k}")
        J = problem.factorize(key_x[k], keys_w[k])
        D1 = problem.first_derivatives(J)
        vectors += list(D1)
        T = None
        if second_order:
            T = np.zeros((m, m, len(x0)))
            for a in range(m):
                T[a, a] = problem.second_derivative(key_x[k], keys_w[k], D1[a], np.eye(m)[a], size)
                vectors.append(T[a, a])
            for a in range(m):
                for b in range(a + 1, m):
                    S = problem.second_derivative(key_x[k], keys_w[k], D1[a] + D1[b], np.eye(m)[a] + np.eye(m)[b],
                                                  size)
                    T[a, b] = T[b, a] = 0.5 * (S - T[a, a] - T[b, b])
                    vectors.append(S)
        exps.append(Expansion(keys_w[k], key_x[k].copy(), D1, T))
    timer.__exit__(None, None, None)
    timer = stage("chord_vectors") if cands else contextlib.nullcontext()
    timer.__enter__()
    # chord vectors: group the candidates by the key whose prediction has the lowest energy
    starts = []
    for wc in cands:
        preds = [e.predict(wc, o) for e in exps for o in ((1, 2) if e.T is not None else (1,))]
        energies = [problem.energy(p, wc) for p in preds]
        i = int(np.nanargmin(energies))
        starts.append((i // (2 if second_order else 1), preds[i], energies[i]))
    done = K
    for k in range(K):
        mine = [j for j, s in enumerate(starts) if s[0] == k]
        if not mine:
            continue
        problem.factorize(key_x[k], keys_w[k])
        for j in mine:
            report(progress, done, total, f"chord vectors {done - K + 1} of {len(cands)}")
            done += 1
            wc = cands[j]
            x, e = starts[j][1], starts[j][2]
            for _ in range(chord_steps):
                d = problem.solve(-problem.gradient(x, wc))
                vectors.append(d)
                step = min(1.0, 0.1 * size * np.sqrt(len(d) / 3) / max(float(np.linalg.norm(d)), 1e-300))
                while step > 1e-8:
                    en = problem.energy(x + step * d, wc)
                    if en < e:
                        break
                    step *= 0.5
                if not (step > 1e-8):
                    break
                x, e = x + step * d, en
            exps.append(Expansion(wc, x))
    timer.__exit__(None, None, None)
    report(progress, total, total, "reduced space")
    return vectors, exps


def _unit_columns(vectors, rows):
    """The non-zero ``vectors`` scaled to unit length, as the columns of a ``(rows, k)`` array."""
    out = [v / n for v in vectors if (n := np.linalg.norm(v)) > 0]
    return np.array(out).T if out else np.zeros((rows, 0))


def orthonormal_basis(vectors, max_size=None, rtol=1e-8, keep=0):
    """Orthonormal columns ``(3V, r)`` spanning the unit-scaled ``vectors``, the first ``keep`` of them exactly.

    The ``keep`` first vectors (the keys) are orthonormalized first; the others, with those directions
    removed, by an SVD whose singular values below ``rtol`` times the largest are dropped, and only
    the largest ones up to ``max_size`` columns in all are kept.  Returns ``(U, singular values)``.
    """
    K, A = _unit_columns(vectors[:keep], len(vectors[0])), _unit_columns(vectors[keep:], len(vectors[0]))
    Q = np.zeros((A.shape[0], 0))
    if K.shape[1]:
        Q, Rk = np.linalg.qr(K)
        Q = Q[:, np.abs(np.diag(Rk)) > rtol]                       # keys equal to others add nothing
    R = A - Q @ (Q.T @ A)
    U, s, _ = np.linalg.svd(R, full_matrices=False)
    n = int(np.count_nonzero(s > rtol * max(float(s[0]) if s.size else 0.0, 1.0)))
    if max_size is not None:
        n = max(0, min(n, int(max_size) - Q.shape[1]))
    return np.ascontiguousarray(np.hstack([Q, U[:, :n]])), s


#: Rows of ``J`` per block in :func:`reduced_normal_equations`.
NORMAL_EQUATION_ROWS = 4096


def reduced_normal_equations(J, U, scale, rhs=None, rows=NORMAL_EQUATION_ROWS):
    """``A^T A`` ``(r, r)`` and ``A^T rhs`` ``(r,)`` of ``A = diag(scale) J U``, in blocks of ``rows`` rows of ``J``.

    ``A`` (``(2E, r)``, 100 MB at 50k vertices and ``r = 44``) is never formed whole: each block's product is
    small enough for the allocator to reuse its memory, where a whole ``A`` per call touches fresh memory, whose
    page faults can cost more than the product (on a virtual machine).  The sums are those of the whole product
    up to rounding.

    Parameters
    ----------
    J : scipy.sparse.csr_matrix, shape (n, N)
    U : (N, r) ndarray
    scale : (n,) ndarray
        Row scaling (``sqrt`` of the energy's weights).
    rhs : (n,) ndarray, optional
        Already scaled right-hand side; without it the second result is None.
    rows : int

    Returns
    -------
    AtA : (r, r) ndarray
    Atb : (r,) ndarray or None

    Examples
    --------
    >>> import scipy.sparse as sp
    >>> rng = np.random.default_rng(0)
    >>> J = sp.random(50, 30, density=0.2, format="csr", random_state=1)
    >>> U, s, b = rng.standard_normal((30, 4)), rng.uniform(1, 2, 50), rng.standard_normal(50)
    >>> AtA, Atb = reduced_normal_equations(J, U, s, b, rows=7)
    >>> A = s[:, None] * (J @ U)
    >>> bool(np.allclose(AtA, A.T @ A) and np.allclose(Atb, A.T @ b))
    True
    """
    n, r = J.shape[0], U.shape[1]
    AtA, Atb = np.zeros((r, r)), None if rhs is None else np.zeros(r)
    ip = J.indptr
    for a in range(0, n, rows):
        b = min(n, a + rows)
        p0, p1 = ip[a], ip[b]
        block = sp.csr_matrix((J.data[p0:p1], J.indices[p0:p1], ip[a:b + 1] - p0), shape=(b - a, J.shape[1]),
                              copy=False)
        A = block @ U
        A *= scale[a:b, None]
        AtA += A.T @ A
        if rhs is not None:
            Atb += A.T @ rhs[a:b]
    return AtA, Atb


def reduced_solve(problem, x0, U, q, wk, iterations=4, linearized=False):
    """Gauss-Newton on ``W_q[z(w), Z(x0 + U q)]`` with the full Jacobian (every edge): ``q`` of the exact reduced
    minimizer, approximately (``iterations`` steps with backtracking).

    Every point is evaluated with its Jacobian (:meth:`FullProblem.linearize`, the lengths and angles from the
    same intermediates): the energy of an accepted step and the next step's Jacobian come from one evaluation, and
    the last one is handed on with ``linearized`` (the factorization and the Newton step there need no second
    evaluation).  A trial point is ``x0 + U q`` of its ``q``, so the points, steps and the result are those of
    evaluating energies and Jacobians separately, to the last bit.

    Returns ``(q, x, energy)``, and with ``linearized`` also ``(J, z)`` at ``x`` (for the factorization there,
    :meth:`FullProblem.factorize`).
    """
    sw = np.sqrt(problem.w)
    x = x0 + U @ q
    J, z = problem.linearize(x)
    e = problem.energy_z(z, wk)
    for _ in range(iterations):
        H, g = reduced_normal_equations(J, U, sw, sw * problem._residual(z, wk))   # A = W^(1/2) J U
        H *= 2.0
        g *= 2.0
        try:
            d = -np.linalg.solve(H + 1e-12 * np.trace(H) / len(H) * np.eye(len(H)), g)
        except np.linalg.LinAlgError:
            break
        step = 1.0
        while step > 1e-6:
            qn = q + step * d
            xn = x0 + U @ qn
            Jn, zn = problem.linearize(xn)
            en = problem.energy_z(zn, wk)
            if en < e:
                break
            step *= 0.5
        if not step > 1e-6:
            break
        q, x, J, z = qn, xn, Jn, zn
        small = e - en <= 1e-4 * e
        e = en
        if small:
            break
    if linearized:
        return q, x, e, (J, z)
    return q, x, e


def relative_rms(x, size):
    """RMS length of the vertex displacements ``x`` ``(3V,)`` over ``size`` (a float).

    >>> round(relative_rms(np.array([3.0, 4.0, 0.0, 0.0, 0.0, 0.0]), 2.0), 6)     # 5 / sqrt(2) / 2
    1.767767
    """
    return float(np.linalg.norm(x) / np.sqrt(len(x) / 3) / size)


def _extend(U, vectors, rtol=1e-8):
    """``U`` ``(n, r)`` (orthonormal columns) followed by orthonormal columns for what ``vectors`` add to its span."""
    V = _unit_columns(vectors, U.shape[0])
    if not V.shape[1]:
        return U
    for _ in range(2):                                        # twice: orthogonal to U to rounding
        V -= U @ (V.T @ U).T                                # (V^T U)^T: faster than U^T V for few columns
    Q, R = np.linalg.qr(V)
    return np.hstack([U, Q[:, np.abs(np.diag(R)) > rtol]])


def newton_vectors(problem, x0, U, starts, size, keys=None, pcg_iterations=0, derivatives=False, progress=None,
                   reduced_iterations=2, min_gain=0.0, presolve=None):
    """One full Gauss-Newton step from the reduced minimizer at each ``(w, q0)`` of ``starts``: the part of the
    projection the space misses, to first order.

    With ``pcg_iterations = 0`` the starts are taken one after another, each in the space enlarged by
    the vectors of the starts before it (the reduced minimizer at a start sees them), and every step is
    solved with a fresh factorization of the Gauss-Newton matrix at the reduced minimizer.  Taking them
    in turn instead of all in the same space lets one round do most of the work of two: on the 5k box
    bar (K = 3, the corners of the box first) one round in turn left the largest RMS error in
    ``[-0.5, 1.5]^2`` at 0.44 % of the diagonal and in ``[0, 1]^2`` at 0.04 % (one round in the same
    space: 0.98 % and 0.07 %; two: 0.37 % and 0.02 %, with 12 factorizations instead of 9).
    Otherwise (``pcg_iterations > 0``) all starts share the space ``U`` and every step is that many
    preconditioned conjugate-gradient iterations (matrix-free products with the Gauss-Newton matrix
    there), preconditioned by the factorization at the nearest key of ``keys`` (``[(w_k, x_k)]``): one
    factorization per key instead of one per start.

    The reduced minimizer needs few iterations (``reduced_iterations`` Gauss-Newton steps in the space,
    :func:`reduced_solve`): the full step from a point ``x`` of the space lands near the projection
    whatever ``x``, so an error of ``x`` within the space changes the step only within the space, to
    first order, and adds nothing to the space.  ``presolve(space, w, q0) -> q`` (with ``pcg_iterations = 0``),
    when given, moves each start first by cheaper iterations in the space as grown so far (the mixer: two
    Gauss-Newton steps of the reduced energy on a sample of edges), and the ``reduced_iterations`` steps with
    every edge start from there.

    With ``derivatives`` (a bool, or a sequence of one per start; and a factorization per start) the same
    factorization also gives the first derivatives of the projection by the weights at the reduced minimizer
    (``H^{-1} 2 J^T W dz_j``, the formula at the keys, :meth:`FullProblem.first_derivatives`): ``m`` more
    right-hand sides of one solve (:meth:`FullProblem.newton_step`), no more factorizations.  They join the steps
    in the returned vectors.

    ``progress(done, total, message)`` is reported before every start (:func:`lacore.progress.report`).

    With ``min_gain > 0`` (and a factorization per start) a start whose step would lower the energy
    there by at most ``min_gain`` times that energy (the Gauss-Newton model's decrease
    ``g^T H^{-1} g / 2``), or whose step is shorter than ``1e-9 size`` (RMS over the vertices; the
    space holds the projection there to rounding), adds no vector: the space is already as good as the
    projection there, and a vector it does not need costs the cubature and every mix.

    Returns the vectors (the steps, then the derivatives when asked), the reduced minimizers
    ``[(w, x)]``, the RMS lengths of the steps relative to ``size`` (the error of the space there
    before the step joined it, to first order), the steps' model decreases relative to the energy
    there (NaN with ``pcg_iterations``) and orthonormal columns spanning ``U`` and the vectors (``U``
    followed by the new directions; with ``pcg_iterations`` None).
    """
    w = problem.w
    solved, steps, extra = [], [None] * len(starts), []
    gains = np.full(len(starts), np.nan)
    if not pcg_iterations:
        space = U
        kept = []
        for i, (wk, q0) in enumerate(starts):
            report(progress, i, len(starts), f"Newton vector {i + 1} of {len(starts)}")
            q0 = np.concatenate([q0, np.zeros(space.shape[1] - U.shape[1])])   # the new columns come last
            if presolve is not None:
                q0 = presolve(space, wk, q0)
            _, x, e, (J, z) = reduced_solve(problem, x0, space, q0, wk, iterations=reduced_iterations,
                                            linearized=True)
            solved.append((np.asarray(wk, float), x))
            g = 2.0 * (J.T @ (w * problem._residual(z, wk)))                  # the step solves H s = -g
            J = problem.factorize(x, wk, linearized=(J, z))
            with_derivatives = derivatives if np.ndim(derivatives) == 0 else derivatives[i]
            steps[i], *more = problem.newton_step(J, x, wk, with_derivatives, z=z)
            gain = -0.5 * float(g @ steps[i])
            gains[i] = gain / e if e > 0 else 0.0
            if min_gain > 0 and (gain <= min_gain * e or
                                 np.linalg.norm(steps[i]) <= 1e-9 * size * np.sqrt(len(x) / 3)):
                continue
            kept.append(steps[i])
            extra += more
            space = _extend(space, [steps[i]] + more)
    else:
        for i, (wk, q0) in enumerate(starts):
            report(progress, i, len(starts), f"Newton vector {i + 1} of {len(starts)}")
            _, x, _ = reduced_solve(problem, x0, U, q0, wk, iterations=reduced_iterations)
            solved.append((np.asarray(wk, float), x))
        near = [int(np.argmin([np.abs(wk - kw).sum() for kw, _ in keys])) for wk, _ in solved]
        for k, (kw, kx) in enumerate(keys):
            mine = [i for i, n in enumerate(near) if n == k]
            if not mine:
                continue
            problem.factorize(kx, kw)
            for i in mine:
                wk, x = solved[i]
                J, z = problem.linearize(x)
                g = 2.0 * (J.T @ (w * problem._residual(z, wk)))
                w2 = 2.0 * w

                def matvec(v, J=J, w2=w2):
                    return J.T @ (w2 * (J @ v))

                d, _, _ = preconditioned_cg(matvec, -g, problem.solve, problem.fixed, 1e-6, pcg_iterations)
                steps[i] = d
    sizes = np.array([relative_rms(d, size) for d in steps])
    if pcg_iterations:
        return steps + extra, solved, sizes, gains, None
    return kept + extra, solved, sizes, gains, space
