"""Operations on a take (:class:`lacore.markers.io.MarkerTake`): which of its points are skin markers, and its frames.

* :func:`drop_non_markers`, :func:`select_markers`, :func:`read_take`: the points that are not markers
  (model outputs, virtual and computed points, never-visible repeats) dropped with a note each;
* :func:`resample`, :func:`sample_frames`, :func:`visibility_keys`: a take on another frame rate or timeline.
"""

import numpy as np

from .io import MarkerError, MarkerTake, read_markers

__all__ = ["drop_non_markers", "select_markers", "read_take", "resample", "sample_frames", "visibility_keys"]


# ----------------------------------------------------------------------------- points that are not markers
_VIRTUAL_DESCRIPTION = ("v_", "virtual")
_AXIS_SUFFIXES = ("O", "A", "L", "P")


def select_markers(take, keep, dropped=()):
    """The take restricted to the markers ``keep`` ((M,) bool or indices), with ``dropped`` notes appended."""
    idx = np.flatnonzero(np.asarray(keep, bool)) if np.asarray(keep).dtype == bool else np.asarray(keep, np.int64)
    return MarkerTake(labels=[take.labels[i] for i in idx], positions=take.positions[:, idx], rate=take.rate,
                      first_frame=take.first_frame, units=take.units, source=take.source,
                      residuals=None if take.residuals is None else take.residuals[:, idx],
                      descriptions=[take.descriptions[i] for i in idx],
                      point_groups={take.labels[i]: take.point_groups[take.labels[i]] for i in idx
                                    if take.labels[i] in take.point_groups},
                      up_axis=take.up_axis, dropped=tuple(take.dropped) + tuple(dropped))


def drop_non_markers(take, rigid_tolerance=1e-6):
    """The take without the points that are not skin markers; every drop noted in ``take.dropped``.

    Rules, in this order (the first that applies names the reason):

    1. the label is listed in a POINT group of non-markers (``POINT:TYPE_GROUPS``
       and :data:`NON_MARKER_GROUPS`: model outputs, modelled and virtual
       markers); a repeated label ``X#2`` counts as ``X``;
    2. its description starts with ``V_`` or ``Virtual`` (virtual points);
    3. it is never visible;
    4. it is one of four labels ``P + O, A, L, P`` (origin and axes of a model's
       segment frame, as biomechanical models export them);
    5. it is rigid to two other points that are rigid to each other, to
       ``rigid_tolerance`` times the take's size (standard deviation of the
       distances over the take): a computed point.  Real markers move against
       each other by at least their noise (>= 0.03 mm in the shared takes,
       computed points <= 1e-5 mm).  Not applied when it would leave fewer than
       three markers: a take that moves rigidly as a whole (noise-free synthetic
       data) keeps its points.

    Returns
    -------
    MarkerTake
        With ``dropped`` extended by ``(label, reason)`` pairs.
    """
    M = take.n_markers
    notes = {}
    for m, lab in enumerate(take.labels):
        group = take.point_groups.get(lab)
        if group is not None:
            notes[lab] = f"listed in POINT:{group}: not a marker"
        elif take.descriptions[m].strip().lower().startswith(_VIRTUAL_DESCRIPTION):
            notes[lab] = f"virtual point (description {take.descriptions[m]!r})"
    vis = take.visible
    for m, lab in enumerate(take.labels):
        if lab not in notes and not vis[:, m].any():
            notes[lab] = "never visible"
    labset = set(take.labels)
    for lab in take.labels:
        if lab.endswith("O") and len(lab) > 1:
            quad = [lab[:-1] + s for s in _AXIS_SUFFIXES]
            if all(q in labset for q in quad):
                for q in quad:
                    notes.setdefault(q, f"segment frame of a model ({lab[:-1]}O/A/L/P): not a marker")
    rest = [m for m in range(M) if take.labels[m] not in notes]
    if len(rest) >= 3:
        x = take.positions[:, rest]
        finite = np.isfinite(x[..., 0])
        size = float(np.nanmax(np.abs(x))) if finite.any() else 1.0
        rig = np.zeros((len(rest), len(rest)), bool)
        for i in range(len(rest)):
            d = np.linalg.norm(x[:, i:i + 1] - x, axis=2)              # (T, n) NaN where either is occluded
            n = np.isfinite(d).sum(0)
            with np.errstate(invalid="ignore"):
                mean = np.where(n > 0, np.nansum(d, 0) / np.maximum(n, 1), 0.0)
                sd = np.sqrt(np.where(n > 0, np.nansum((d - mean) ** 2, 0) / np.maximum(n, 1), np.inf))
            rig[i] = (n >= 3) & (sd <= rigid_tolerance * size)
        np.fill_diagonal(rig, False)
        computed = []
        for i in range(len(rest)):
            nb = np.flatnonzero(rig[i])
            if any(rig[b, c] for j, b in enumerate(nb) for c in nb[j + 1:]):
                computed.append(i)
        if len(rest) - len(computed) >= 3:  # else the whole take moves rigidly (noise-free data): keep its points
            for i in computed:
                notes.setdefault(take.labels[rest[i]], "rigid to two other points to rounding error: computed")
    keep = np.array([lab not in notes for lab in take.labels], bool)
    if not keep.any():
        raise MarkerError(f"{take.source or 'marker take'}: no markers left after dropping {M} points that are not "
                          "markers (model outputs, virtual or never visible points)")
    return select_markers(take, keep, [(lab, notes[lab]) for lab in take.labels if lab in notes])


