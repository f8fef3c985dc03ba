"""In-betweens of two keys by a reduced model of their path: few factorizations for many in-betweens.

An in-between of the keys ``A`` (``t = 0``) and ``B`` (``t = 1``) is the projection of the target
``z(t) = z_A + t (z_B - z_A)`` (angles on the circle, lengths floored: the blend of a two-key
:class:`~lacore.shapes.mixing.ShapeMixer`, thesis 4.2), the minimizer of ``W_q[z(t), Z(X)]`` (3.19),
the energy of :func:`lacore.reconstruction.reconstruct` with ``A``'s weights at every ``t`` (as the mixer's; for
keys more than 1.5 times apart in size :func:`~lacore.reconstruction.reconstruct` itself would scale the length
weights with the target, :mod:`lacore.reconstruction.context`, "Target scale").  The targets lie on a segment, so a
subspace made for that segment needs far fewer factorizations than a general mixer of the keys
(``K + C`` of them, :mod:`.mixer`) or the full projection (one or more per in-between):

* the keys: ``X_B - X_A`` (the projection is ``A`` at ``t = 0`` and ``B`` at ``t = 1``);
* the tangent of the path at ``A`` (and optionally ``B``), ``dX/dt = H^{-1} 2 J^T W (z_B - z_A)`` (one
  factorization each, of the key's Hessian; :meth:`.subspace.FullProblem.first_derivatives`, as the
  mixer's build computes them at its keys);
* Newton vectors (:func:`.subspace.newton_vectors`, the mixer's), added only where needed: first at the
  in-between where the error of the space is expected to be largest (:func:`_error_shape`), then at the
  one farthest from the keys and the points already probed, one full Gauss-Newton step from the
  minimizer in the space (a new numeric factorization, the symbolic analysis reused) and the tangent
  there from the same factorization.

Distances are over each in-between's own size: ``A``'s bounding-box diagonal times the in-between's
:meth:`~.mixer.ShapeMixer.relative_size` (its total edge length over ``A``'s, ``1 + t (L_B / L_A - 1)``), and
"along the path" is in the path's own length ``u(t) = int_0^t ds / relative_size(s)`` (:func:`_own_length`; ``u =
t`` for keys of one size).  A probe's step length is the *error estimate* of the reduced in-between there (to
first order, the distance to the projection); its *offset* is the distance from the step's landing point (in the
space once the step joins it) to the reduced in-between there in that space, what the step's first-order model
misses.  The *indicator* of an in-between is :data:`SAFETY` times the largest of the last estimate and every
probe's offset (an earlier probe's at most the estimate of the later probe nearest to it, scaled to it), each scaled
from its probe along the path by :func:`_error_shape` (:func:`_scaled_errors`).  Probing stops as soon as every
indicator is at most :attr:`PathOptions.tolerance`, or after :attr:`PathOptions.max_newton_vectors` probes.  A probe
costs one factorization, less than the polish of a single in-between, and two probes' estimates, taken at different
in-betweens in different spaces, do not tell whether the space converges: on the 50k bar twisted by 90 degrees they
read 0.58 %, 0.67 % and 0.68 % while the largest indicator went from 3.6 % to 1.8 %, within the range where the
polish by Fast suffices (the rolled plates of the shared data, estimates 10-20 % of the diagonal, go to Gauss-Newton
after three probes).

Keys of very different sizes are where the size and the offsets matter.  ``W_q`` with ``A``'s weights weighs
stretching against bending by the square of the in-between's size over ``A``'s, so the projection changes most,
relative to its size, where the in-betweens are small, and a probe far from there does not see it.  Between the
finger of the shared data and the bent finger scaled by 0.1 the probes go to ``t = 0.91, 0.64, 0.36``; the largest
error is 0.074 % of the in-between's size, the indicator there 0.19 %.  On keys of one size the sizes are 1 and the
offsets far below the estimates (1.0e-6 of the diagonal against 7.5e-4 on the bent bar of the tests): the indicator
is the last estimate's.

Every in-between is the minimizer of the exact reduced energy (every edge, ``O(n r)`` per Gauss-Newton
step for ``r`` columns, no cubature: :class:`.reduced.ReducedEnergy`).  When the indicator stays above
the tolerance after :attr:`PathOptions.max_newton_vectors` probes, the in-betweens where it does are
polished by the full projection of the same energy (Fast or Gauss-Newton, :attr:`PathOptions.polish_method`;
or, with ``polish=False``, returned with ``success`` False and a message), never a silently wrong shape.

Cost: ``1 + p`` factorizations for ``p`` probes (``p >= 1``: the estimate needs one; one more with
``tangents="both"``), whatever the number of in-betweens.  On the 50k bar (a 90-degree bend) and the CC0
body's knee and torso keys two, on its raised arm three; the polish costs what full Gauss-Newton does.
Measurements: ``benchmarks/bench_path_inbetweens.py``.
"""

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...progress import report
from ...reconstruction.settings import GaussNewtonOptions
from ...reconstruction.spanning_trees import default_root_faces
from .mixer import MixerOptions, ShapeMixer, _Stopwatch
from .subspace import _extend, newton_vectors, orthonormal_basis, relative_rms

