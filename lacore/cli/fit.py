"""``lacore fit``: poses of a shape model from motion-capture markers (thesis 4.3.1) on the command line.

Usage::

    lacore fit MODEL.npz --markers TAKE.c3d|TAKE.trc|MARKERS.npz -o OUT.npz [--json] [--static STATIC.c3d]
               [--prior-weight G|auto] [--temporal-weight W] [--penetration-weight MU]
               [--observed-radius R1 R2|0] [--frames A:B] [--units mm|cm|dm|m|in|ft] [--pin LABEL=VERTEX ...]

``MODEL.npz`` is a shape model written by ``lacore model``
(:meth:`lacore.models.shape_model.ShapeModel.save`).

A take (``.c3d``, ``.trc``) is calibrated and fitted with no hand work
(:func:`lacore.markers.fit_take`): points that are not markers are dropped, the
units are read from the file (``--units`` overrides) and checked against the
model's size, the model is placed, sized and bound to the markers on a few frames
(or on ``--static``), then every frame is fitted and, if the model carries a fine
level, prolonged to full resolution.  Standard marker names (Plug-in Gait, CGM, ...)
place a humanoid; ``--pin LABEL=VERTEX`` (3 or more, vertices of the model's
full-resolution mesh) places any other character.  ``OUT.npz`` gets ``vertices`` ``(T, V, 3)``
(full resolution if the model has a fine level; the take's axes, the model's unit,
the performer's size), ``faces``, ``coarse_vertices``, ``coarse_faces``,
``marker_residuals`` ``(T, M, 3)`` (NaN where occluded), ``markers`` ``(T, M, 3)``,
``labels``, the binding on the coarse mesh at the performer's size (``binding_faces``,
``binding_barycentric``, ``binding_offsets``), ``frame_rms_mm``, ``frame_status``,
``coefficients``, ``length_unit`` and ``self_intersections`` ``(T,)`` (face pairs of
the coarse fit passing through each other where the rest mesh does not and the
markers show no contact).  ``--json`` prints ``frames``, ``seconds``,
``calibration_seconds``, ``seconds_per_frame`` (fitting only), ``prior_weight``,
``marker_rms`` and ``marker_p95`` (millimetres: mean over frames of the per-frame
values), ``flagged_frames``, ``flagged_markers``, ``self_intersection_frames`` (take
frames with such pairs), ``warnings`` and ``notes``.

``MARKERS.npz`` is a precomputed binding: ``positions`` ``(T, M, 3)`` in the model's
unit (NaN where occluded) and either ``vertices`` ``(M,)`` int, or ``faces`` ``(M,)``
int + ``barycentric`` ``(M, 3)`` float; optional ``offsets`` ``(M,)``.  It is fitted
without calibration; ``OUT.npz`` gets ``vertices``, ``faces``, ``coefficients``,
``marker_residuals`` ``(T, M, 3)``, ``frame_status`` and ``frame_rms``.

Bad input (including a unit or axis mismatch) prints one line on stderr and exits
with code 2; the output is written to a temporary file in the target folder and
renamed, so a failed run leaves nothing behind.  A fit that fails (a frame did not
converge, nothing fitted) is written and reported on one stderr line, exit code 3 (0
with ``--allow-failure``); flagged frames and markers are warnings on stderr.
Registered in :mod:`lacore.cli` through :func:`register`.
"""

import dataclasses
import sys
import time

import numpy as np

from ..errors import InputError
from ..io.atomic import save_npz_atomic
from ..markers.take_fit import fit_take, frame_indices
from ..markers.fitting import FIT_DEFAULTS, fit_markers
from ..markers.io import COMMON_UNITS, UNIT_SCALES, read_marker_arrays
from ..markers.takes import read_take
from ..models.shape_model import ShapeModel
from ..result import json_value
from .common import MAX_WEIGHT, add_allow_failure, check_number, check_outputs, finish, print_json

__all__ = ["register", "configure", "run", "HELP", "load_marker_file"]

HELP = "fit a shape model to motion-capture markers (poses per frame, no skeleton)"
#: The units ``--units`` names in its help (:data:`lacore.markers.io.UNIT_SCALES` also takes their spelled-out names).
KNOWN_UNITS = ", ".join(COMMON_UNITS)


def register(register_subcommand):
    """Register ``fit`` with ``register_subcommand(name, help, configure, run)`` (:mod:`lacore.cli`)."""
    register_subcommand("fit", HELP, configure, run)


