"""Reading and writing motion-capture marker trajectories (C3D and TRC).

A *take* (:class:`MarkerTake`) is ``T`` frames of ``M`` labelled 3-D marker
positions sampled at ``rate`` Hz, always in **metres**, with ``NaN`` where a
marker was occluded or its sample is flagged invalid.  Readers convert from the
file's own unit (C3D ``POINT:UNITS``, the TRC header's ``Units``); the original
unit string is kept in :attr:`MarkerTake.units`.

C3D (https://www.c3d.org)
    Header and parameter section are parsed by the pure-Python ``c3d`` package
    (imported on first use); the point data are then decoded here in one
    vectorized pass over the whole data section (the package's
    ``Reader.read_frames`` yields one frame at a time; benchmarks/bench_markers.py
    compares the two).  All three
    processor formats (Intel, DEC/VAX, SGI/MIPS) and both storages (16-bit
    integers times ``POINT:SCALE``, 32-bit floats when ``POINT:SCALE < 0``)
    are handled.  A sample is invalid (``NaN``) when its residual word is
    negative (the C3D convention) or a coordinate is NaN (Vicon writes NaN
    with residual 0 for points it could not compute).  An infinite
    coordinate is not something exporters write: the file is refused as
    damaged, naming the marker and the frame.  Entries that
    are model outputs rather than markers (their labels listed in
    ``POINT:ANGLES``, ``FORCES``, ``MOMENTS``, ``POWERS``, ``SCALARS``, see
    :data:`MODEL_OUTPUT_GROUPS`) are skipped.
TRC (OpenSim / Motion Analysis ``PathFileType 4``)
    Tab-separated text; empty fields (or ``NaN``) are occluded samples, and so
    are the fields missing at the end of a row (exporters leave out the
    trailing tabs of occluded markers), on any row, the last one included.  A
    row without its Frame# or Time, or with a number beyond the header's
    columns, is refused naming its line.  An infinite coordinate (``inf``, or
    a number beyond float64's range such as ``1e999``) is refused as damage,
    naming the marker and the frame.  A file cut short is refused: fewer data
    rows than the header's ``NumFrames``, or a last row that lacks the final
    line break and ends inside a marker (some but not all of its X, Y, Z; a
    row ending after a whole marker is read, and so is a last number that may
    be cut, which no reader can tell).

Labels are made unique and non-empty (C3D files do repeat labels): a blank
label becomes ``"POINT<n>"`` (``n`` the 1-based entry in the file) and the
``k``-th repeat of a label gets ``"#k"`` appended (``"RKNE"``, ``"RKNE#2"``).

Every problem with a file raises :class:`MarkerFileError` (an
:class:`~lacore.errors.InputError`) naming the file, what is wrong and what to do.
"""

import io
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..io.atomic import atomic_write

__all__ = ["MarkerTake", "MarkerError", "MarkerFileError", "read_markers", "read_c3d", "read_trc", "write_c3d",
           "write_trc", "unit_scale", "read_marker_arrays", "MODEL_OUTPUT_GROUPS", "UNIT_SCALES",
           "COMMON_UNITS", "NON_MARKER_GROUPS"]

#: POINT parameters whose labels name model outputs (angles, forces...), not markers.
MODEL_OUTPUT_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS")
#: POINT parameters listing points that are not markers (besides the groups POINT:TYPE_GROUPS names).
NON_MARKER_GROUPS = MODEL_OUTPUT_GROUPS + ("REACTIONS", "MODELED_MARKERS", "MODELLED_MARKERS", "VIRTUAL_MARKERS",
                                           "CALCULATED_MARKERS")

#: Length units (lower case) and their size in metres.
UNIT_SCALES = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "dm": 0.1, "km": 1e3, "um": 1e-6, "\u00b5m": 1e-6,
               "in": 0.0254, "inch": 0.0254, "inches": 0.0254, "ft": 0.3048, "feet": 0.3048,
               "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0, "millimeter": 1e-3,
               "millimeters": 1e-3, "millimetre": 1e-3, "millimetres": 1e-3, "centimeter": 1e-2,
               "centimeters": 1e-2, "centimetre": 1e-2, "centimetres": 1e-2}

#: The units lengths are commonly given in (keys of :data:`UNIT_SCALES`): what help texts list and what a unit
#: mismatch names.
COMMON_UNITS = ("mm", "cm", "dm", "m", "in", "ft")

_C3D_MAGIC = 0x50
#: What a C3D reader error tells the user to do when the file itself is damaged.
_C3D_AGAIN = "export the take again from the capture software"
_TRC_AGAIN = "export the take again"
_PROCESSORS = {84: "Intel", 85: "DEC", 86: "SGI/MIPS"}


class MarkerError(InputError):
    """A marker take (arrays, rate, labels) is not valid."""