__all__ = ["PathOptions", "PathResult", "path_inbetweens", "SAFETY", "FAST_POLISH"]

#: The indicator is this many times the probes' first-order estimate (or offset), scaled along the path
#: (:func:`_error_shape`).  With the factor 1 it was down to 0.98 times the RMS distance to converged Gauss-Newton
#: (a 302-vertex bar bent by 2.5 and twisted by 2 radians), 4 to 300 times on milder paths and on the CC0 body
#: (``tests/test_path_inbetweens.py`` asserts that the indicator covers the error).
SAFETY = 2.0

#: In-betweens whose distance to the keys and the probes along the path is within this fraction of the largest are
#: equally far: the next probe is the first of them in the order given, so keys of nearly one size probe where keys
#: of exactly one size do (the flat 121-vertex plate and its roll, 0.8 % shorter: at 0.25 rather than at 0.5 after
#: 0.75; three probes then bring the largest indicator to 0.07 %, in the other order to 3.5 %, which sends every
#: in-between to Gauss-Newton).
FARTHEST_TIE = 0.01

#: ``polish_method="auto"`` polishes by Fast when the largest indicator is at most this many times the tolerance.
FAST_POLISH = 10.0


@dataclass(frozen=True)
class PathOptions:
    """Settings of :func:`path_inbetweens` (all scale-free).

    Attributes
    ----------
    tolerance : float
        Largest accepted indicator (the estimated RMS distance to the projection over the in-between's own size,
        the bounding-box diagonal of ``A`` times :meth:`~.mixer.ShapeMixer.relative_size`; module docstring);
        default 0.003, the 0.3 % the in-betweens are held to.
    max_newton_vectors : int
        Most probes (factorizations beyond the two at the keys) before falling back (at least 1).
    iterations : int
        Gauss-Newton steps of every reduced solve (they stop earlier when the energy stops decreasing).
    polish : bool
        When the estimate stays above ``tolerance``: compute the in-betweens above it by the full projection
        (:attr:`polish_method`; the default), else return the reduced results with ``success`` False.
    tangents : {"from", "both"}
        The tangents of the path in the space: at ``A`` only (the default: one factorization fewer; the
        Newton vector in the middle also brings the tangent there), or at both keys.
    polish_method : {"auto", "fast", "gn"}
        How in-betweens above the tolerance are polished: by lacore's default projection Fast, continuing from the
        keys and the in-betweens within the tolerance (on the 5k bar twisted by 90 degrees 0.36 s instead of
        1.5 s for converged Gauss-Newton from the reduced results, the same largest distance to Gauss-Newton,
        0.075 % of the diagonal), or by Gauss-Newton to convergence, continuing the same way (as
        ``interpolate(method="gn")``; the reduced in-betweens it replaces are farther off than the secant through
        its neighbours: on the 50k bar bent by 90 degrees into a twist by 90 degrees, estimates of 5.6 %, the path
        with 9 in-betweens polished took 152 and 156 s against 166 and 174 s from the reduced ones).  ``"auto"`` (the
        default): Fast when the indicator is within :data:`FAST_POLISH` times the tolerance (the reduced
        in-betweens are close), else Gauss-Newton (between the rolled plates of the shared data, estimates of
        10-20 %, Fast ended 1 % of the diagonal away from Gauss-Newton).
    polish_iterations : int
        Iterations of a polish.
    bending_weight : float or None
        ``eta`` of ``W_q`` (default: the reconstruction's default).

    Examples
    --------
    >>> PathOptions().tolerance, PathOptions().max_newton_vectors
    (0.003, 3)
    """

    tolerance: float = 3e-3
    max_newton_vectors: int = 3
    iterations: int = 20
    polish: bool = True
    tangents: str = "from"
    polish_method: str = "auto"
    polish_iterations: int = 300
    bending_weight: float | None = None

    def __post_init__(self):
        if not (np.isfinite(self.tolerance) and self.tolerance > 0):
            raise InputError(f"tolerance must be a positive number, got {self.tolerance!r}")
        for name, low in (("max_newton_vectors", 1), ("iterations", 1), ("polish_iterations", 1)):
            v = getattr(self, name)
            if int(v) != v or v < low:
                raise InputError(f"{name} must be an integer of at least {low}, got {v!r}")
        if self.bending_weight is not None and not (np.isfinite(self.bending_weight) and self.bending_weight >= 0):
            raise InputError(f"bending_weight must be a non-negative number, got {self.bending_weight!r}")
        if self.tangents not in ("from", "both"):
            raise InputError(f"tangents must be 'from' or 'both', got {self.tangents!r}")
        if self.polish_method not in ("auto", "gn", "fast"):
            raise InputError(f"polish_method must be 'auto', 'gn' or 'fast', got {self.polish_method!r}")


