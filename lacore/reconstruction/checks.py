"""After-the-fact checks of a reconstruction: the one place that decides ``success``.

Every method of :func:`lacore.reconstruction.reconstruct` (and the hybrid
smoothing, and every frame of an interpolation) ends in :func:`apply_checks`, so
``success`` means the same for all of them:

``success`` is True exactly when

1. every output coordinate is finite, and
2. no edge is *folded*: its dihedral angle lies more than :data:`FOLD_ANGLE`
   (``pi / 2``) from the target's on the circle (the surface is turned over
   there), and
3. either the target is **reproduced** -- per edge, lengths relative to the
   target length and angles in radians::

       max_e |l_e - l*_e| / l*_e <= LENGTH_RTOL         (1e-5)
       max_e |theta_e - theta*_e| <= ANGLE_ATOL         (1e-5 rad, interior edges, on the circle)

   -- or the method is an energy minimizer (``"gn"``, ``"hybrid"``) that
   **converged** (on an integrable target not to a wrong local minimum, below):
   Gauss-Newton stopped by one of its scale-free stationarity
   rules (status 1-4 of
   :data:`~lacore.reconstruction.result.STATUS_MESSAGES`: energy at the
   noise floor, predicted Gauss-Newton decrease or decrease of a full step
   below ``ftol`` times the energy, gradient below ``gtol`` times energy /
   size, a full step below ``xtol`` times the size), or -- the hybrid method
   -- did the smoothing iterations it was asked for (status 6: a budgeted
   approximation of the minimizer; its residuals are in ``checks``).  A line
   search that stalls (no decrease, or only tiny partial steps, status -1 or
   -3) and the iteration limit (status 0) are *not* convergence.

The second branch is what success means for a **non-admissible** target (an
average or extrapolation of shapes, a weighted sum of lengths and angles): no
immersion has these lengths and angles, the residual never reaches zero, and
the answer asked for is the minimizer of the energy (thesis Def. 3.15).  The
direct methods (``"bfs"``, ``"mst"``, ``"spt"``, ``"lsq"``) minimize nothing,
so for them success means condition 3's first branch: the target is reproduced.
On a non-admissible target they report ``success=False`` ("not reproduced"),
with the errors in the message; use ``"gn"`` or ``"hybrid"`` to project it.

Integrability of the target
---------------------------
A result that passes without reproducing its target is named by what the
target is (:func:`lacore.integrability.check_integrability`, all of Theorem 3.2:
every vertex, hole and handle): for a target that is not integrable it is
**the closest mesh** (``checks["outcome"] == "closest"``, and the message says
why the target is no mesh's lengths and angles), for an integrable one a
**minimum** of the energy that does not reproduce it (``"minimum"``).  A minimum that misses an
integrable target by more than :data:`LOCAL_MINIMUM_RTOL` (1 %) in a length or :data:`LOCAL_MINIMUM_ANGLE`
(0.1 rad) in an angle is a wrong local minimum and fails (``failure="local_minimum"``): a mesh with those
lengths and angles exists (e.g. a sphere's mirror image, which Gauss-Newton from the sphere cannot turn inside
out).  A direct
method that fails on a non-integrable target says where the target does not
close (a frame-based walk leaves a seam there).  The target is checked only
when it is not reproduced (a reproduced target is integrable within the
tolerances): ``checks["target_integrable"]`` is None, True or False.

The tolerances lie far above the round-off of every method on admissible
targets and still resolve a thin strip's dihedral angles of 1e-3 rad; thin
triangles (aspect ``a``) lose about ``a * eps`` in the frame-based walks.
"""

from dataclasses import dataclass, replace

import numpy as np

from ..errors import format_indices
from ..geometry.lengths_angles import lengths_and_angles, wrap_angle
from ..integrability.checks import check_integrability

__all__ = ["LENGTH_RTOL", "ANGLE_ATOL", "FOLD_ANGLE", "CONVERGED_STATUSES", "LOCAL_MINIMUM_RTOL",
           "LOCAL_MINIMUM_ANGLE", "ReconstructionCheck",
           "check_reconstruction", "apply_checks"]

#: Max relative length error per edge, ``|l - l*| / l*``, of a reproduced target.
LENGTH_RTOL = 1e-5
#: Max dihedral angle error per interior edge (radians) of a reproduced target.
ANGLE_ATOL = 1e-5
#: An edge whose dihedral angle is farther than this from the target's is folded.
FOLD_ANGLE = 0.5 * np.pi
#: Gauss-Newton statuses that mean a converged minimizer (scale-free stopping rules), and 6: the hybrid
#: method spent the smoothing budget it was asked for.
CONVERGED_STATUSES = (1, 2, 3, 4, 6)

