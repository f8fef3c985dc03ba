"""A fit's quality on the fitted object: the per-frame marker RMS curve and the summary the panel shows.

Written by Fit to Markers and Calibrate & Fit (:func:`write_quality`), removed by Remove Data
(:func:`remove_quality`).
"""

import numpy as np

from .compat import ensure_animation_channels, id_fcurves
from .operators_markers import _write_curve as write_curve

__all__ = ["FIT_PROP", "RMS_PROP", "write_quality", "settings_text", "remove_quality"]

#: The last fit's quality on the object (take, frames, marker RMS / p95 in mm, prior weight, flagged frames/markers).
FIT_PROP = "lengths_angles_fit"
#: The keyed float property of the fitted object holding the per-frame marker RMS in mm (a curve to look at).
RMS_PROP = "LA marker RMS"


def _distances(result):
    """``(T, M)`` marker distances of a fit result (NaN where occluded)."""
    d = getattr(result, "marker_distances", None)
    if d is None:
        d = np.asarray(result.marker_residuals, float)
        d = np.linalg.norm(d, axis=2) if d.ndim == 3 else d
    return np.asarray(d, float)


def write_quality(obj, frames, result, labels, unit, take_name, settings=None):
    """Store a fit's quality on ``obj`` and describe it.

    * the per-frame curve: the float property :data:`RMS_PROP` (millimetres) keyed at every fitted frame
      (LINEAR; frames without a visible marker get no key), so the Graph Editor and the Dope Sheet show
      where the fit is poor (an existing curve of that property is replaced);
    * ``obj[FIT_PROP]``: take, frame range, marker RMS and p95 (mm: per-frame values averaged over the take),
      prior weight, flagged frames and markers, frames where the surface passes through itself and the markers
      do not (:func:`lacore.markers.interpenetration.new_self_intersections`), and ``settings`` (a dict: the fit's
      other settings, :func:`.operators_fit.recorded_settings`) as ``obj[FIT_PROP]["settings"]``.

    Returns ``{"text": report text, "notes": [warning texts]}``.
    """
    frames = np.asarray(frames)
    mm = 1000.0 * float(unit)
    d = _distances(result) * mm
    seen = np.isfinite(d)
    n = seen.sum(1)
    rms = np.full(len(d), np.nan)
    rms[n > 0] = np.sqrt(np.nansum(d[n > 0] ** 2, axis=1) / n[n > 0])
    # the take's figures as lacore states them (TakeFitResult.marker_rms_mm / marker_p95_mm: per-frame RMS and
    # 95th percentile in mm, averaged over the frames with markers), computed alike when the result has none
    overall = float(np.nanmean(rms)) if (n > 0).any() else float("nan")
    p95 = float(np.nanmean(np.nanpercentile(d[n > 0], 95, axis=1))) if (n > 0).any() else float("nan")
    stated = [getattr(result, name, None) for name in ("marker_rms_mm", "marker_p95_mm")]
    if all(v is not None and np.isfinite(v) for v in stated):
        overall, p95 = map(float, stated)
    flagged_frames = [int(frames[t]) for t in getattr(result, "flagged_frames", [])]
    flagged_markers = [labels[m] if isinstance(m, (int, np.integer)) else str(m)
                       for m in getattr(result, "flagged_markers", [])]
    crossing = [int(frames[t]) for t in getattr(result, "self_intersection_frames", [])]
    prior = float(getattr(result, "prior_weight", float("nan")))
    obj[FIT_PROP] = {"take": take_name, "frame_start": int(frames[0]), "frame_end": int(frames[-1]),
                     "marker_rms_mm": overall, "marker_p95_mm": p95, "prior_weight": prior,
                     "flagged_frames": flagged_frames, "flagged_markers": flagged_markers,
                     "self_intersection_frames": crossing,
                     "success": bool(getattr(result, "success", True))}
    if settings is not None:
        obj[FIT_PROP]["settings"] = dict(settings)
    for name in ("calibration_seconds", "seconds_per_frame"):  # lacore's timings, where it states them
        value = getattr(result, name, None)
        if value is not None and np.isfinite(value):
            obj[FIT_PROP][name] = float(value)
    obj[RMS_PROP] = float(rms[0]) if np.isfinite(rms[0]) else 0.0
    obj.id_properties_ui(RMS_PROP).update(
        min=0.0, description="RMS distance (mm) of the visible markers from the fitted surface in this frame")
    owner, _ = ensure_animation_channels(obj, f"{obj.name} LA fit quality")
    path = f'["{RMS_PROP}"]'
    old = owner.fcurves.find(path)
    if old is not None:
        owner.fcurves.remove(old)
    keyed = np.isfinite(rms)
    write_curve(owner.fcurves, path, 0, frames[keyed].astype(np.float64), rms[keyed], 'LINEAR')
    text = (f"marker RMS {overall:.1f} mm, p95 {p95:.1f} mm, prior weight {prior:g}; per-frame RMS in "
            f"the property '{RMS_PROP}' of '{obj.name}' (Graph Editor)")
    notes = []
    where = [f"at {_count(flagged_frames, 'frame')} ({_listing(flagged_frames)})" if flagged_frames else "",
             f"for {_count(flagged_markers, 'marker')} ({_listing(flagged_markers)})" if flagged_markers else ""]
    if flagged_frames or flagged_markers:
        notes.append(f"residuals far above marker noise {' and '.join(w for w in where if w)}: inspect them")
    if crossing:
        notes.append(f"the surface passes through itself where the markers do not at {_count(crossing, 'frame')} "
                     f"({_listing(crossing)}): inspect them")
    if not getattr(result, "success", True):
        notes.append(f"the fit did not succeed: {getattr(result, 'message', '')}")
    return {"text": text, "notes": notes, "rms": rms, "marker_rms_mm": overall, "marker_p95_mm": p95}