@dataclass(frozen=True)
class PathResult:
    """In-betweens of :func:`path_inbetweens`.

    Attributes
    ----------
    vertices : (N, V, 3) ndarray
        The in-betweens, in the frame of ``A`` (its fixed face where ``A`` has it).
    factors : (N,) ndarray
    energy : (N,) ndarray
        ``W_q[z(t), Z(vertices)]`` on the whole mesh.
    indicator : (N,) ndarray
        Error estimate of every in-between (RMS distance to the projection over the in-between's own size, the
        bounding-box diagonal of ``A`` times :meth:`~.mixer.ShapeMixer.relative_size`): 0 at the keys and for
        in-betweens polished by converged Gauss-Newton; for those polished by Fast the reduced in-between's (an
        upper estimate: on the 50k bar twisted by 90 degrees Fast ended within 0.15 % of Gauss-Newton where the
        reduced in-betweens were estimated up to 0.6 % off); else :data:`SAFETY` times the largest of the last
        probe's estimate and the probes' offsets, scaled along the path (module docstring).
    estimates : list of (float, float)
        ``(t, estimate)`` of every probe, in order: its Gauss-Newton step's RMS length over the in-between's size.
    offsets : list of (float, float)
        ``(t, offset)`` of every probe, in order: the RMS distance from its step's landing point to the reduced
        in-between there in the space the step joined, over the in-between's size.
    polished : bool
        Whether full Gauss-Newton produced in-betweens: those whose indicator stayed above the tolerance (their
        indicator is then 0).
    success : bool
        The estimate is within the tolerance or every polish converged.
    message : str
    reduced_size : int
    factorizations : int
        Numeric factorizations of the Gauss-Newton matrix (one per tangent and one per probe; polishes not
        included).
    seconds, cpu_seconds : dict
        Wall and CPU seconds by stage: ``setup``, ``derivatives`` (the tangents), ``newton_vectors``, ``reduced``
        (the reduced solves and the output), ``polish`` and ``total``.
    """

    vertices: np.ndarray
    factors: np.ndarray
    energy: np.ndarray
    indicator: np.ndarray
    estimates: list
    offsets: list
    polished: bool
    success: bool
    message: str
    reduced_size: int
    factorizations: int
    seconds: dict
    cpu_seconds: dict