def _prior_weight(text):
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"--prior-weight must be a number in (0, {MAX_WEIGHT:g}] or auto, got {text!r}") from None
    return check_number("--prior-weight", v, 0.0, MAX_WEIGHT, low_open=True)


def configure(parser):
    """Arguments of ``lacore fit``."""
    parser.add_argument("model", metavar="MODEL.npz", help="a shape model written by `lacore model`")
    parser.add_argument("--markers", required=True, metavar="TAKE.c3d|TAKE.trc|MARKERS.npz",
                        help="a take (calibrated automatically), or positions (T,M,3) in the model's unit with "
                             "NaN for occlusion and vertices (M,) or faces (M,) + barycentric (M,3) [+ offsets (M,)]")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.npz", help="result file to write")
    parser.add_argument("--static", metavar="STATIC.c3d", help="a static trial to calibrate on (takes only)")
    parser.add_argument("--prior-weight", default=FIT_DEFAULTS.prior_weight, metavar="G",
                        help=f"scale-free prior weight gamma, or 'auto' (default {FIT_DEFAULTS.prior_weight:g})")
    parser.add_argument("--temporal-weight", type=float, default=FIT_DEFAULTS.temporal_weight, metavar="W",
                        help=f"weight of the vertex temporal term at {FIT_DEFAULTS.reference_rate:g} Hz, scaled "
                             f"with the square of the frame rate (default {FIT_DEFAULTS.temporal_weight:g})")
    parser.add_argument("--penetration-weight", type=float, default=FIT_DEFAULTS.penetration_weight, metavar="MU",
                        help="weight of the non-penetration term: frames whose surface passes through itself where "
                             "the markers do not are fitted again holding the crossing faces apart (default "
                             f"{FIT_DEFAULTS.penetration_weight:g}; 0: off, faster on takes with many such frames)")
    r1, r2 = FIT_DEFAULTS.observed_radius
    parser.add_argument("--observed-radius", nargs="+", type=float, default=None, metavar="R",
                        help="the model's modes act within R1 and not beyond R2 (fractions of the body's diagonal, "
                             f"along the surface) of two markers (default {r1:g} {r2:g}); 0: everywhere (a mesh "
                             "with few markers spread over a bend of the whole mesh)")
    parser.add_argument("--rate", type=float, metavar="HZ",
                        help="frames per second of MARKERS.npz positions that form a recording: enables the temporal "
                             "term (a take's own rate is used; without one, frames are fitted independently)")
    parser.add_argument("--frames", metavar="A:B", help="fit only the take's frames A to B-1 (takes only)")
    parser.add_argument("--units", metavar="UNIT",
                        help=f"the take's length unit ({KNOWN_UNITS}) if its file lacks or misstates it")
    parser.add_argument("--pin", nargs="+", action="extend", metavar="LABEL=VERTEX",
                        help="markers pinned to vertices of the model's mesh (full resolution), 3 or more: what "
                             "places a character whose markers have no standard names (takes only)")
    add_allow_failure(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")


#: A markers ``.npz`` whose markers spread more than this factor farther (or less far) than the points they are
#: bound to on the model's mean shape holds another unit than the model's (1000 for mm against m, 25.4 for mm
#: against inches); a pose changes the spread far less.
MARKER_SPREAD_LIMIT = 4.0


def load_marker_file(path, model):
    """Positions ``(T, M, 3)`` and the binding of a markers file (:func:`lacore.markers.io.read_marker_arrays`),
    checked to be in the model's unit (:func:`check_marker_spread`)."""
    positions, binding = read_marker_arrays(path, model.faces, model.topology.n_vertices)
    check_marker_spread(path, positions, binding, model)
    return positions, binding


def check_marker_spread(path, positions, binding, model):
    """InputError unless the markers spread about as far as the points they are bound to on the model's mean
    shape: the median over frames (with 3 or more markers visible) of their RMS distance from their centroid,
    over the same for the bound points, within ``1 / MARKER_SPREAD_LIMIT .. MARKER_SPREAD_LIMIT``."""
    corners = np.asarray(model.mean_vertices, float)[binding.corner_vertices(model.faces)]   # (M, 3, 3)
    on_model = np.einsum("mk,mkd->md", np.asarray(binding.barycentric, float), corners)
    ratios = []
    for frame in np.asarray(positions, float):
        seen = np.isfinite(frame).all(axis=1)
        if seen.sum() < 3:
            continue
        spread = [np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean()) for p in (frame[seen], on_model[seen])]
        if spread[0] > 0 and spread[1] > 0:
            ratios.append(spread[0] / spread[1])
    if not ratios:
        return
    ratio = float(np.median(ratios))
    if not 1.0 / MARKER_SPREAD_LIMIT <= ratio <= MARKER_SPREAD_LIMIT:
        raise InputError(f"{path}: the markers are {ratio:.3g} times as far apart as the points they are bound to "
                         "on the model: give their positions in the model's unit")