#: A converged minimizer that misses an integrable target by more than this relative length or this angle
#: (radians) on some edge is in a wrong local minimum (a failure); closer misses are minima of targets integrable
#: only within :func:`lacore.integrability.check_integrability`'s tolerance (a sweep along a shape model's mode).
LOCAL_MINIMUM_RTOL = 1e-2
LOCAL_MINIMUM_ANGLE = 0.1


@dataclass(frozen=True)
class ReconstructionCheck:
    """Outcome of :func:`check_reconstruction`.

    Attributes
    ----------
    passed : bool
        The result is what was asked for (see the module docstring).
    failure : str
        ``""`` when passed, else one of ``"non_finite"``, ``"folded"``,
        ``"not_converged"`` (a minimizer that neither reproduced the target nor
        converged), ``"not_reproduced"`` (a direct method on a target it does
        not reproduce).
    message : str
        The failure in words (``""`` when passed).
    reproduced : bool
        Residuals within :data:`LENGTH_RTOL` / :data:`ANGLE_ATOL`.
    max_relative_length_error, max_angle_error : float
        ``max |l - l*| / l*`` and ``max |theta - theta*|`` (interior edges).
    folded_edges : (k,) ndarray of int
        Edges farther than :data:`FOLD_ANGLE` from their target angle.
    folded_faces : (m,) ndarray of int
        Faces incident to a folded edge.
    target_integrable : bool or None
        Whether the target satisfies all of Theorem 3.2 (checked when it is not
        reproduced; None when it is).
    target : str
        :meth:`~lacore.integrability.checks.IntegrabilityCheck.describe` of the target (when checked).
    outcome : str
        ``"reproduced"``, ``"closest"`` (passed without reproducing a target that is not integrable: the
        closest mesh), ``"minimum"`` (a converged minimizer that does not reproduce an integrable target: passed
        when it misses by at most :data:`LOCAL_MINIMUM_RTOL` / :data:`LOCAL_MINIMUM_ANGLE`, else failed as a wrong
        local minimum) or ``"failed"``.
    """

    passed: bool
    failure: str
    message: str
    reproduced: bool
    max_relative_length_error: float
    max_angle_error: float
    folded_edges: np.ndarray
    folded_faces: np.ndarray
    target_integrable: object = None
    target: str = ""
    outcome: str = ""

    def summary(self):
        """JSON-friendly dict (counts instead of index arrays)."""
        def num(x):
            return float(x) if np.isfinite(x) else None
        return {"passed": self.passed, "failure": self.failure, "reproduced": self.reproduced,
                "max_relative_length_error": num(self.max_relative_length_error),
                "max_angle_error": num(self.max_angle_error), "folded_edges": int(self.folded_edges.size),
                "folded_faces": int(self.folded_faces.size),
                "length_rtol": LENGTH_RTOL, "angle_atol": ANGLE_ATOL, "outcome": self.outcome,
                "target_integrable": self.target_integrable, "target": self.target}


