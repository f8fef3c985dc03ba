"""The fit of a whole take with its calibration: :func:`fit_take` and its result, :class:`TakeFitResult`.

:func:`fit_take` ignores the stretches of trajectories that their markers' rigid neighbours
contradict (:func:`lacore.markers.takes.drop_inconsistent_samples`: a warning each; their
residuals are NaN like an occluded marker's), calibrates
(:func:`lacore.markers.calibration.calibrate`, on a static trial if given) unless a
calibration is passed, fits every frame with the calibrated
binding and mean (:func:`lacore.markers.fitting.fit_markers`, the take's own frame rate
for the temporal term), prolongs to the model's fine level if it has one, and reports
residuals in millimetres, flagged frames and markers, frames where the surface passes
through itself and the markers do not (:mod:`lacore.markers.interpenetration`), and
the prior weight used (``prior_weight="auto"``: chosen by held-out markers on the
calibration frames).
"""

import dataclasses
import time
from dataclasses import dataclass, field

import warnings

import numpy as np

from ..errors import InputError
from .binding import MarkerBinding, surface_points
from .calibration import CALIBRATION_DEFAULTS, PRIOR_WEIGHT_CHOICES, Calibration, calibrate, model_pins
from .fitting import FrameSolver, MarkerFitResult, fit_markers, fit_options, marker_statistics
from .interpenetration import new_self_intersections
from .io import MarkerTake
from .takes import drop_inconsistent_samples, drop_non_markers

__all__ = ["fit_take", "TakeFitResult"]


@dataclass(kw_only=True, repr=False)
class TakeFitResult(MarkerFitResult):
    """Outcome of :func:`fit_take` (a :class:`~lacore.markers.fitting.MarkerFitResult`).

    Geometry (``vertices``, ``fine_vertices``, ``markers``, ``marker_residuals``,
    ``frame_rms``...) is in the take's axes and the model's unit, with the performer's
    size (the fitted body scaled by ``calibration.performer_ratio``), i.e. over the take's
    markers converted to model units.

    Attributes
    ----------
    markers : (T, M, 3) ndarray
        The take's positions in model units.
    labels : list of str
    frames : (T,) int ndarray
        Take frames fitted.
    calibration : Calibration
    marker_rms_mm, marker_p95_mm : float
        Mean over frames of the per-frame marker RMS and 95th percentile, millimetres.
    marker_rms_by_marker_mm : (M,) ndarray
        Each marker's RMS over the take, millimetres.
    flagged_frames : list of int
        Take frames whose RMS is far above marker noise (> 3x the take's median and > 10 mm).
    flagged_markers : list of str
        Markers whose RMS is far above the others' (> 3x the median and > 10 mm).
    self_intersections : (T,) int ndarray
        Per frame, the face pairs of the fitted (coarse) mesh that pass through each
        other where the rest mesh does not and the markers show no contact
        (:func:`lacore.markers.interpenetration.new_self_intersections`).
    self_contacts : (T,) int ndarray
        New face pairs at two markers in contact (closer than their offsets): expected, not flagged.
    self_intersection_pairs : list of (P_t, 2) int ndarray
        The pairs counted by ``self_intersections``.
    self_intersection_frames : list of int
        Take frames with ``self_intersections > 0``: a quality warning, not a failure
        (``success`` keeps its meaning: every frame converged to the markers).
    warnings : list of str
        One line per flag.
    seconds_per_frame : float
        Fitting time per frame (calibration not included).
    calibration_seconds : float
    """

    markers: np.ndarray = None
    labels: list = field(default_factory=list)
    frames: np.ndarray = None
    calibration: Calibration = None
    marker_rms_mm: float = float("nan")
    marker_p95_mm: float = float("nan")
    marker_rms_by_marker_mm: np.ndarray = None
    flagged_frames: list = field(default_factory=list)
    flagged_markers: list = field(default_factory=list)
    self_intersections: np.ndarray = None
    self_contacts: np.ndarray = None
    self_intersection_pairs: list = field(default_factory=list)
    self_intersection_frames: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    seconds_per_frame: float = float("nan")
    calibration_seconds: float = 0.0
    _summary_exclude = MarkerFitResult._summary_exclude + ("markers", "calibration", "self_intersection_pairs")

    @property
    def binding(self):
        """The calibration's binding at the result's size (offsets times the performer ratio).

        ``surface_points(vertices[t], faces, binding) - markers[t]`` is ``marker_residuals[t]``
        (model's coarse faces).
        """
        b = self.calibration.binding
        return MarkerBinding(b.faces, b.barycentric, b.offsets * self.calibration.performer_ratio, b.vertices)

    def summary(self):
        """JSON-ready dict: :meth:`MarkerFitResult.summary` plus the take's figures."""
        s = super().summary()

        def f(x):
            return None if x is None or not np.isfinite(x) else float(x)
        s.update(marker_rms_mm=f(self.marker_rms_mm), marker_p95_mm=f(self.marker_p95_mm),
                 flagged_frames=[int(t) for t in self.flagged_frames], flagged_markers=list(self.flagged_markers),
                 self_intersection_frames=[int(t) for t in self.self_intersection_frames],
                 warnings=list(self.warnings), seconds_per_frame=f(self.seconds_per_frame),
                 calibration_seconds=f(self.calibration_seconds), markers=len(self.labels),
                 performer_ratio=f(self.calibration.performer_ratio) if self.calibration else None,
                 length_unit=f(self.calibration.length_unit) if self.calibration else None,
                 notes=list(self.calibration.notes) if self.calibration else [])
        return s


