"""``lacore model`` and ``lacore model-sweep``: statistical shape models on the command line.

Usage::

    lacore model TRAIN_MESH... -o MODEL.npz [--modes J] [--tangent ambient|projected]
                 [--bending-weight ETA] [--reference I] [--localize] [--json]
    lacore model-sweep MODEL.npz --mode J --range T0 T1 --frames K -o PREFIX [--format ply|obj|off|stl] [--json]

``lacore model`` fits a :class:`lacore.models.shape_model.ShapeModel` (thesis 4.3:
extrinsic mean (4.16), tangent vectors (4.18, the default) or (4.17), PCA in the metric of
``W_q`` (4.14)) to two or more meshes in dense correspondence and saves it to
one ``.npz`` (see :meth:`ShapeModel.save`).  ``--json`` prints one object with
``vertices``, ``samples``, ``modes``, ``explained_variance`` (per mode),
``seconds`` and the seconds of each stage (``mean``, ``tangent_decomposition``,
``tangent_solves``, ``gram``, ``eigen``, plus ``load``, ``localize`` and
``save``).  ``--localize`` saves the modes rotated toward locality
(:meth:`ShapeModel.localized`).

``lacore model-sweep`` writes ``K`` poses along mode ``J`` (0-based), at ``t``
evenly spaced from ``T0`` to ``T1`` standard deviations of the mode
(:meth:`ShapeModel.mode_sweep`), to ``PREFIX_000.ply ...``.

Bad input (fewer than 2 meshes, meshes not in correspondence, ``--modes``
larger than N - 1, a corrupt model file, a mode out of range, a ``--range``
whose poses no mesh can have) prints one line on stderr and exits with code 2;
nothing is written then (outputs are checked before computing).  Sweep frames
that fail their checks are written and reported on one stderr line, exit code 3
(0 with ``--allow-failure``).  Every output file is written to a temporary file
in its folder and renamed into place.

Registered in :mod:`lacore.cli` through :func:`register`.
"""

import time
from dataclasses import replace

import numpy as np

from ..io.meshes import MESH_FORMATS, save_mesh
from ..models.settings import DEFAULT_TANGENT, MODEL_SETTINGS, PROJECTION_METRICS, TANGENTS, ShapeModelError
from ..models.shape_model import ShapeModel
from .common import (EXIT_OK, add_allow_failure, check_outputs, finish, frame_count, load_meshes_in_correspondence,
                     positive_int, print_json, weight)
from .interpolate import output_format, output_paths

__all__ = ["register", "configure_model", "run_model", "configure_sweep", "run_sweep", "MODEL_HELP", "SWEEP_HELP"]

MODEL_HELP = "fit a statistical shape model (PCA / simplified PGA in lengths and angles) to meshes"
SWEEP_HELP = "write meshes along one mode of a shape model"


def register(register_subcommand):
    """Register both subcommands with ``register_subcommand(name, help, configure, run)`` (:mod:`lacore.cli`)."""
    register_subcommand("model", MODEL_HELP, configure_model, run_model)
    register_subcommand("model-sweep", SWEEP_HELP, configure_sweep, run_sweep)


def configure_model(parser):
    """Arguments of ``lacore model``."""
    parser.add_argument("meshes", nargs="+", metavar="TRAIN_MESH",
                        help="two or more training meshes in dense correspondence (same vertices and faces)")
    parser.add_argument("-o", "--output", required=True, metavar="MODEL.npz", help="model file to write")
    parser.add_argument("--modes", type=positive_int, default=None, metavar="J",
                        help="number of modes J (1 <= J <= N - 1; default N - 1)")
    parser.add_argument("--tangent", choices=TANGENTS, default=DEFAULT_TANGENT,
                        help="tangent vectors: z - mean (4.18, ambient) or projected onto the tangent space "
                             "(4.17, the thesis' simplified PGA; harder to reconstruct far from the mean); "
                             "default %(default)s")
    parser.add_argument("--projection-metric", choices=PROJECTION_METRICS, default=PROJECTION_METRICS[0],
                        help="orthogonality of the tangent projection: Euclidean as in the thesis or g; "
                             "default %(default)s")
    parser.add_argument("--bending-weight", type=weight, default=MODEL_SETTINGS.bending_weight, metavar="ETA",
                        help="bending weight eta of the quadratic energy W_q (default %(default)s)")
    parser.add_argument("--localize", action="store_true",
                        help="rotate the modes toward locality (g-varimax, same subspace; beyond the thesis)")
    parser.add_argument("--reference", type=int, default=0, metavar="I",
                        help="index of the training mesh used as reference (weights, frame); default 0")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the model's summary")