class MarkerFileError(MarkerError):
    """A marker file cannot be read or written; the message names the file and the problem."""


@dataclass(frozen=True, eq=False)
class MarkerTake:
    """Labelled marker trajectories of one recording.

    Attributes
    ----------
    labels : (M,) tuple of str
        Unique, non-empty marker labels.
    positions : (T, M, 3) float64 ndarray
        Positions in metres; ``NaN`` (all three coordinates) where the marker is
        occluded or the sample is invalid.
    rate : float
        Frames per second (Hz).
    first_frame : int
        Number of the first frame in the recording (C3D counts from 1).
    units : str
        The unit the file stored positions in (``"mm"``, ``"m"``...); positions
        here are always metres.
    source : str
        Where the take came from (file path), for messages and metadata.
    residuals : (T, M) float64 ndarray or None
        Per-sample residual (reconstruction error estimate) in metres, ``NaN``
        where invalid; ``None`` if the format has none (TRC).
    descriptions : (M,) tuple of str
        Point descriptions (C3D ``POINT:DESCRIPTIONS``; empty strings if none).
    point_groups : dict
        ``{label: group}`` for labels the file lists in a POINT group of
        non-markers (``POINT:TYPE_GROUPS``, ``MODELED_MARKERS``, ...; see
        :data:`NON_MARKER_GROUPS`).
    up_axis : str or None
        The vertical axis the file declares (C3D ``POINT:Y_SCREEN``, e.g. ``"+z"``).
    dropped : tuple of (str, str)
        ``(label, reason)`` of the points :func:`drop_non_markers` removed.
    """

    labels: tuple
    positions: np.ndarray
    rate: float
    first_frame: int = 1
    units: str = "m"
    source: str = ""
    residuals: np.ndarray = field(default=None)
    descriptions: tuple = None
    point_groups: dict = None
    up_axis: str = None
    dropped: tuple = ()

    def __post_init__(self):
        labels = tuple(str(s) for s in self.labels)
        pos = np.asarray(self.positions, dtype=np.float64)
        what = f"marker take {self.source!r}" if self.source else "marker take"
        if pos.ndim != 3 or pos.shape[2] != 3:
            raise MarkerError(f"{what}: positions must have shape (frames, markers, 3), got {pos.shape}")
        if len(labels) != pos.shape[1]:
            raise MarkerError(f"{what}: {len(labels)} labels for {pos.shape[1]} markers")
        if len(set(labels)) != len(labels) or any(not s for s in labels):
            raise MarkerError(f"{what}: labels must be unique and non-empty")
        if not (np.isfinite(self.rate) and self.rate > 0):
            raise MarkerError(f"{what}: frame rate must be positive and finite, got {self.rate!r}")
        # a sample is either fully valid or fully missing
        pos = pos.copy()
        pos[~np.isfinite(pos).all(axis=2)] = np.nan
        res = None
        if self.residuals is not None:
            res = np.asarray(self.residuals, dtype=np.float64)
            if res.shape != pos.shape[:2]:
                raise MarkerError(f"{what}: residuals have shape {res.shape}, expected {pos.shape[:2]}")
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "rate", float(self.rate))
        object.__setattr__(self, "first_frame", int(self.first_frame))
        object.__setattr__(self, "residuals", res)
        desc = ("",) * len(labels) if self.descriptions is None else tuple(str(d) for d in self.descriptions)
        if len(desc) != len(labels):
            raise MarkerError(f"{what}: {len(desc)} descriptions for {len(labels)} markers")
        object.__setattr__(self, "descriptions", desc)
        object.__setattr__(self, "point_groups", dict(self.point_groups or {}))
        object.__setattr__(self, "dropped", tuple((str(a), str(b)) for a, b in self.dropped))

    @property
    def n_frames(self):
        """Number of frames ``T``."""
        return self.positions.shape[0]

    @property
    def n_markers(self):
        """Number of markers ``M``."""
        return self.positions.shape[1]

    @property
    def visible(self):
        """(T, M) bool: True where the marker has a valid position."""
        return ~np.isnan(self.positions[:, :, 0])

    @property
    def times(self):
        """(T,) float64: time of each frame in seconds, 0 at the first frame."""
        return np.arange(self.n_frames) / self.rate


def unit_scale(units, path=""):
    """Size in metres of the length unit ``units`` (e.g. ``"mm"`` -> 0.001); MarkerFileError if unknown."""
    key = str(units).strip().strip("\x00").strip().lower()
    if key not in UNIT_SCALES:
        where = f"{path}: " if path else ""
        raise MarkerFileError(f"{where}unknown length unit {units!r} (known: mm, cm, dm, m, in, ft); "
                              "pass units= to override")
    return UNIT_SCALES[key]