def _observed_radius(values):
    """``--observed-radius`` as :attr:`FitOptions.observed_radius`: the default when not given, ``(R1, R2)``, or None
    for ``0`` (the modes everywhere)."""
    if values is None:
        return FIT_DEFAULTS.observed_radius
    if len(values) == 1 and values[0] == 0:
        return None
    if len(values) != 2 or not all(np.isfinite(values)) or not 0 <= values[0] < values[1]:
        raise InputError(f"--observed-radius must be two numbers 0 <= R1 < R2, or 0 (the modes everywhere), "
                         f"got {' '.join(f'{v:g}' for v in values)}")
    return (float(values[0]), float(values[1]))


def _pins(items):
    """``--pin LABEL=VERTEX ...`` as ``{label: vertex}`` (None when not given)."""
    if not items:
        return None
    pins = {}
    for item in items:
        label, sep, vertex = str(item).rpartition("=")
        try:
            v = int(vertex)
        except ValueError:
            v = None
        if not sep or not label or v is None:
            raise InputError(f"--pin takes LABEL=VERTEX (a marker label and a vertex number), got {item!r}")
        if label in pins:
            raise InputError(f"--pin names marker {label} twice")
        pins[label] = v
    return pins


def _frames(text):
    if text is None:
        return None
    try:
        a, b = (int(p) if p.strip() else None for p in str(text).split(":"))
    except ValueError:
        raise InputError(f"--frames must be A:B (frame numbers from 0), got {text!r}") from None
    return slice(a, b)


def run(args):
    """Run ``lacore fit``; returns the exit code (bad input raises for :func:`lacore.cli.main`)."""
    start = time.perf_counter()
    if not args.output.lower().endswith(".npz"):
        raise InputError(f"the output file must end in .npz, got {args.output}")
    check_outputs([args.output], inputs=[args.model, args.markers, args.static])
    gamma = _prior_weight(args.prior_weight)
    v = args.temporal_weight = check_number("--temporal-weight", args.temporal_weight, 0.0, MAX_WEIGHT)
    mu = args.penetration_weight = check_number("--penetration-weight", args.penetration_weight, 0.0, MAX_WEIGHT)
    args.observed_radius = _observed_radius(args.observed_radius)
    model = ShapeModel.load(args.model)
    if str(args.markers).lower().endswith(".npz"):
        if gamma == "auto":
            raise InputError("--prior-weight auto needs a take (.c3d or .trc): a markers .npz has no calibration")
        if args.rate is not None and not (np.isfinite(args.rate) and args.rate > 0):
            raise InputError(f"--rate must be a positive number of frames per second, got {args.rate}")
        given = [o for o, v in (("--frames", args.frames), ("--static", args.static), ("--units", args.units),
                                ("--pin", args.pin)) if v is not None]
        if given:
            raise InputError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for a take (.c3d or .trc): a "
                             "markers .npz is fitted whole, in the model's unit")
        return _run_binding(args, model, gamma, start)
    if args.rate is not None:
        raise InputError("--rate is for a markers .npz: a take (.c3d or .trc) has its own frame rate")
    if args.units is not None and str(args.units).strip().lower() not in UNIT_SCALES:
        raise InputError(f"--units must be a length unit ({KNOWN_UNITS}), got {args.units!r}")
    pins = _pins(args.pin)
    frames = _frames(args.frames)
    take = read_take(args.markers, units=args.units)
    if frames is not None and not len(frame_indices(frames, take.n_frames)):
        raise InputError(f"--frames {args.frames} selects no frame of {args.markers} (frames 0 to "
                         f"{take.n_frames - 1})")
    static = read_take(args.static, units=args.units) if args.static else None
    res = fit_take(model, take, options=dataclasses.replace(FIT_DEFAULTS, prior_weight=gamma, temporal_weight=v,
                                                            penetration_weight=mu,
                                                            observed_radius=args.observed_radius),
                   frames=frames, static=static, pins=pins)
    cal = res.calibration
    fine = res.fine_vertices is not None
    b = res.binding
    t = time.perf_counter()
    save_npz_atomic(args.output, vertices=res.fine_vertices if fine else res.vertices,
                    faces=model.fine_level.fine_faces if fine else model.faces,
                    coarse_vertices=res.vertices, coarse_faces=model.faces, coefficients=res.coefficients,
                    marker_residuals=res.marker_residuals, markers=res.markers, labels=np.array(res.labels, str),
                    binding_faces=b.faces, binding_barycentric=b.barycentric, binding_offsets=b.offsets,
                    frame_rms_mm=res.frame_rms * cal.length_unit * 1000, frame_status=res.frame_status,
                    frames=res.frames, length_unit=np.array(cal.length_unit),
                    self_intersections=res.self_intersections)
    t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    s = res.summary()
    summary = {
        "command": "fit", "output": args.output, "frames": res.n_frames, "markers": len(res.labels),
        "vertices": int(res.fine_vertices.shape[1] if fine else res.vertices.shape[1]),
        "seconds": seconds, "calibration_seconds": res.calibration_seconds,
        "seconds_per_frame": res.seconds_per_frame, "prior_weight": res.prior_weight,
        "temporal_weight": res.temporal_weight, "penetration_weight": mu,
        "observed_radius": None if args.observed_radius is None else list(args.observed_radius),
        "marker_rms": s["marker_rms_mm"], "marker_p95": s["marker_p95_mm"],
        "units": "mm", "flagged_frames": s["flagged_frames"], "flagged_markers": s["flagged_markers"],
        "self_intersection_frames": s["self_intersection_frames"],
        "temporal_lowered_frames": s["temporal_lowered_frames"],
        "success": s["success"], "status": s["status"], "message": s["message"],
        "frame_status_counts": s["frame_status_counts"], "performer_ratio": s["performer_ratio"],
        "length_unit": s["length_unit"], "warnings": s["warnings"], "notes": s["notes"], "save_seconds": t_save,
    }
    if args.json:
        print_json(json_value(summary))
    else:
        print(f"fitted {res.n_frames} frames ({summary['vertices']} vertices, {len(res.labels)} markers): "
              f"marker RMS {res.marker_rms_mm:.2f} mm, p95 {res.marker_p95_mm:.2f} mm; calibration "
              f"{res.calibration_seconds:.1f} s, {res.seconds_per_frame:.3f} s per frame")
        print(f"  {res.message}")
        print(f"  wrote {args.output} in {seconds:.1f} s")
    for w in res.warnings:
        print(f"lacore fit: warning: {w}", file=sys.stderr, flush=True)
    return finish("fit", res.success, res.message, args)