def configure_sweep(parser):
    """Arguments of ``lacore model-sweep``."""
    parser.add_argument("model", metavar="MODEL.npz", help="a model written by `lacore model`")
    parser.add_argument("--mode", type=int, required=True, metavar="J", help="mode index, 0-based")
    parser.add_argument("--range", type=float, nargs=2, default=(-2.0, 2.0), metavar=("T0", "T1"),
                        help="first and last t in standard deviations of the mode (default -2 2)")
    parser.add_argument("--frames", type=frame_count, default=5, metavar="K", help="number of meshes (default 5)")
    parser.add_argument("-o", "--output", required=True, metavar="PREFIX",
                        help="writes PREFIX_000.ply, PREFIX_001.ply, ...")
    parser.add_argument("--format", choices=MESH_FORMATS, default=None,
                        help="mesh format (default: the extension of -o if it is one of these, else ply)")
    add_allow_failure(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")



def _load_training(paths):
    if len(paths) < 2:
        raise ShapeModelError(f"a shape model needs at least 2 training meshes, got {len(paths)}")
    shapes, topology = load_meshes_in_correspondence(paths)
    return np.stack(shapes), topology


def run_model(args):
    """Run ``lacore model``; returns the exit code (bad input raises for :func:`lacore.cli.main`)."""
    start = time.perf_counter()
    if not args.output.lower().endswith(".npz"):
        raise ShapeModelError(f"the model file must end in .npz, got {args.output}")
    check_outputs([args.output], inputs=args.meshes)
    X, topology = _load_training(args.meshes)
    N = len(X)
    if args.modes is not None and args.modes > N - 1:
        raise ShapeModelError(f"--modes {args.modes} is larger than N - 1 = {N - 1} for {N} training meshes")
    if not 0 <= args.reference < N:
        raise ShapeModelError(f"--reference {args.reference} is not the index of one of the {N} meshes")
    t_load = time.perf_counter() - start
    model = ShapeModel.fit(X, topology, reference_vertices=X[args.reference], n_modes=args.modes,
                           tangent=args.tangent, projection_metric=args.projection_metric,
                           settings=replace(MODEL_SETTINGS, bending_weight=args.bending_weight))
    t_localize = 0.0
    if args.localize:
        t = time.perf_counter()
        model = model.localized()
        t_localize = time.perf_counter() - t
    t = time.perf_counter()
    model.save(args.output)
    t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    tm = model.timings
    summary = {
        "command": "model",
        "output": args.output,
        "vertices": int(topology.n_vertices),
        "edges": int(topology.n_edges),
        "faces": int(topology.n_faces),
        "samples": N,
        "modes": model.n_modes,
        "tangent": model.tangent,
        "projection_metric": model.projection_metric,
        "bending_weight": model.bending_weight,
        "explained_variance": [float(r) for r in model.explained_variance_ratio],
        "explained_variance_total": float(np.sum(model.explained_variance_ratio)),
        "variances": [float(v) for v in model.variances],
        "localized": bool(args.localize),
        "mean_iterations": int(model.mean_result.iterations),
        "mean_energy": float(model.mean_result.energy),
        "seconds": seconds,
        "stages": {"load": t_load, "encode": tm.get("encode", 0.0), "mean": tm["mean"],
                   "tangent_decomposition": tm["tangent_decomposition"], "tangent_solves": tm["tangent_solves"],
                   "gram": tm["gram"], "eigen": tm["eigen"], "localize": t_localize, "save": t_save},
    }
    if args.json:
        print_json(summary)
    else:
        print(f"{model.n_modes} modes from {N} meshes ({topology.n_vertices} vertices), {model.tangent} tangents: "
              f"explained {summary['explained_variance_total']:.4f} of the g-variance")
        print("  per mode: " + " ".join(f"{r:.4f}" for r in model.explained_variance_ratio))
        print("  stages: " + ", ".join(f"{k} {v:.3f} s" for k, v in summary["stages"].items()))
        print(f"  wrote {args.output} in {seconds:.3f} s")
    return EXIT_OK


def run_sweep(args):
    """Run ``lacore model-sweep``; returns the exit code."""
    start = time.perf_counter()
    if not np.all(np.isfinite(args.range)):
        raise ShapeModelError(f"--range must be two finite numbers (standard deviations), got "
                              f"{args.range[0]:g} {args.range[1]:g}")
    paths = output_paths(args.output, args.frames, output_format(args.output, args.format))
    check_outputs(paths, inputs=[args.model])
    model = ShapeModel.load(args.model)
    if not 0 <= args.mode < model.n_modes:
        raise ShapeModelError(f"--mode {args.mode} is not a mode of the model (0 to {model.n_modes - 1})")
    try:
        (X, results), t = model.mode_sweep(args.mode, tuple(args.range), args.frames, return_results=True)
    except ShapeModelError as exc:
        raise ShapeModelError(f"--range {args.range[0]:g} {args.range[1]:g}: {exc}; try a smaller --range") from None
    for path, x in zip(paths, X, strict=True):
        save_mesh(path, x, model.faces)  # each file atomically (lacore.io.atomic)
    failed = [i for i, r in enumerate(results) if not r.success]
    seconds = time.perf_counter() - start
    outputs = [{"file": p, "t": float(ti), "alpha": float(ti * model.standard_deviations[args.mode]),
                "iterations": int(r.iterations), "energy": float(r.energy), "seconds": float(r.timings["total"]),
                "success": bool(r.success), "failure": getattr(r, "failure", "")}
               for p, ti, r in zip(paths, t, results, strict=True)]
    if args.json:
        print_json({"command": "model-sweep", "model": args.model, "mode": args.mode,
                    "standard_deviation": float(model.standard_deviations[args.mode]),
                    "explained_variance": float(model.explained_variance_ratio[args.mode]),
                    "vertices": int(model.topology.n_vertices), "outputs": outputs, "seconds": seconds,
                    "success": not failed, "failed_frames": failed})
    else:
        print(f"mode {args.mode} ({model.explained_variance_ratio[args.mode]:.4f} of the variance), "
              f"{len(t)} frames:")
        for o in outputs:
            print(f"  {o['file']}: t {o['t']:g} sd, {o['iterations']} iterations, energy {o['energy']:.4g}")
        print(f"  total {seconds:.3f} s")
    message = ""
    if failed:
        first = results[failed[0]]
        reason = getattr(first, "failure", "") or first.message
        message = (f"{len(failed)} of {len(t)} frames failed their checks (frames {failed}; frame {failed[0]}: "
                   f"{reason}); sweeps far out along a mode are hard to reconstruct: try a smaller --range")
    return finish("model-sweep", not failed, message, args)