def _next_probe(u, probed, u1, shape=None):
    """Index of the in-between farthest from the keys and the probed in-betweens along the path (``u``: their
    :func:`_own_length`, ``u1`` that of ``B``; ``probed``: indices; the first in the order given of those within
    :data:`FARTHEST_TIE` of the farthest), None when all are keys or probed; with ``shape`` (:func:`_error_shape`),
    the in-between in ``[0, 1]`` where it is largest."""
    inside = (u > 0.0) & (u < u1)
    if shape is not None and inside.any():
        return int(np.argmax(np.where(inside, shape, -1.0)))
    known = np.array([0.0, u1] + [u[j] for j in probed])
    dist = np.abs(u[:, None] - known[None, :]).min(axis=1)
    if dist.max() <= 1e-12 * u1:
        return None
    return int(np.argmax(dist >= (1.0 - FARTHEST_TIE) * dist.max()))      # the first of the farthest


def _own_length(factors, rel):
    """``u(t) = int_0^t ds / rel(s)``: the path's parameter in units of the in-betweens' own size, for ``rel`` the
    :meth:`~.mixer.ShapeMixer.relative_size` at ``factors`` (linear in ``t``: ``u = t ln(rel) / (rel - 1)``, and
    ``u = t`` where the size does not change).  Along a path of one size ``u = t``; where the size shrinks, equal steps
    of ``t`` are longer steps of ``u``: the in-betweens change more relative to their size."""
    t, r = np.asarray(factors, float), np.asarray(rel, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = t * np.log(r) / (r - 1.0)
    return np.where(np.abs(r - 1.0) <= 1e-9, t, u)


def _error_shape(U, tangents):
    """How the error of the space grows along the path, up to a factor: that of the polynomial interpolant of
    ``X(U)`` the space holds (``X_A``, ``X_B`` and ``X'(0)``: ``U^2 |1 - U|``; also ``X'(1)``: ``U^2 (1 - U)^2``), in
    the path's own length ``U = u(t) / u(1)`` (:func:`_own_length`; ``U = t`` along a path of one size)."""
    U = np.asarray(U, float)
    return U * U * (np.abs(1.0 - U) if tangents == "from" else (1.0 - U) ** 2)


def _scaled_errors(probed, estimates, offsets, u, shape):
    """The error measurements of the space scaled along the path from their probes by ``shape``
    (:func:`_error_shape`), ``(M, N)``: the last probe's estimate and every probe's offset, an earlier probe's at most
    the estimate of the later probe nearest to it (along ``u``, :func:`_own_length`) scaled to it, a measurement of a
    later space next to it."""
    out = [estimates[-1] * shape / shape[probed[-1]]]
    for k, (j, off) in enumerate(zip(probed, offsets, strict=True)):
        later = probed[k + 1:]
        if later:
            n = min(range(len(later)), key=lambda m: abs(u[later[m]] - u[j]))
            off = min(off, estimates[k + 1 + n] * shape[j] / shape[later[n]])
        out.append(off * shape / shape[j])
    return np.array(out)


def _polish(mixer, topology, T, X, over, method, iterations):
    """The in-betweens ``over`` by the full projection of the mixer's energy (``A``'s weights at every ``t``, as the
    reduced model), continuing along ``t`` from the keys and the in-betweens within the tolerance (as
    :func:`lacore.interpolate`): ``method`` None for lacore's default projection (Fast: one Gauss-Newton step per
    in-between, more where a step disagrees with its quadratic model), ``"gn"`` for Gauss-Newton to convergence (at
    most ``iterations`` steps each).  Returns ``(vertices, energy, failures)``."""
    from ..projection import SequenceProjection, projection_options

    keep = np.setdiff1d(np.arange(len(T)), over)
    anchors = [(0.0, mixer.keys[0]), (1.0, mixer.keys[1])]
    anchors += [(float(T[j]), X[j]) for j in keep if T[j] not in (0.0, 1.0)]
    targets = np.array([mixer.target([T[j]]) for j in over])
    gn = GaussNewtonOptions(max_iterations=iterations) if method == "gn" else None
    opts = projection_options(method, True, None, mixer.options.settings, gn, None, {}, "path_inbetweens")
    run = SequenceProjection(targets, topology, mixer.keys[0], T[over], anchors, opts, context=mixer._context).run()
    res = [f.result for f in run.frames]
    failed = [f"t = {T[j]:g}: {r.message}" for j, r in zip(over, res, strict=True) if not r.success]
    return np.array([r.vertices for r in res]), np.array([float(r.energy) for r in res]), failed


def path_inbetweens(key_from, key_to, topology, factors, options=None, *, progress=None):
    """In-betweens (and extrapolations) of two keys by a reduced model of their path (module docstring).

    Parameters
    ----------
    key_from, key_to : (V, 3) array_like
        The keys ``A`` (``t = 0``, the reference: weights of ``W_q``, fixed face, output frame) and ``B``
        (``t = 1``).
    topology : MeshTopology
    factors : (N,) array_like
        ``t`` of the in-betweens (outside ``[0, 1]`` they extrapolate; the estimate covers them like the
        others).
    options : PathOptions, optional
    progress : callable, optional
        ``progress(done, total, message)`` (:mod:`lacore.progress`); returning True raises
        :class:`lacore.progress.Cancelled`.

    Returns
    -------
    PathResult

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=6, n_side=2)
    >>> res = path_inbetweens(X, bar_pose(X, 0.6, 0.0), MeshTopology.from_faces(faces), [0.25, 0.5, 0.75])
    >>> res.vertices.shape, res.success, res.polished, res.factorizations
    ((3, 58, 3), True, False, 2)
    >>> bool(res.indicator.max() <= PathOptions().tolerance)
    True
    """
    o = PathOptions() if options is None else options
    if not isinstance(o, PathOptions):
        raise InputError(f"options must be PathOptions, got {type(o).__name__}")
    T = np.atleast_1d(np.asarray(factors, float))
    if T.ndim != 1 or not T.size or not np.all(np.isfinite(T)):
        raise InputError("factors must be a non-empty list of finite numbers")
    watch = _Stopwatch()
    total = 3 + o.max_newton_vectors
    report(progress, 0, total, "lengths and angles of the keys")
    with watch("setup"):
        mixer = ShapeMixer(np.stack([np.asarray(key_from, float), np.asarray(key_to, float)]), topology.faces,
                           MixerOptions(bending_weight=o.bending_weight), _topology=topology,
                           _fixed_faces=default_root_faces(topology, vertices=key_from))
    P, ctx = mixer._problem, mixer._context
    xk = mixer._key_x
    x0, size = xk[0], ctx.size
    report(progress, 1, total, "tangents of the path at the keys")
    ends = [0, 1] if o.tangents == "both" else [0]
    vectors = [xk[1] - x0]
    with watch("derivatives"):
        for k in ends:                                  # as the mixer's build (.subspace.build_space), at t = k
            vectors += list(P.first_derivatives(P.factorize(xk[k], [float(k)])))
    with watch("reduced"):
        U, _ = orthonormal_basis(vectors, keep=1)
    # solved points (t, q): the keys, then the probes; a solve starts from the nearest one
    solved = {0.0: np.zeros(0), 1.0: U.T @ (xk[1] - x0)}

    step_tol = mixer.options.step_tolerance * size * np.sqrt(mixer.n_vertices)
    reduced = {}

    def solve(U, t, iterations):
        """The minimizer of the exact reduced energy (every edge, :class:`.reduced.ReducedEnergy`) at ``t``."""
        if reduced.get("U") is not U:
            mixer.basis = U
            reduced.update(U=U, energy=mixer._make_energy(None, None))

        def padded(s):
            return np.concatenate([solved[s], np.zeros(U.shape[1] - len(solved[s]))])

        s1, s2 = sorted(solved, key=lambda s: abs(s - t))[:2]
        w, q = np.array([t]), padded(s1)
        secant = q + (t - s1) / (s2 - s1) * (padded(s2) - q)     # through the two nearest solved points
        # within the two points or no farther beyond them than they are apart, the secant is taken without
        # comparing energies (two evaluations on every edge, ~0.02 s each at 50k vertices): along a smooth path
        # it is the closer start there; farther out the nearer energy decides
        if abs(t - s1) <= abs(s2 - s1) or reduced["energy"].energy(secant, w) < reduced["energy"].energy(q, w):
            q = secant
        q, e, _ = reduced["energy"].solve(w, q, iterations, step_tol)
        return q, x0 + U @ q, e

    keys = (T == 0.0) | (T == 1.0)
    rel = mixer.relative_size(T[:, None])                      # over A's diagonal / rel: over the in-between's size
    u, u1 = _own_length(T, rel), float(_own_length(1.0, mixer.relative_size([1.0])))
    shape = _error_shape(u / u1, o.tangents)
    estimates, offsets, indicator = [], [], np.zeros(len(T))
    probed = []
    while len(estimates) < o.max_newton_vectors:
        i = _next_probe(u, probed, u1, None if estimates else shape)
        if i is None:
            break
        report(progress, 2 + len(estimates), total, f"Newton vector {len(estimates) + 1} (t = {T[i]:g})")
        with watch("reduced"):
            q, _, _ = solve(U, float(T[i]), o.iterations)
        with watch("newton_vectors"):
            new, start, sizes, _, _ = newton_vectors(P, x0, U, [(np.array([T[i]]), q)], size, derivatives=True,
                                                     reduced_iterations=0)
        probed.append(i)
        estimates.append((float(T[i]), float(sizes[0] / rel[i])))
        with watch("reduced"):
            U = _extend(U, new)
            q, x, _ = solve(U, float(T[i]), o.iterations)
        solved[float(T[i])] = q
        # the step's landing point is in the space now: how far the reduced in-between there lands from it
        offsets.append((float(T[i]), relative_rms(x - start[0][1] - new[0], size) / rel[i]))
        indicator = np.where(keys, 0.0, SAFETY * _scaled_errors(probed, [e for _, e in estimates],
                                                                [e for _, e in offsets], u, shape).max(axis=0))
        if indicator.max() <= o.tolerance:
            break
    with watch("reduced"):
        xs, energy = [None] * len(T), np.empty(len(T))
        for i in np.argsort(np.abs(T - 0.5)):                       # from the middle out: near a solved point
            q, xs[i], energy[i] = solve(U, float(T[i]), o.iterations)
            solved[float(T[i])] = q
    estimate = float(indicator.max())
    with watch("reduced"):
        X = np.array([ctx.from_canonical(x.reshape(-1, 3)) for x in xs])
        # the reduced solve's energy is W_q on every edge at X (the exact reduced energy): no second evaluation,
        # except at t = 0, where the output is the key itself
        at_key = np.flatnonzero(T == 0.0)
        X[at_key] = mixer.keys[0]
        energy[at_key] = [mixer.full_energy([0.0], mixer.keys[0])] * len(at_key)
    polished, success, message = False, True, ""
    if estimate > o.tolerance:
        if o.polish:
            polished = True
            over = np.flatnonzero(indicator > o.tolerance)       # the others are within the tolerance as they are
            fast = o.polish_method == "fast" or (o.polish_method == "auto" and estimate <= FAST_POLISH * o.tolerance)
            by = "Fast" if fast else "full Gauss-Newton"
            report(progress, total - 1, total, f"polishing {len(over)} of {len(T)} in-betweens by {by}")
            with watch("polish"):
                X[over], energy[over], failed = _polish(mixer, topology, T, X, over, None if fast else "gn",
                                                        o.polish_iterations)
            if not fast:                                         # converged Gauss-Newton: the projection
                indicator[over] = 0.0
            success = not failed
            message = (f"error estimate {estimate:.3g} above {o.tolerance:g} after {len(estimates)} Newton vectors: "
                       f"{len(over)} of {len(T)} polished by {by}")
            if failed:
                message += f"; {len(failed)} did not converge (first {failed[0]})"
        else:
            success = False
            message = (f"error estimate {estimate:.3g} above the tolerance {o.tolerance:g} after {len(estimates)} "
                       "Newton vectors: polish the in-betweens or use full Gauss-Newton")
    report(progress, total, total, "done")
    watch.wall["total"] = sum(watch.wall.values())
    watch.cpu["total"] = sum(watch.cpu.values())
    return PathResult(vertices=X, factors=T, energy=energy, indicator=indicator, estimates=estimates, offsets=offsets,
                      polished=polished, success=success, message=message, reduced_size=int(U.shape[1]),
                      factorizations=len(ends) + len(estimates), seconds=dict(watch.wall), cpu_seconds=dict(watch.cpu))