def read_take(path, units=None):
    """:func:`read_markers` followed by :func:`drop_non_markers`: the skin markers of a file, drops noted."""
    return drop_non_markers(read_markers(path, units=units))


# ----------------------------------------------------------------------------- resampling
def resample(take, rate):
    """The take resampled to ``rate`` Hz by linear interpolation in time, NaN-aware.

    New sample ``j`` is at time ``j / rate`` (the first sample stays at time 0),
    ``j = 0 .. floor((T - 1) * rate / take.rate)``: the new take never extends
    past the last original sample.  A new sample that falls exactly on an
    original one (to 1e-9 of a sample) copies it; one strictly between two
    originals is their linear interpolation if BOTH are valid and NaN otherwise
    (an occluded sample is never filled in).  Residuals are not resampled
    (``None``).

    Parameters
    ----------
    take : MarkerTake
    rate : float
        New rate (Hz), positive.

    Returns
    -------
    MarkerTake
        Same labels, units, source and first frame; positions (T', M, 3).
    """
    rate = float(rate)
    if not (np.isfinite(rate) and rate > 0):
        raise MarkerError(f"resample: the new rate must be positive and finite, got {rate!r}")
    T = take.n_frames
    ratio = take.rate / rate  # original samples per new sample
    n_new = int(np.floor((T - 1) / ratio + 1e-9)) + 1
    s = np.arange(n_new) * ratio  # positions in original samples
    i0 = np.floor(s + 1e-9).astype(np.int64)
    frac = s - i0
    exact = np.abs(frac) <= 1e-9
    i0 = np.minimum(i0, T - 1)
    i1 = np.minimum(i0 + 1, T - 1)
    frac = np.where(exact, 0.0, frac)[:, None, None]
    p0, p1 = take.positions[i0], take.positions[i1]
    blended = (1.0 - frac) * p0 + frac * p1  # NaN if either neighbour is NaN
    positions = np.where(exact[:, None, None], p0, blended)
    return MarkerTake(labels=take.labels, positions=positions, rate=rate, first_frame=take.first_frame,
                      units=take.units, source=take.source)


# ----------------------------------------------------------------------------- keys for animation systems
def sample_frames(n_frames, rate, frame_start=1.0, scene_rate=None):
    """Frame numbers at which to key the samples of a take.

    Parameters
    ----------
    n_frames : int
        Number of samples ``T``.
    rate : float
        The take's sample rate (Hz).
    frame_start : float
        Frame of the first sample.
    scene_rate : float, optional
        Frame rate of the target timeline.  ``None`` (or equal to ``rate``): one
        frame per sample.  Otherwise samples are placed by time,
        ``frame_start + i * scene_rate / rate``, on fractional frames: no sample
        is dropped or merged.

    Returns
    -------
    (T,) float64 ndarray
    """
    step = 1.0 if scene_rate is None else float(scene_rate) / float(rate)
    if not (np.isfinite(step) and step > 0):
        raise MarkerError(f"cannot map a {rate!r} Hz take to a {scene_rate!r} fps timeline")
    return float(frame_start) + np.arange(int(n_frames), dtype=np.float64) * step


def visibility_keys(visible):
    """Step keys reproducing each marker's visibility with constant interpolation.

    Parameters
    ----------
    visible : (T, M) bool array_like

    Returns
    -------
    list of M pairs ``(samples, values)``
        ``samples`` (K,) int: the first sample and every sample whose visibility
        differs from the previous one; ``values`` (K,) float64 in {0, 1}: the
        visibility from that sample on.
    """
    vis = np.asarray(visible, dtype=bool)
    if vis.ndim != 2 or vis.shape[0] == 0:
        raise MarkerError(f"visibility must have shape (frames >= 1, markers), got {vis.shape}")
    change = np.ones(vis.shape, bool)
    change[1:] = vis[1:] != vis[:-1]
    out = []
    for m in range(vis.shape[1]):
        idx = np.flatnonzero(change[:, m])
        out.append((idx, vis[idx, m].astype(np.float64)))
    return out


# ----------------------------------------------------------------------------- helpers
