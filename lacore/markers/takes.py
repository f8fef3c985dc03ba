"""Operations on a take (:class:`lacore.markers.io.MarkerTake`): which of its points are skin markers, and its frames.

* :func:`drop_non_markers`, :func:`select_markers`, :func:`read_take`: the points that are not markers
  (model outputs, virtual and computed points, never-visible repeats) dropped with a note each;
* :func:`inconsistent_samples`, :func:`drop_inconsistent_samples`: stretches of a marker's trajectory that
  its rigid neighbours contradict (a mislabelled or swapped trajectory), made occluded with a note;
* :func:`resample`, :func:`sample_frames`, :func:`visibility_keys`: a take on another frame rate or timeline.
"""

import dataclasses
import warnings

import numpy as np

from .io import MarkerError, MarkerTake, read_markers

__all__ = ["drop_non_markers", "select_markers", "read_take", "resample", "sample_frames", "visibility_keys",
           "inconsistent_samples", "drop_inconsistent_samples", "NEIGHBOURS", "RIGID_SPREAD", "DEVIATION", "JUMP"]


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
       ``rigid_tolerance`` times the take's extent (the diagonal of the box its
       points span; rigidity: the standard deviation of the distances over the
       take): a computed point.  Real markers move against
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
        # the take's extent (diagonal of the box its visible points span): independent of the origin and the unit
        flat = x[finite]
        size = float(np.linalg.norm(flat.max(axis=0) - flat.min(axis=0))) if finite.any() else 0.0
        size = size if np.isfinite(size) and size > 0 else 1.0
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


# ----------------------------------------------------------------------------- samples that contradict their neighbours
#: A marker is checked against this many of its nearest markers (median distance over the take).
NEIGHBOURS = 3
#: ... those whose distance to it is rigid: median absolute deviation at most this fraction of the median.
RIGID_SPREAD = 0.05
#: A stretch contradicts a neighbour when its median distance to it is this fraction off the take's median.
DEVIATION = 0.2
#: A stretch ends where the marker moves against at least half of its visible neighbours by this fraction of
#: their distance in one frame (a label jumping to another point).
JUMP = 0.25


def inconsistent_samples(take):
    """Stretches of marker trajectories that their rigid neighbours contradict.

    A marker's neighbours are the :data:`NEIGHBOURS` markers nearest to it (median
    distance over the take) whose distance to it is rigid over the take (median absolute
    deviation at most :data:`RIGID_SPREAD` of the median): the markers of one cluster or
    one bone.  Its trajectory is cut into stretches at occlusions and at jumps (a frame in
    which it moves against at least half of its visible neighbours by more than :data:`JUMP`
    times their distance).  A stretch is inconsistent when its median distance to a neighbour
    is more than :data:`DEVIATION` off the take's median for most of the neighbours seen with
    it: the label was on another point then (a mislabelled, swapped or gap-filled
    trajectory).  All thresholds are ratios: the test is free of units and scale.  A marker
    right most of the take is kept where it is right: the take's medians come from it.

    Parameters
    ----------
    take : MarkerTake

    Returns
    -------
    list of (str, (K,) int ndarray, list of str)
        Per inconsistent stretch: the marker's label, its frames (0-based) and the
        neighbours it contradicts.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.markers import MarkerTake
    >>> rng = np.random.default_rng(0)
    >>> T = 60
    >>> body = np.array([[0, 0, 0], [.1, 0, 0], [0, .1, 0], [.1, .1, 0], [1, 0, 0], [1, .1, 0], [1.1, 0, 0]])
    >>> x = body + np.linspace(0, 1, T)[:, None, None] * [1, 0, 0] + 1e-4 * rng.standard_normal((T, 7, 3))
    >>> x[20:30, 1] += [0, 0, 0.08]                         # marker 'b' on another point for 10 frames
    >>> take = MarkerTake(labels=list("abcdefg"), positions=x, rate=60.0)
    >>> [(lab, int(f[0]), int(f[-1])) for lab, f, _ in inconsistent_samples(take)]
    [('b', 20, 29)]
    """
    x = np.asarray(take.positions, float)
    T, M, _ = x.shape
    vis = np.isfinite(x[..., 0])
    out = []
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)                 # pairs never seen together
        for m in range(M):
            d = np.linalg.norm(x - x[:, m:m + 1], axis=2)              # (T, M), NaN where either is occluded
            med = np.nanmedian(d, axis=0)
            mad = np.nanmedian(np.abs(d - med), axis=0)
            seen = np.isfinite(d).sum(0)
            order = np.argsort(np.where(np.isfinite(med) & (med > 0), med, np.inf), kind="stable")
            near = [j for j in order[:NEIGHBOURS] if j != m and seen[j] >= 10 and mad[j] <= RIGID_SPREAD * med[j]]
            if not near:
                continue
            near = np.asarray(near)
            rel = x[:, m:m + 1] - x[:, near]
            step = np.linalg.norm(np.diff(rel, axis=0), axis=2) / med[near]   # (T-1, n)
            both = np.isfinite(step)
            jumped = both.any(1) & (2 * (both & (step > JUMP)).sum(1) >= both.sum(1))
            start = vis[:, m] & np.r_[True, ~vis[:-1, m] | jumped]
            stretch = np.where(vis[:, m], np.cumsum(start), 0)
            for s in range(1, int(stretch.max()) + 1):
                f = np.flatnonzero(stretch == s)
                off = np.nanmedian(np.abs(d[f][:, near] - med[near]), axis=0) / med[near]
                known = np.isfinite(off)
                bad = known & (off > DEVIATION)
                if 2 * bad.sum() > known.sum():
                    out.append((take.labels[m], f, [take.labels[j] for j in near[bad]]))
    return out