def _unique_labels(labels):
    """Blank labels -> ``POINT<n>``; repeats -> ``label#k`` (see the module docstring)."""
    out, seen = [], set()
    counts = {}
    for i, s in enumerate(labels):
        s = s.strip() or f"POINT{i + 1}"
        counts[s] = counts.get(s, 0) + 1
        name, k = s, counts[s]
        while name in seen:
            name = f"{s}#{k}"
            k += 1
        seen.add(name)
        out.append(name)
    return out


def _dec_to_ieee(raw):
    """DEC F-floats (uint8 bytes, 4 per value) -> IEEE float32, as the ``c3d`` package decodes them.

    A DEC F-float has the IEEE layout with its two 16-bit words swapped and a value
    a quarter of the IEEE reading (exponent bias 128, hidden bit before the point):
    swap the words, lower the exponent by 2 (leaving exponent 0, DEC's zero, alone).
    """
    b = np.asarray(raw, dtype=np.uint8).reshape(-1, 4)
    out = np.empty_like(b)
    out[:, 0], out[:, 1], out[:, 2] = b[:, 2], b[:, 3], b[:, 0]
    high = b[:, 1]
    out[:, 3] = high + ((high & 0x7F) == 0) - 1  # sign + top exponent bits; -1 here is -2 on the exponent
    return out.reshape(-1).view("<f4")


def _read_bytes(path):
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise MarkerFileError(f"{path}: cannot read the file ({exc.strerror or exc})") from None


def _import_c3d():
    try:
        import c3d
    except ImportError:  # pragma: no cover - c3d is a declared dependency
        raise MarkerFileError("reading C3D files needs the 'c3d' package (pip install c3d)") from None
    return c3d


# ----------------------------------------------------------------------------- dispatch
def read_markers(path, units=None):
    """Read a marker file, C3D or TRC, recognised by its content (not its extension).

    Parameters
    ----------
    path : str or os.PathLike
    units : str, optional
        Override the file's length unit (e.g. when a C3D file lacks ``POINT:UNITS``).

    Returns
    -------
    MarkerTake
    """
    data = _read_bytes(path)
    if len(data) >= 2 and data[1] == _C3D_MAGIC and not data[:20].lstrip().lower().startswith(b"pathfiletype"):
        return _read_c3d_bytes(data, str(path), units)
    if data.lstrip()[:12].lower() == b"pathfiletype":
        return _read_trc_text(data, str(path), units)
    raise MarkerFileError(f"{path}: neither a C3D file (byte 2 is {data[1] if len(data) > 1 else 'missing'}, "
                          f"expected {_C3D_MAGIC}) nor a TRC file (no 'PathFileType' header): choose a .c3d or .trc "
                          "marker file, or export the take again in one of these formats")


# ----------------------------------------------------------------------------- C3D
def read_c3d(path, units=None):
    """Read the markers of a C3D file (see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
    units : str, optional
        Override ``POINT:UNITS``.

    Returns
    -------
    MarkerTake
        positions (T, M, 3) metres, NaN where invalid; residuals (T, M) metres.
    """
    return _read_c3d_bytes(_read_bytes(path), str(path), units)


