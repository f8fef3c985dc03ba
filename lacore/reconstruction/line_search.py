"""Armijo backtracking line search of the Gauss-Newton loop, along a line or a geodesic-acceleration parabola."""

import numpy as np

from ..geometry.lengths_angles import lengths_and_angles, wrap_angle

__all__ = ["armijo_line_search"]


def armijo_line_search(objective, X, d, energy, slope, c1, max_backtracks, refine=8, accel=None, theta=None):
    """Armijo backtracking from the full step ``t = 1``; returns ``(t, X_new, E_new, evaluations)``.

    The trial points are ``X + t d``, or ``X + t d + t^2 accel / 2`` along the
    parabola of a geodesic acceleration ``accel`` (same slope ``g.d`` at 0).

    Trial steps shrink by safeguarded quadratic interpolation.  When a step
    ``t < 1`` is accepted after the larger ``t_prev`` was rejected, up to
    ``refine`` further trials in ``(t, t_prev)`` (minimizers of the quadratic
    through ``E(0), E'(0), E(t)``) look for a lower energy: an evaluation of
    ``Z`` costs far less than a Gauss-Newton iteration.

    With ``theta = (target, unfolded)`` (the target dihedral angles and a mask
    of the edges whose angle at ``X`` is within ``pi / 2`` of it), trials
    folding one of these edges -- its angle more than ``pi / 2`` off the target on
    the circle -- are rejected (the step is halved): such a step turns the surface
    over, into another, usually worse, local minimum.
    """
    E = objective.topology.n_edges

    def trial(tt):
        Xt = X + tt * d if accel is None else X + tt * d + (0.5 * tt * tt) * accel
        if theta is None:
            return Xt, objective.energy(Xt), False
        z = lengths_and_angles(Xt, objective.topology, check=False)
        if np.any(np.abs(wrap_angle(z[E:][theta[1]] - theta[0][theta[1]])) > 0.5 * np.pi):
            return Xt, np.nan, True
        return Xt, objective.value_z(z), False

    t, t_prev = 1.0, None
    for k in range(max_backtracks):
        Xt, Et, turned = trial(t)
        if np.isfinite(Et) and Et <= energy + c1 * t * slope:
            n = k + 1
            for _ in range(refine if t_prev is not None else 0):
                denom = 2.0 * (Et - energy - slope * t)
                t_try = -slope * t * t / denom if denom > 0 else 2.0 * t
                t_try = min(t_try, 0.5 * (t + t_prev), 2.0 * t)
                if not t_try > 1.05 * t:
                    break
                X_try, E_try, _ = trial(t_try)
                n += 1
                if not (np.isfinite(E_try) and E_try < Et):
                    break
                t, Xt, Et = t_try, X_try, E_try
            return t, Xt, Et, n
        t_prev = t
        if turned:
            t *= 0.5
        elif np.isfinite(Et):
            # minimizer of the quadratic through E(0), E'(0) and E(t), kept in [0.1 t, 0.5 t]
            denom = 2.0 * (Et - energy - slope * t)
            t_new = -slope * t * t / denom if denom > 0 else 0.5 * t
            t = min(0.5 * t, max(0.1 * t, t_new))
        else:
            t *= 0.1
    return 0.0, X, energy, max_backtracks

