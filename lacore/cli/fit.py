"""``lacore fit``: poses of a shape model from motion-capture markers (thesis 4.3.1) on the command line.

Usage::

    lacore fit MODEL.npz --markers MARKERS.npz -o OUT.npz [--prior-weight G] [--temporal-weight W] [--json]

``MODEL.npz`` is a shape model written by ``lacore model``
(:meth:`lacore.models.shape_model.ShapeModel.save`).  ``MARKERS.npz`` holds
``positions`` ``(T, M, 3)`` float (NaN where a marker is occluded in a frame)
and the binding: either ``vertices`` ``(M,)`` int, or ``faces`` ``(M,)`` int +
``barycentric`` ``(M, 3)`` float (triangles in the model's face order); optional
``offsets`` ``(M,)`` (distance along the face normal, positive outside).

``OUT.npz`` gets ``vertices`` ``(T, V, 3)``, ``faces`` ``(F, 3)``,
``coefficients`` ``(T, J)``, ``marker_residuals`` ``(T, M, 3)`` (NaN where
occluded), ``frame_status`` ``(T,)`` and ``frame_rms`` ``(T,)``.  ``--json``
prints one object with ``frames``, ``seconds``, ``seconds_per_frame``,
``marker_rms``, the stage timings and the per-frame status counts.

Bad input (checked by :func:`lacore.markers.io.read_marker_arrays` and
:meth:`~lacore.models.shape_model.ShapeModel.load`) prints one line on stderr
and exits with code 2; the output is written to a temporary file in the target
folder and renamed, so a failed run leaves nothing behind.  A fit that fails is
written and reported on one stderr line, exit code 3 (0 with
``--allow-failure``).  Registered in :mod:`lacore.cli` through :func:`register`.
"""

import time

import numpy as np

from ..errors import InputError
from ..io.atomic import check_writable, save_npz_atomic
from ..markers.fitting import fit_markers
from ..markers.io import read_marker_arrays
from ..models.shape_model import ShapeModel
from .common import add_allow_failure, finish, print_json

__all__ = ["register", "configure", "run", "HELP", "load_marker_file"]

HELP = "fit a shape model to motion-capture markers (poses per frame, no skeleton)"


def register(register_subcommand):
    """Register ``fit`` with ``register_subcommand(name, help, configure, run)`` (:mod:`lacore.cli`)."""
    register_subcommand("fit", HELP, configure, run)


def configure(parser):
    """Arguments of ``lacore fit``."""
    parser.add_argument("model", metavar="MODEL.npz", help="a shape model written by `lacore model`")
    parser.add_argument("--markers", required=True, metavar="MARKERS.npz",
                        help="positions (T,M,3) with NaN for occlusion, and vertices (M,) or faces (M,) + "
                             "barycentric (M,3) [+ offsets (M,)]")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.npz", help="result file to write")
    parser.add_argument("--prior-weight", type=float, default=1.0, metavar="G",
                        help="prior weight gamma of (4.23) (default 1)")
    parser.add_argument("--temporal-weight", type=float, default=0.0, metavar="W",
                        help="weight of |alpha_t - alpha_(t-1)|^2, the change of the model coefficients (default 0)")
    add_allow_failure(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def load_marker_file(path, model):
    """Positions ``(T, M, 3)`` and the binding of a markers file (:func:`lacore.markers.io.read_marker_arrays`)."""
    return read_marker_arrays(path, model.faces, model.topology.n_vertices)


def run(args):
    """Run ``lacore fit``; returns the exit code (bad input raises for :func:`lacore.cli.main`)."""
    start = time.perf_counter()
    if not args.output.endswith(".npz"):
        raise InputError(f"the output file must end in .npz, got {args.output}")
    check_writable(args.output)
    for name, v in (("--prior-weight", args.prior_weight), ("--temporal-weight", args.temporal_weight)):
        if not np.isfinite(v) or v < 0 or (name == "--prior-weight" and v == 0):
            raise InputError(f"{name} must be a finite number {'> 0' if name == '--prior-weight' else '>= 0'}, "
                             f"got {v}")
    model = ShapeModel.load(args.model)
    x, binding = load_marker_file(args.markers, model)
    t_load = time.perf_counter() - start
    res = fit_markers(model, x, binding, prior_weight=args.prior_weight, temporal_weight=args.temporal_weight)
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
        "prior_weight": args.prior_weight, "temporal_weight": args.temporal_weight,
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