def _count(items, noun):
    """``"1 frame"``, ``"3 frames"``.

    >>> _count([4], "frame"), _count([4, 5], "marker")
    ('1 frame', '2 markers')
    """
    return f"{len(items)} {noun}{'' if len(items) == 1 else 's'}"


def settings_text(settings):
    """The fit's settings stored by :func:`write_quality` in words (the panel's line).

    >>> settings_text({"temporal_weight": 10.0, "penetration_weight": 0.0, "coefficient_weight": 0.1,
    ...                "modes_near_markers": False})
    'Temporal 10, non-penetration off, training range 0.1; modes everywhere'
    >>> settings_text({"temporal_weight": 10.0, "penetration_weight": 10.0, "coefficient_weight": 0.0,
    ...                "modes_near_markers": True, "observed_radius": [0.1, 0.2]})
    'Temporal 10, non-penetration 10, training range off; modes near markers (0.1-0.2 of the size)'
    """
    def weight(name):
        v = float(settings.get(name, 0.0))
        return f"{v:g}" if v > 0 else "off"
    if settings.get("modes_near_markers"):
        r1, r2 = settings.get("observed_radius", (0.0, 0.0))
        modes = f"modes near markers ({float(r1):g}-{float(r2):g} of the size)"
    else:
        modes = "modes everywhere"
    return (f"Temporal {weight('temporal_weight')}, non-penetration {weight('penetration_weight')}, "
            f"training range {weight('coefficient_weight')}; {modes}")


def remove_quality(obj):
    """Remove the last fit's quality (summary, keyed RMS property and its curve) from ``obj``; True if there was
    one."""
    had = FIT_PROP in obj or RMS_PROP in obj
    fcurves = id_fcurves(obj)
    fc = fcurves.find(f'["{RMS_PROP}"]') if fcurves is not None else None
    if fc is not None:
        fcurves.remove(fc)
    for prop in (FIT_PROP, RMS_PROP):
        if prop in obj:
            del obj[prop]
    return had


def _listing(items, n=8):
    items = list(items)
    return ", ".join(map(str, items[:n])) + (f" and {len(items) - n} more" if len(items) > n else "") or "none"