def check_reconstruction(vertices, z_target, topology, *, minimizer=False, converged=False,
                         length_rtol=LENGTH_RTOL, angle_atol=ANGLE_ATOL):
    """Check a reconstruction against its target (see the module docstring for the rules).

    Parameters
    ----------
    vertices : (V, 3) ndarray
    z_target : (2E,) ndarray
        Validated target lengths and angles.
    topology : MeshTopology
    minimizer : bool
        The method minimizes the energy (``"gn"``, ``"hybrid"``): a converged
        result passes without reproducing the target.
    converged : bool
        The minimizer stopped by a stationarity rule (:data:`CONVERGED_STATUSES`).
    length_rtol, angle_atol : float
        Tolerances of "reproduced".

    Returns
    -------
    ReconstructionCheck
    """
    E = topology.n_edges
    X = np.asarray(vertices, float)
    empty = np.zeros(0, np.int64)
    if not np.all(np.isfinite(X)):
        bad = np.flatnonzero(~np.all(np.isfinite(X), axis=1))
        return ReconstructionCheck(False, "non_finite", f"non-finite coordinates at vertices {format_indices(bad)}",
                                   False, np.inf, np.inf, empty, empty, outcome="failed")
    z = lengths_and_angles(X, topology, check=False)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.abs(z[:E] - z_target[:E]) / z_target[:E]
    ie = topology.interior_edges
    dang = np.abs(wrap_angle(z[E:][ie] - z_target[E:][ie]))
    max_rel = float(np.max(rel)) if rel.size else 0.0
    max_ang = float(np.max(dang)) if dang.size else 0.0
    if not (np.isfinite(max_rel) and np.isfinite(max_ang)):
        return ReconstructionCheck(False, "non_finite", "the output has degenerate triangles (undefined angles)",
                                   False, max_rel, max_ang, empty, empty, outcome="failed")
    folded_edges = np.asarray(ie)[dang > FOLD_ANGLE]
    folded_faces = np.unique(topology.edge_faces[folded_edges].ravel()) if folded_edges.size else empty
    folded_faces = folded_faces[folded_faces >= 0]
    reproduced = max_rel <= length_rtol and max_ang <= angle_atol
    errors = f"max relative length error {max_rel:.3g}, max angle error {max_ang:.3g} rad"
    target, why = {}, ""
    if not reproduced:
        tc = check_integrability(z_target, topology)
        target = {"target_integrable": tc.integrable, "target": tc.describe()}
        if not tc.integrable:
            why = f"; the target is {target['target']} (no mesh has these lengths and angles)"
    if folded_edges.size:
        return ReconstructionCheck(
            False, "folded", f"{folded_faces.size} folded faces (edges {format_indices(folded_edges)} more than "
            f"pi/2 off their target angle); {errors}{why}", reproduced, max_rel, max_ang, folded_edges, folded_faces,
            outcome="failed", **target)
    if reproduced:
        return ReconstructionCheck(True, "", "", True, max_rel, max_ang, empty, empty, outcome="reproduced")
    if (minimizer and converged and target["target_integrable"]
            and (max_rel > LOCAL_MINIMUM_RTOL or max_ang > LOCAL_MINIMUM_ANGLE)):
        return ReconstructionCheck(
            False, "local_minimum", f"a local minimum of the energy that does not reproduce the target, which is "
            f"integrable (a mesh has these lengths and angles: {errors}); start from a shape closer to the target "
            "(initial vertices) or reconstruct it with a tree walk (method 'bfs')", False, max_rel, max_ang, empty,
            empty, outcome="minimum", **target)
    if minimizer and converged:
        outcome = "minimum" if target["target_integrable"] else "closest"
        return ReconstructionCheck(True, "", "", False, max_rel, max_ang, empty, empty, outcome=outcome, **target)
    if minimizer:
        return ReconstructionCheck(
            False, "not_converged", f"neither converged nor reproduced the target ({errors}){why}", False, max_rel,
            max_ang, empty, empty, outcome="failed", **target)
    return ReconstructionCheck(
        False, "not_reproduced", f"the target is not reproduced ({errors} > tolerances {length_rtol:g}, "
        f"{angle_atol:g}){why}; a non-admissible target needs method 'gn' or 'hybrid' (the closest mesh)", False,
        max_rel, max_ang, empty, empty, outcome="failed", **target)


def apply_checks(result, z_target, topology, minimizer):
    """``result`` (a :class:`~lacore.reconstruction.result.ReconstructionResult`) with the checks applied.

    ``success``, ``failure``, ``checks`` and ``message`` are set: on failure the
    solver's reason followed by the failed check; for the closest mesh to a
    target that is not integrable the solver's reason followed by
    ``"; the closest mesh: the target is not integrable ..."``.  ``status``
    keeps the solver's stopping reason.
    """
    check = check_reconstruction(result.vertices, z_target, topology, minimizer=minimizer,
                                 converged=result.status in CONVERGED_STATUSES)
    if not check.passed:
        message = f"{result.message}; check failed: {check.message}"
    elif check.outcome == "closest" and result.status == 6:
        message = (f"{result.message}; an approximation of the closest mesh ({result.iterations} budgeted "
                   f"iterations): the target is {check.target}")
    elif check.outcome == "closest":
        message = f"{result.message}; the closest mesh: the target is {check.target}"
    elif check.outcome == "minimum":
        message = f"{result.message}; a minimum of the energy that does not reproduce the (integrable) target"
    else:
        message = result.message
    return replace(result, success=check.passed, failure=check.failure, message=message, checks=check.summary())