def drop_inconsistent_samples(take):
    """The take with the stretches of :func:`inconsistent_samples` occluded (NaN), and a note for each.

    Returns
    -------
    take : MarkerTake
        The same take when nothing is inconsistent.
    notes : list of str
        ``"LFT3 frames 0-42 (43) ignored: ..."`` per stretch (0-based frames).

    Examples
    --------
    >>> from lacore.markers import read_take, drop_inconsistent_samples
    >>> take, notes = drop_inconsistent_samples(read_take("Eb015pr.c3d"))     # doctest: +SKIP
    >>> notes                                                                 # doctest: +SKIP
    ['LFT3 frames 0-42 (43) ignored: its distances to LFT1, LFT2 differ from the rest of the take (mislabelled?)']
    """
    found = inconsistent_samples(take)
    if not found:
        return take, []
    pos = take.positions.copy()
    res = None if take.residuals is None else take.residuals.copy()
    index = {lab: i for i, lab in enumerate(take.labels)}
    notes = []
    for lab, f, against in found:
        pos[f, index[lab]] = np.nan
        if res is not None:
            res[f, index[lab]] = np.nan
        notes.append(f"{lab} frames {f[0]}-{f[-1]} ({len(f)}) ignored: its distances to {', '.join(against)} "
                     "differ from the rest of the take (mislabelled?)")
    return dataclasses.replace(take, positions=pos, residuals=res), notes


# ----------------------------------------------------------------------------- resampling
def resample(take, rate):
    """The take resampled to ``rate`` Hz by linear interpolation in time, NaN-aware.

    New sample ``j`` is at time ``j / rate`` (the first sample stays at time 0),
    ``j = 0 .. floor((T - 1) * rate / take.rate)``: the new take never extends
    past the last original sample.  A new sample that falls exactly on an
    original one (to 1e-9 of a sample) copies it; one strictly between two
    originals is their linear interpolation if BOTH are valid and NaN otherwise
    (an occluded sample is never filled in).  Residuals are not resampled
    (``None``); what tells the points apart (descriptions, point groups, the up axis, the
    dropped points' notes) is kept, so :func:`drop_non_markers` finds the same points.

    Parameters
    ----------
    take : MarkerTake
    rate : float
        New rate (Hz), positive.

    Returns
    -------
    MarkerTake
        Same labels, units, source, first frame, descriptions, point groups, up axis and notes;
        positions (T', M, 3).
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
    return dataclasses.replace(take, positions=positions, rate=rate, residuals=None)


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