# ----------------------------------------------------------------------------- helpers


def _auto_prior_weight(model, cal, y_frames, fo, notes):
    """The candidate of :data:`PRIOR_WEIGHT_CHOICES` with the least error on held-out markers (calibration frames)."""
    M = y_frames.shape[1]
    rng = np.random.default_rng(0)
    folds = np.array_split(rng.permutation(M), 4)
    errors = []
    for g in PRIOR_WEIGHT_CHOICES:
        opts = dataclasses.replace(fo, prior_weight=g)
        sq, n = 0.0, 0
        for held in folds:
            y = y_frames.copy()
            y[:, held] = np.nan
            solver = FrameSolver(model, cal.binding, opts, mean_z=cal.mean_z)
            for i in range(len(y)):
                X, _, _, _, _ = solver.solve_frame(cal.poses[i], cal.coefficients[i], y[i])
                d = surface_points(X, model.faces, cal.binding)[held] - y_frames[i, held]
                ok = np.isfinite(d[:, 0])
                sq += float(np.sum(d[ok] ** 2))
                n += int(ok.sum())
        errors.append(np.sqrt(sq / max(n, 1)) / cal.scale * 1000)
    best = PRIOR_WEIGHT_CHOICES[int(np.argmin(errors))]
    notes.append("prior_weight auto: " + ", ".join(f"{g:g}: {e:.2f} mm" for g, e in
                                                   zip(PRIOR_WEIGHT_CHOICES, errors, strict=True)) + f" -> {best:g}")
    return best


def frame_indices(frames, n_frames):
    """The frames of a take of ``n_frames`` that ``frames`` selects, as ``(k,)`` int64 indices.

    ``frames``: None (all), a slice, indices in ``0..n_frames-1`` or a boolean mask of ``n_frames``; anything
    else (negative or too large indices, fractions, a mask of another length) is an :class:`InputError`.

    >>> frame_indices(slice(2, 5), 10), frame_indices([0, 9], 10)
    (array([2, 3, 4]), array([0, 9]))
    """
    if frames is None:
        return np.arange(n_frames)
    if isinstance(frames, slice):
        return np.arange(n_frames)[frames]
    f = np.atleast_1d(np.asarray(frames))
    what = (f"frames must be a slice, frame indices in 0..{n_frames - 1} or a boolean mask of {n_frames} frames, "
            "got ")
    if f.dtype == bool:
        if f.shape != (n_frames,):
            raise InputError(what + f"a mask of shape {f.shape}")
        return np.flatnonzero(f)
    if f.ndim != 1 or f.dtype.kind not in "iu":
        raise InputError(what + (f"{f.dtype} values" if f.ndim == 1 else f"shape {f.shape}"))
    bad = f[(f < 0) | (f >= n_frames)]
    if bad.size:
        raise InputError(what + f"{bad[0]}")
    return f.astype(np.int64)