def _run_binding(args, model, gamma, start):
    """``--markers MARKERS.npz``: positions and a precomputed binding, fitted without calibration."""
    x, binding = load_marker_file(args.markers, model)
    t_load = time.perf_counter() - start
    res = fit_markers(model, x, binding, prior_weight=gamma, temporal_weight=args.temporal_weight, rate=args.rate,
                      penetration_weight=args.penetration_weight, observed_radius=args.observed_radius)
    t = time.perf_counter()
    save_npz_atomic(args.output, vertices=res.vertices, faces=model.faces, coefficients=res.coefficients,
                    marker_residuals=res.marker_residuals, frame_status=res.frame_status, frame_rms=res.frame_rms)
    t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    s = res.summary()
    T = res.n_frames
    summary = {
        "command": "fit", "output": args.output, "frames": T, "markers": int(binding.n_markers),
        "vertices": int(model.topology.n_vertices), "modes": int(model.n_modes),
        "seconds": seconds, "seconds_per_frame": res.timings["total"] / T if T else None,
        "marker_rms": s["marker_rms"], "max_frame_rms": s["max_frame_rms"],
        "success": s["success"], "status": s["status"], "message": s["message"],
        "frame_status_counts": s["frame_status_counts"], "iterations": s["iterations"],
        "stages": {"load": t_load, **{k: v for k, v in s["timings"].items() if k != "total"}, "save": t_save},
        "prior_weight": gamma, "temporal_weight": args.temporal_weight, "penetration_weight": args.penetration_weight,
        "observed_radius": None if args.observed_radius is None else list(args.observed_radius),
    }
    if args.json:
        print_json(summary)
    else:
        rms = "n/a" if s["marker_rms"] is None else f"{s['marker_rms']:.4g}"
        print(f"fitted {T} frames ({model.topology.n_vertices} vertices, {model.n_modes} modes, "
              f"{binding.n_markers} markers): marker RMS {rms}, {summary['seconds_per_frame'] or 0:.3f} s per frame")
        print(f"  {res.message}")
        print(f"  wrote {args.output} in {seconds:.3f} s")
    return finish("fit", res.success, res.message, args)