def _c3d_reader(data, path):
    """The ``c3d.Reader`` of the header and parameter section, with clear errors for non-C3D input."""
    c3d = _import_c3d()
    if len(data) < 512:
        raise MarkerFileError(f"{path}: not a C3D file or truncated: {len(data)} bytes, a C3D header alone is 512; "
                              f"copy the whole file again or {_C3D_AGAIN}")
    if data[1] != _C3D_MAGIC:
        raise MarkerFileError(f"{path}: not a C3D file (byte 2 is {data[1]}, expected {_C3D_MAGIC}): choose a .c3d "
                              f"file, or {_C3D_AGAIN}")
    param_block = data[0]
    proc_at = (param_block - 1) * 512 + 3
    if param_block < 2 or proc_at >= len(data):
        raise MarkerFileError(f"{path}: truncated or malformed C3D file: the parameter section (block {param_block}) "
                              f"is not inside the file ({len(data)} bytes): copy the whole file again or "
                              f"{_C3D_AGAIN}")
    if data[proc_at] not in _PROCESSORS:
        raise MarkerFileError(f"{path}: malformed C3D file: unknown processor type {data[proc_at]} "
                              f"(expected 84 Intel, 85 DEC or 86 SGI/MIPS): {_C3D_AGAIN}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return c3d.Reader(io.BytesIO(data))
    except Exception as exc:  # the package raises assorted errors on malformed parameter sections
        raise MarkerFileError(f"{path}: malformed C3D parameter section ({type(exc).__name__}: {exc}): "
                              f"{_C3D_AGAIN}") from None


def _c3d_strings(reader, name):
    """All strings of a (possibly multi-part, e.g. LABELS, LABELS2...) string parameter ``POINT:<name>``."""
    out = []
    for key in [name] + [f"{name}{k}" for k in range(2, 100)]:
        param = reader.get(f"POINT:{key}")
        if param is None:
            if key != name:
                break
            continue
        if not param.dimensions:
            continue
        arr = np.atleast_1d(param.string_array) if len(param.dimensions) > 1 else [param.string_value]
        out.extend(str(s).strip() for s in np.ravel(arr))
    return out


def _read_c3d_bytes(data, path, units):
    reader = _c3d_reader(data, path)
    proc = data[(data[0] - 1) * 512 + 3]
    try:
        used = int(reader.point_used)
        scale = float(reader.point_scale)
        rate = float(reader.point_rate)
        first, last = int(reader.first_frame), int(reader.last_frame)
        analog_used = int(reader.analog_used)
        analog_rate = float(reader.analog_rate) if analog_used else 0.0
        data_block = int(reader.header.data_block)
        unit_param = reader.get("POINT:UNITS")
        file_units = unit_param.string_value.strip().strip("\x00").strip() if unit_param is not None else ""
    except Exception as exc:
        raise MarkerFileError(f"{path}: malformed C3D parameters ({type(exc).__name__}: {exc}): "
                              f"{_C3D_AGAIN}") from None
    # checked here, not left to the c3d package: it checks some of these with assert, which python -O skips
    if not np.isfinite(rate) or rate <= 0:
        raise MarkerFileError(f"{path}: invalid point rate {rate!r} Hz (POINT:RATE must be a positive number): "
                              f"{_C3D_AGAIN}")
    if not np.isfinite(scale) or scale == 0:
        raise MarkerFileError(f"{path}: invalid POINT:SCALE {scale!r} (a finite non-zero number; negative for float "
                              f"storage): {_C3D_AGAIN}")
    if used < 1:
        raise MarkerFileError(f"{path}: the file has no 3-D points (POINT:USED is {used}): export the take again "
                              "with its markers (trajectories), not only analog or force data")
    if analog_used < 0 or (analog_used and not (np.isfinite(analog_rate) and analog_rate >= 0)):
        raise MarkerFileError(f"{path}: invalid analog channels: ANALOG:USED {analog_used}, ANALOG:RATE "
                              f"{analog_rate!r} Hz (a damaged file: the rate must be a finite number >= 0): "
                              f"{_C3D_AGAIN}")
    n_frames = last - first + 1
    if n_frames < 1:
        raise MarkerFileError(f"{path}: no frames (first frame {first}, last {last}): export the take again with "
                              "its frame range")
    if units is None and not file_units:
        raise MarkerFileError(f"{path}: no POINT:UNITS parameter: give the unit (units='mm' in Python, --units mm "
                              f"in the CLI) or {_C3D_AGAIN}")
    to_metres = unit_scale(units if units is not None else file_units, path)

    is_float = scale < 0
    word = 4 if is_float else 2
    analog_per_frame = int(round(analog_rate / rate)) if analog_used else 0
    point_bytes = 4 * used * word
    frame_bytes = point_bytes + analog_used * analog_per_frame * word
    start = (data_block - 1) * 512
    need = start + n_frames * frame_bytes
    if data_block < 2 or len(data) < need:
        complete = max(0, (len(data) - start) // frame_bytes) if frame_bytes else 0
        raise MarkerFileError(f"{path}: truncated C3D file: {n_frames} frames of {used} points need {need} bytes, "
                              f"the file has {len(data)} (only {min(complete, n_frames)} complete frames): copy the "
                              f"whole file again or {_C3D_AGAIN}")

    block = np.frombuffer(data, dtype=np.uint8, count=n_frames * frame_bytes, offset=start)
    raw_bytes = np.ascontiguousarray(block.reshape(n_frames, frame_bytes)[:, :point_bytes])
    if is_float:
        if proc == 85:
            words = _dec_to_ieee(raw_bytes)
        else:
            words = raw_bytes.view(">f4" if proc == 86 else "<f4")
        words = words.reshape(n_frames, used, 4)
        xyz = words[:, :, :3].astype(np.float64)
        w4 = words[:, :, 3].astype(np.float64)
        finite4 = np.isfinite(w4)
        last_word = np.clip(np.where(finite4, w4, -1.0), -2.0 ** 31, 2.0 ** 31 - 1).astype(np.int64)
        invalid = ~finite4
    else:
        words = raw_bytes.view(">i2" if proc == 86 else "<i2").reshape(n_frames, used, 4)
        xyz = words[:, :, :3].astype(np.float64) * abs(scale)
        last_word = words[:, :, 3].astype(np.int64)
        invalid = np.zeros(last_word.shape, bool)
    invalid |= last_word < 0
    flagged = invalid.copy()  # invalid by the residual word: its coordinates mean nothing
    invalid |= ~np.isfinite(xyz).all(axis=2)
    residuals = (last_word & 0xFF).astype(np.float64) * abs(scale) * to_metres
    positions = xyz * to_metres
    positions[invalid] = np.nan
    residuals[invalid] = np.nan

    labels = _c3d_strings(reader, "LABELS")[:used]
    labels += [""] * (used - len(labels))
    descriptions = _c3d_strings(reader, "DESCRIPTIONS")[:used]
    descriptions += [""] * (used - len(descriptions))
    groups = {}
    for group in dict.fromkeys(NON_MARKER_GROUPS + tuple(g.upper() for g in _c3d_strings(reader, "TYPE_GROUPS"))):
        for s in _c3d_strings(reader, group):
            if s:
                groups.setdefault(s, group)
    screen = reader.get("POINT:Y_SCREEN")
    up_axis = screen.string_value.strip().lower() if screen is not None and screen.dimensions else None
    up_axis = up_axis if up_axis in ("+x", "-x", "+y", "-y", "+z", "-z") else None
    model_outputs = set()
    for group in MODEL_OUTPUT_GROUPS:
        model_outputs.update(s for s in _c3d_strings(reader, group) if s)
    keep = np.array([s.strip() not in model_outputs for s in labels], bool)
    if not keep.any():
        raise MarkerFileError(f"{path}: all {used} points are model outputs (POINT:{'/'.join(MODEL_OUTPUT_GROUPS)}),"
                              " no markers: export the take again with its marker trajectories")
    labels = _unique_labels([s for s, k in zip(labels, keep, strict=True) if k])
    _refuse_infinite(np.where(flagged[:, keep, None], 0.0, xyz[:, keep]), labels, first, path, _C3D_AGAIN)
    descriptions = [d for d, k in zip(descriptions, keep, strict=True) if k]
    point_groups = {lab: groups[lab.split("#")[0]] for lab in labels if lab.split("#")[0] in groups}
    return MarkerTake(labels=labels, positions=positions[:, keep], rate=rate, first_frame=first,
                      units=units if units is not None else file_units, source=path, residuals=residuals[:, keep],
                      descriptions=descriptions, point_groups=point_groups, up_axis=up_axis)


def write_c3d(path, take, units="mm", integer=False):
    """Write ``take`` as a C3D file (Intel processor format) with the ``c3d`` package.

    Parameters
    ----------
    path : str or os.PathLike
        Written atomically (temporary file in the same folder, then renamed).
    take : MarkerTake
    units : str
        Length unit stored in the file (``POINT:UNITS``); positions are converted from metres.
    integer : bool
        Store 16-bit integers (``POINT:SCALE`` > 0, chosen so the largest coordinate
        uses the int16 range) instead of 32-bit floats.

    Invalid samples (NaN) are written with residual -1; valid ones with the
    take's residual (0, "modelled", when it has none).  The take's descriptions
    (``POINT:DESCRIPTIONS``), point groups (``POINT:<group>``, ``POINT:TYPE_GROUPS``)
    and up axis (``POINT:Y_SCREEN``) are written too, so that :func:`read_markers`
    and :func:`lacore.markers.takes.drop_non_markers` tell the points apart as in
    the file the take came from.
    """
    c3d = _import_c3d()
    path = str(path)
    factor = 1.0 / unit_scale(units, path)
    _check_writable_take(take, path, "C3D")
    pos = take.positions * factor
    if not np.all(np.abs(pos[take.visible]) < np.finfo(np.float32).max):
        raise MarkerError(f"{path}: positions beyond float32's range in {units}: write them in a larger unit")
    valid = take.visible
    if integer:
        peak = float(np.nanmax(np.abs(pos))) if valid.any() else 1.0
        point_scale = float(np.float32(max(peak, 1e-12) / 32000.0))  # stored as float32
    else:
        point_scale = -1.0
    res = np.zeros(valid.shape) if take.residuals is None else np.nan_to_num(take.residuals * factor)
    frames = np.zeros((take.n_frames, take.n_markers, 5), np.float32)
    frames[:, :, :3] = np.where(valid[:, :, None], pos, 0.0)
    # the writer stores round(residual / |scale|) in a byte
    frames[:, :, 3] = np.where(valid, np.clip(res, 0, 255 * abs(point_scale)), -1.0)
    if integer:
        # the writer truncates value / scale to int16: hand it (k + 0.25 sign k) * scale so it stores k = round
        k = np.round(np.where(valid[:, :, None], pos, 0.0) / point_scale)
        frames[:, :, :3] = (k + 0.25 * np.sign(k)) * point_scale
    writer = c3d.Writer(point_rate=float(take.rate), analog_rate=0.0, point_scale=point_scale, point_units=units)
    writer.set_point_labels(list(take.labels))
    _write_point_metadata(writer, take)
    empty_analog = np.zeros((0, 0), np.float32)
    writer.add_frames([(frames[t], empty_analog) for t in range(take.n_frames)])
    writer.set_start_frame(max(1, take.first_frame))

    def write(fh):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "No analog data found in file."
            writer.write(fh)

    _atomic_write(path, write)


def _write_point_strings(writer, name, strings, description):
    """The string parameter ``POINT:<name>`` (one fixed-width entry per string), as the c3d writer stores LABELS."""
    size = max(1, max(len(x) for x in strings))
    writer.point_group.add_str(name, description, "".join(x.ljust(size) for x in strings), size, len(strings))


def _write_point_metadata(writer, take):
    """POINT:DESCRIPTIONS, the point groups (with TYPE_GROUPS) and Y_SCREEN of ``take``, where it has them."""
    if any(take.descriptions):
        _write_point_strings(writer, "DESCRIPTIONS", list(take.descriptions), "Point descriptions.")
    groups = {}
    for label in take.labels:
        group = take.point_groups.get(label)
        if group is not None:
            groups.setdefault(group, []).append(label.split("#")[0])
    for group, labels in groups.items():
        _write_point_strings(writer, group, list(dict.fromkeys(labels)), f"Points of the {group} group.")
    if groups:
        _write_point_strings(writer, "TYPE_GROUPS", list(groups), "Groups of points that are not markers.")
    if take.up_axis:
        up = take.up_axis.upper()
        writer.set_screen_axis(X="+Y" if up[1] == "X" else "+X", Y=up)


def _atomic_write(path, write):
    """``write(fh)`` into ``path`` through :func:`lacore.io.atomic.atomic_write`; MarkerFileError if it fails."""
    try:
        with atomic_write(path, "wb") as fh:
            write(fh)
    except OSError as exc:
        raise MarkerFileError(str(exc)) from None


# ----------------------------------------------------------------------------- TRC
def read_trc(path, units=None):
    """Read a TRC file (tab-separated ``PathFileType 4`` text; empty fields = occluded).

    The header's ``DataRate`` is the rate, ``Units`` the length unit, the first
    ``Frame#`` the first frame.  Returns a :class:`MarkerTake` (no residuals).
    """
    return _read_trc_text(_read_bytes(path), str(path), units)


def _read_trc_text(data, path, units):
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    lines = text.splitlines()
    if len(lines) < 5 or not lines[0].lower().startswith("pathfiletype"):
        raise MarkerFileError(f"{path}: not a TRC file (expected 'PathFileType' and 4 more header lines)")
    keys = lines[1].split("\t")
    values = lines[2].split("\t")
    header = {k.strip().lower(): v.strip() for k, v in zip(keys, values, strict=False)}
    try:
        rate = float(header["datarate"])
        n_markers = int(float(header["nummarkers"]))
        file_units = header["units"]
    except (KeyError, ValueError, OverflowError) as exc:
        raise MarkerFileError(f"{path}: malformed TRC header (DataRate, NumMarkers, Units): {exc}") from None
    to_metres = unit_scale(units if units is not None else file_units, path)
    names = [s.strip() for s in lines[3].split("\t")[2:]]
    labels = [s for s in names if s]
    if len(labels) != n_markers:
        raise MarkerFileError(f"{path}: header says NumMarkers {n_markers} but line 4 names {len(labels)} markers")
    labels = _unique_labels(labels)
    width = 2 + 3 * n_markers
    fields, n_rows, last, row_lines = [], 0, None, []
    for number, ln in enumerate(lines[5:], start=6):
        if not ln.strip():
            continue
        n_rows += 1
        row = _trc_row(ln.split("\t"), width, n_markers, path, f"line {number} (data row {n_rows})")
        fields += row
        row_lines.append(number)
        last = (number, ln, row)
    if not n_rows:
        raise MarkerFileError(f"{path}: TRC file without data rows")
    announced = _trc_frame_count(header.get("numframes"))
    if announced is not None and n_rows < announced:
        raise MarkerFileError(f"{path}: the header announces {announced} frames (NumFrames) but the file holds "
                              f"{n_rows} data rows: it is truncated or damaged (export the take again)")
    number, last_line, row = last
    if text.endswith(last_line):  # no line break after the last row: was the file cut inside it?
        ends = len(last_line.split("\t")) - 1  # index of the row's last field
        if 2 <= ends < width:
            k = (ends - 2) // 3
            xyz = [bool(f.strip()) for f in row[2 + 3 * k:5 + 3 * k]]
            if any(xyz) and not all(xyz):
                raise MarkerFileError(f"{path}: line {number} (the last data row, {n_rows}) ends without a line break "
                                      f"inside marker {labels[k]!r} ({sum(xyz)} of its X, Y, Z): the file is "
                                      "truncated or damaged (export the take again)")
    try:
        numbers = np.array([f.strip() or "nan" for f in fields], dtype=np.float64).reshape(n_rows, width)
    except ValueError:
        raise MarkerFileError(_trc_non_numeric(fields, width, labels, row_lines, path)) from None
    frames = numbers[:, 0]
    if np.isnan(frames).any():
        r = int(np.flatnonzero(np.isnan(frames))[0])
        raise MarkerFileError(f"{path}: line {row_lines[r]} (data row {r + 1}) has no frame number (Frame# is NaN): "
                              f"the file is damaged; {_TRC_AGAIN}")
    if not (np.isfinite(frames[0]) and abs(frames[0]) < 2.0 ** 31 and frames[0] == np.round(frames[0])):
        raise MarkerFileError(f"{path}: data row 1 has frame number {frames[0]:g}; frame numbers are whole numbers "
                              "(fix the Frame# column)")
    positions = numbers[:, 2:].reshape(n_rows, n_markers, 3) * to_metres
    _refuse_infinite(positions, labels, frames, path, _TRC_AGAIN)
    return MarkerTake(labels=labels, positions=positions, rate=rate, first_frame=int(frames[0]),
                      units=units if units is not None else file_units, source=path)


def _trc_non_numeric(fields, width, labels, row_lines, path):
    """The one-line error naming the first field of a TRC's data rows that is not a number (``fields``: the rows'
    ``width`` fields each, concatenated; ``row_lines``: each row's line number)."""
    for i, f in enumerate(fields):
        text = f.strip()
        try:
            float(text or "nan")
        except ValueError:
            r, c = divmod(i, width)
            column = ("Frame#", "Time")[c] if c < 2 else f"{'XYZ'[(c - 2) % 3]} of marker {labels[(c - 2) // 3]!r}"
            return (f"{path}: line {row_lines[r]} (data row {r + 1}): {column} is {text[:40]!r}, not a number: the "
                    f"file is damaged; {_TRC_AGAIN}")
    return f"{path}: non-numeric TRC data: the file is damaged; {_TRC_AGAIN}"  # pragma: no cover


def _trc_row(row, width, n_markers, path, where):
    """The ``width`` fields of a TRC data row split at its tabs; MarkerFileError naming ``where`` if it is damaged.

    Empty fields at the end of the row that an exporter left out are added back (occluded markers); empty fields
    beyond ``width`` are dropped.  A row without its Frame# or Time, or with a non-empty field beyond ``width``,
    is refused.
    """
    for i, name in enumerate(("Frame#", "Time")):
        if len(row) <= i or not row[i].strip():
            raise MarkerFileError(f"{path}: {where} has no {name} (a data row begins with Frame# and Time): the file "
                                  f"is damaged; {_TRC_AGAIN}")
    if len(row) > width:
        used = max(i for i, f in enumerate(row) if f.strip() or i < width) + 1
        if used > width:
            raise MarkerFileError(f"{path}: {where} has {used} fields, {used - width} more than the header's {width} "
                                  f"(Frame#, Time and X, Y, Z of NumMarkers {n_markers}): the file is damaged; "
                                  f"{_TRC_AGAIN}")
        return row[:width]
    return row + [""] * (width - len(row))


def _refuse_infinite(xyz, labels, frame_numbers, path, what_to_do):
    """MarkerFileError naming the first marker and frame with an infinite coordinate in ``xyz`` (T, M, 3).

    ``frame_numbers`` is the first frame's number (int) or every frame's (T,) numbers.
    """
    bad = np.isinf(xyz).any(axis=2)
    if not bad.any():
        return
    t, m = (int(i[0]) for i in np.nonzero(bad))
    frame = frame_numbers + t if np.ndim(frame_numbers) == 0 else frame_numbers[t]
    at = f"frame {int(frame)}" if np.isfinite(frame) and abs(frame) < 2.0 ** 63 else f"data row {t + 1}"
    raise MarkerFileError(f"{path}: marker {labels[m]!r} has an infinite coordinate at {at} "
                          f"({int(bad.sum())} such samples): the file is damaged; {what_to_do}")


def _trc_frame_count(text):
    """The header's ``NumFrames`` as a non-negative int, or None where it is missing or not a whole number."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return int(value) if np.isfinite(value) and value >= 0 and value == np.round(value) else None


def _check_writable_take(take, path, kind):
    """:class:`MarkerError` before writing a take the format cannot hold: no frames or markers, labels that
    are empty, not ASCII (C3D's fixed-width byte fields), or hold tabs or line breaks (TRC's separators)."""
    if take.n_frames == 0 or take.n_markers == 0:
        raise MarkerError(f"{path}: the take has {take.n_frames} frames and {take.n_markers} markers: nothing to "
                          "write")
    for label in take.labels:
        if not label.strip() or not label.isascii() or not label.isprintable():
            raise MarkerError(f"{path}: marker label {label!r} cannot be written to {kind} (labels are non-empty "
                              "printable ASCII without tabs or line breaks): rename the marker")


def write_trc(path, take, units="mm"):
    """Write ``take`` as a TRC file (occluded samples as empty fields), atomically."""
    factor = 1.0 / unit_scale(units, str(path))
    _check_writable_take(take, str(path), "TRC")
    T, M = take.n_frames, take.n_markers
    lines = ["PathFileType\t4\t(X/Y/Z)\t" + os.path.basename(str(path)),
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{take.rate:.12g}\t{take.rate:.12g}\t{T}\t{M}\t{units}\t{take.rate:.12g}\t{take.first_frame}\t{T}",
             "Frame#\tTime\t" + "\t".join(f"{s}\t\t" for s in take.labels),
             "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(M)), ""]
    table = np.column_stack([take.first_frame + np.arange(T), take.times, (take.positions * factor).reshape(T, 3 * M)])
    buf = io.StringIO()
    np.savetxt(buf, table, fmt=["%d", "%.6f"] + ["%.17g"] * (3 * M), delimiter="\t")  # %.17g: exact float64
    data = buf.getvalue().replace("\tnan", "\t")  # occluded: empty fields (no number starts with "nan")
    body = ("\n".join(lines) + "\n" + data).encode()
    _atomic_write(str(path), lambda fh: fh.write(body))



# ----------------------------------------------------------------------------- marker arrays (.npz)
def read_marker_arrays(path, mesh_faces, n_vertices=None):
    """Marker positions and their binding from an ``.npz`` file, every array checked.

    The file holds ``positions`` ``(T, M, 3)`` (NaN where occluded) and the
    binding: ``vertices`` ``(M,)`` int, or ``faces`` ``(M,)`` int +
    ``barycentric`` ``(M, 3)`` (triangles of ``mesh_faces``); optional
    ``offsets`` ``(M,)`` (distance along the face normal, positive outside).
    No pickles are read.

    Parameters
    ----------
    path : str or os.PathLike
    mesh_faces : (F, 3) array_like of int
        The mesh the markers are bound to (e.g. a shape model's faces).
    n_vertices : int, optional
        Its vertex count (default ``mesh_faces.max() + 1``).

    Returns
    -------
    positions : (T, M, 3) float64 ndarray
        As :func:`lacore.markers.fitting.check_markers` returns them.
    binding : MarkerBinding

    Raises
    ------
    FileNotFoundError
    MarkerFileError
        Not a readable ``.npz`` file, a missing or wrongly typed array (object,
        string or complex arrays included).
    MarkerBindingError, MarkerDataError
        A binding out of range or to nothing, positions with no frames, no
        markers, infinite or too large values, or no visible marker at all.
    """
    from ..io.npz import open_npz, read_array
    from .binding import MarkerBinding, MarkerBindingError
    from .fitting import check_markers

    path = os.fspath(path)
    what = "markers"
    with open_npz(path, what, MarkerFileError) as npz:
        keys = set(npz.files)
        if "positions" not in keys:
            raise MarkerFileError(f"{path} has no 'positions' array (T, M, 3)")
        positions = read_array(npz, "positions", path, what, MarkerFileError, kind="f")
        offsets = read_array(npz, "offsets", path, what, MarkerFileError, kind="f") if "offsets" in keys else None
        if "vertices" in keys and "faces" in keys:
            raise MarkerBindingError(f"{path} has both 'vertices' and 'faces': give one binding")
        if "vertices" in keys:
            vertices = read_array(npz, "vertices", path, what, MarkerFileError, kind="i", ndim=1)
            binding = MarkerBinding.from_vertices(vertices, mesh_faces, n_vertices, offsets)
        elif "faces" in keys:
            if "barycentric" not in keys:
                raise MarkerBindingError(f"{path} has 'faces' but no 'barycentric' (M, 3)")
            faces = read_array(npz, "faces", path, what, MarkerFileError, kind="i", ndim=1)
            bary = read_array(npz, "barycentric", path, what, MarkerFileError, kind="f", ndim=2)
            binding = MarkerBinding.from_surface(faces, bary, offsets)
        else:
            raise MarkerBindingError(f"{path} binds the markers to nothing: it needs 'vertices' (M,) or 'faces' (M,) "
                                     "+ 'barycentric' (M, 3)")
    binding.check(mesh_faces)
    try:
        return check_markers(positions, binding), binding
    except InputError as exc:
        raise type(exc)(f"{path}: {exc}") from None