def fit_take(model, take, calibration=None, options=None, *, frames=None, static=None, calibration_options=None,
             pins=None, progress=None):
    """Calibrate (unless given) and fit every frame of a take; full resolution if the model has a fine level.

    Parameters
    ----------
    model : lacore.models.ShapeModel
    take : MarkerTake
        Positions in metres (:func:`lacore.markers.takes.read_take`).
    calibration : Calibration, optional
        Default: :func:`calibrate` on ``static`` if given, else on the take.
    options : FitOptions, optional
        Default :data:`lacore.markers.fitting.FIT_DEFAULTS`; ``prior_weight="auto"``
        picks from :data:`PRIOR_WEIGHT_CHOICES` by held-out markers.
    frames : slice or array_like of int or bool, optional
        Take frames to fit (default all; :func:`frame_indices`).
    static : MarkerTake, optional
        A static trial to calibrate on.
    calibration_options : CalibrationOptions, optional
    pins : dict of str -> int, optional
        Marker label -> vertex of the mesh the fit returns (full resolution with a fine level): what places a
        character whose markers have no standard names (:func:`~lacore.markers.calibration.model_pins`); 3 or more
        seen at the first calibration frame.  Only when the take is calibrated here.
    progress : callable, optional
        ``progress(done, total, message)`` over calibration and frames (:mod:`lacore.progress`).

    Returns
    -------
    TakeFitResult
        ``success`` as :func:`fit_markers` (every frame converged, something fitted);
        frames far from the markers, markers far from the surface and frames where the
        surface passes through itself with no marker contact are warnings
        (``warnings``; the last also a clause of ``message``), not failures: the fit
        still follows the markers, and the frames say where to look.

    Examples
    --------
    >>> from lacore.markers import read_take, fit_take
    >>> from lacore.samples.human import human_model
    >>> res = fit_take(human_model(), read_take("Walk1.c3d"), frames=slice(0, 30))  # doctest: +SKIP
    >>> res.success, res.marker_rms_mm < 6, res.fine_vertices.shape                   # doctest: +SKIP
    (True, True, (30, 13380, 3))
    """
    t_start = time.perf_counter()
    fo = fit_options(options, allow_auto=True)
    if not isinstance(take, MarkerTake):
        raise InputError(f"take must be a MarkerTake (lacore.markers.read_take), got {type(take).__name__}")
    take, ignored = drop_inconsistent_samples(drop_non_markers(take))
    T_all = take.n_frames
    idx = frame_indices(frames, T_all)
    if not len(idx):
        raise InputError(f"frames={frames!r} selects no frame of the take (frames 0 to {T_all - 1})")
    n_cal = 2 + (calibration_options or CALIBRATION_DEFAULTS).rounds if calibration is None else 0
    total = n_cal + len(idx)

    def shifted(offset):
        if progress is None:
            return None
        return lambda done, _total, message: progress(offset + done, total, message)

    if calibration is None:
        calibration = calibrate(model, static if static is not None else take, calibration_options, fit=fo,
                                pins=model_pins(model, pins) if pins else None, progress=shifted(0))
    elif pins:
        raise InputError("pins place the model when the take is calibrated: give them to calibrate(), or no "
                         "calibration")
    cal = calibration
    notes = list(cal.notes) + [n for n in ignored if n not in cal.notes]
    missing = [lab for lab in cal.labels if lab not in take.labels]
    if missing:
        raise InputError(f"the calibration's markers {', '.join(missing)} are not in the take")
    extra = [lab for lab in take.labels if lab not in cal.labels]
    if extra:
        notes.append(f"markers not calibrated, left out: {', '.join(extra)}")
    order = [take.labels.index(lab) for lab in cal.labels]
    x = take.positions[idx][:, order]
    k, u = cal.scale, cal.length_unit
    y = x * k
    if isinstance(fo.prior_weight, str):
        fo = dataclasses.replace(fo, prior_weight=_auto_prior_weight(
            model, cal, take.positions[cal.frames][:, order] * k, fo, notes))
    X0, a0 = cal.start(int(idx[0]))
    t_fit = time.perf_counter()
    res = fit_markers(model, y, cal.binding, fo, rate=take.rate, initial_vertices=X0, initial_coefficients=a0,
                      prolongation=model.fine_level, mean_z=cal.mean_z, progress=shifted(n_cal))
    fit_seconds = time.perf_counter() - t_fit
    c = 1.0 / (k * u)                                   # fitted (body-size) units -> model units at performer size
    dist_m = res.marker_distances / k
    stats = marker_statistics(dist_m)
    frame_rms_mm = stats["frame_rms"] * 1000
    frame_p95_mm = stats["frame_p95"] * 1000
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # markers occluded in every frame
        by_marker = np.sqrt(np.nanmean(dist_m ** 2, axis=0)) * 1000
    flagged_frames, flagged_markers, warns = [], [], list(ignored)
    n_markers, n_unknowns = len(cal.labels), model.n_modes + 6
    if 3 * n_markers < n_unknowns:
        warns.append(f"only {n_markers} markers: {3 * n_markers} coordinates for {model.n_modes} modes and the "
                     f"rigid placement ({n_unknowns} unknowns); the poses follow the model's prior more than the "
                     "markers (full-body marker sets have 35-60)")
    if np.isfinite(frame_rms_mm).any():
        med = float(np.nanmedian(frame_rms_mm))
        bad = np.flatnonzero(frame_rms_mm > max(3 * med, 10.0))
        flagged_frames = [int(idx[t]) for t in bad]
        if len(bad):
            warns.append(f"{len(bad)} frame(s) with marker RMS far above the take's ({med:.1f} mm median): "
                         + ", ".join(f"{int(idx[t])} ({frame_rms_mm[t]:.0f} mm)" for t in bad[:10])
                         + (" ..." if len(bad) > 10 else ""))
    if np.isfinite(by_marker).any():
        medm = float(np.nanmedian(by_marker))
        badm = np.flatnonzero(by_marker > max(3 * medm, 10.0))
        flagged_markers = [cal.labels[m] for m in badm]
        if len(badm):
            warns.append("markers far from the surface (RMS): " + ", ".join(
                f"{cal.labels[m]} ({by_marker[m]:.0f} mm)" for m in badm))
    t_si = time.perf_counter()
    si = new_self_intersections(res.vertices, model.faces, cal.binding, y, model.reference_vertices)
    si_frames = [int(idx[t]) for t in si.frames]
    message = res.message
    if si_frames:
        near = np.concatenate([m for m in si.nearest_marker if len(m)])
        labels, n = np.unique(near, return_counts=True)
        where = ", ".join(cal.labels[m] if m >= 0 else "none near" for m in labels[np.argsort(-n, kind="stable")][:4])
        warns.append(f"{len(si_frames)} frame(s) where the surface passes through itself and the markers do not "
                     f"(up to {int(si.counts.max())} face pairs, nearest markers {where}): "
                     + ", ".join(str(t) for t in si_frames[:10]) + (" ..." if len(si_frames) > 10 else ""))
        message += f"; the surface passes through itself in {len(si_frames)} frame(s)"
    timings = dict(res.timings, calibration=cal.seconds, self_intersections=time.perf_counter() - t_si,
                   total=time.perf_counter() - t_start)
    fields_ = {f.name: getattr(res, f.name) for f in dataclasses.fields(MarkerFitResult)}
    fields_.update(
        vertices=res.vertices * c, marker_residuals=res.marker_residuals * c, marker_distances=res.marker_distances * c,
        frame_rms=res.frame_rms * c, frame_p95=res.frame_p95 * c, marker_rms=res.marker_rms * c,
        fine_vertices=None if res.fine_vertices is None else res.fine_vertices * c, timings=timings,
        prior_weight=float(fo.prior_weight), message=message)
    out = TakeFitResult(**fields_, markers=x / u, labels=list(cal.labels), frames=idx, calibration=cal,
                        marker_rms_mm=float(np.nanmean(frame_rms_mm)) if np.isfinite(frame_rms_mm).any() else np.nan,
                        marker_p95_mm=float(np.nanmean(frame_p95_mm)) if np.isfinite(frame_p95_mm).any() else np.nan,
                        marker_rms_by_marker_mm=by_marker, flagged_frames=flagged_frames,
                        flagged_markers=flagged_markers, self_intersections=si.counts, self_contacts=si.contact_counts,
                        self_intersection_pairs=si.pairs, self_intersection_frames=si_frames, warnings=warns,
                        seconds_per_frame=fit_seconds / len(idx), calibration_seconds=cal.seconds)
    out.calibration = dataclasses.replace(cal, notes=notes)
    return out
