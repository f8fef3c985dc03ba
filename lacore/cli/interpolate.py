"""``lacore interpolate``: in-betweens and extrapolations of shapes in lengths and angles.

Usage::

    lacore interpolate A.ply B.ply [C.ply ...] (--t T [T ...] | --frames N)
                       [--keyframes K1 K2 ...] [--smooth-spline] [--method fast|gn|hybrid|bfs|mst|spt|lsq|path]
                       -o OUT_PREFIX [--format ply|obj|off|stl] [--json]

The input meshes must be in dense correspondence (same vertex count and
faces).  They sit at the keyframe times ``--keyframes`` (default ``0, 1, ...``).

``--t T ...``
    Frames at these times in keyframe-time units: for two shapes at 0 and 1,
    ``0 <= t <= 1`` interpolates and ``t < 0`` or ``t > 1`` extrapolates.
``--frames N``
    ``N`` evenly spaced frames from the first to the last keyframe (inclusive).

The lengths and angles are interpolated piecewise linearly (or, with
``--smooth-spline``, by a natural cubic spline through the keyframes) and
projected onto the admissible set by reconstruction, see
:mod:`lacore.shapes.interpolation`; by default with
:data:`lacore.reconstruction.settings.DEFAULT_PROJECTION` (``fast``: continuation
along ``t`` and one Gauss-Newton step per frame, the add-on's Fast), ``--method gn``
runs Gauss-Newton to convergence from the same starts.  ``--method path`` computes every
segment between two keys by a reduced model of its path (:func:`lacore.shapes.mixing.path_inbetweens`:
two or three sparse factorizations per segment instead of one or more per frame, so it pays for many
frames of large meshes; each frame's error estimate is in the JSON as ``indicator``, and frames
whose estimate stays above 0.3 % of the size are finished by Gauss-Newton; not with
``--smooth-spline``).  Frames are written in the order given to
``OUT_PREFIX_000.ply``, ``OUT_PREFIX_001.ply``, ... (at least three digits), all
in the frame of the reference shape (``--reference``, default the first).

``--json`` prints one JSON object: per output file its ``factor`` (and, with
``--frames``, its ``frame``), ``seconds``, ``energy``, ``iterations``,
``max_length_error``, ``max_angle_error``, ``success``, ``failure``, plus
``totals``.  Bad input (missing files, meshes not in correspondence, a keyframe
count different from the mesh count, keyframes not strictly increasing,
negative counts) exits with code 2 and a message.  Every frame is written
(atomically) as soon as it is projected, so a run that is stopped keeps the
frames done; bad input found mid-run (exit 2) removes the frames it wrote and puts back the files they
replaced.  Frames that fail their checks
(:mod:`lacore.reconstruction.checks`) are written too, and the exit code is 3 unless ``--allow-failure`` is given.

The subcommand is registered in :mod:`lacore.cli` with :func:`configure` and :func:`run`.
"""

import os
import shutil
import tempfile
import time

import numpy as np

from dataclasses import replace

from ..errors import InputError
from ..io.meshes import MESH_FORMATS, save_mesh
from ..reconstruction import METHODS, GaussNewtonOptions, ReconstructionSettings
from ..reconstruction.settings import DEFAULT_PROJECTION, PROJECTION_PRESETS, SOLVERS, WEIGHTS, projection_preset
from .common import (CliError, add_allow_failure, check_outputs, finish, frame_count, json_float,
                     load_meshes_in_correspondence, nonnegative_int, positive_int, print_json, weight)

__all__ = ["HELP", "configure", "run", "output_format", "output_paths", "frame_times"]

#: ``--method path`` (:data:`lacore.shapes.interpolation.PATH`; not imported from there: scipy.interpolate is slow to
#: import)
PATH = "path"

HELP = "interpolate or extrapolate shapes in lengths and angles (in-betweens, keyframes)"



def configure(parser):
    """Declare the arguments of ``lacore interpolate`` (defaults from the settings dataclasses)."""
    settings, gn = ReconstructionSettings(), GaussNewtonOptions()

    parser.add_argument("meshes", nargs="+", metavar="MESH",
                        help="two or more meshes in dense correspondence (same vertices and faces)")
    when = parser.add_mutually_exclusive_group(required=True)
    when.add_argument("--t", nargs="+", type=float, metavar="T",
                      help="frame times in keyframe units (0 = first mesh, 1 = second, ...; outside extrapolates)")
    when.add_argument("--frames", type=frame_count, metavar="N",
                      help="N evenly spaced frames from the first to the last keyframe (inclusive)")
    parser.add_argument("--keyframes", nargs="+", type=float, metavar="K",
                        help="strictly increasing keyframe times of the meshes (default 0 1 2 ...)")
    parser.add_argument("--smooth-spline", action="store_true",
                        help="natural cubic spline in lengths and angles through the keyframes (default: linear)")
    parser.add_argument("--method", choices=(*PROJECTION_PRESETS, *METHODS, PATH), default=DEFAULT_PROJECTION.name,
                        help=f"projection by reconstruction: fast (continuation along t and one Gauss-Newton step "
                             f"per frame, the add-on's Fast), gn (Gauss-Newton to convergence from the same "
                             f"starts), hybrid (least-squares start + smoothing), bfs/mst/spt (frame-based, one "
                             f"preassembled tree), lsq, path (a reduced model of the path between two keys: a few "
                             f"factorizations for all frames, with an error estimate per frame; piecewise linear "
                             f"only) (default {DEFAULT_PROJECTION.name})")
    parser.add_argument("--reference", type=int, default=0, metavar="I",
                        help="index of the mesh giving the energy weights and the output frame (default 0)")
    parser.add_argument("--bending-weight", type=weight, default=settings.bending_weight, metavar="ETA",
                        help=f"bending weight eta of W_q (default {settings.bending_weight:g})")
    parser.add_argument("--energy-weights", choices=WEIGHTS, default=settings.weights,
                        help="weights of W_q: (3.20) (default), (3.21) or 1")
    parser.add_argument("--max-iterations", type=nonnegative_int, metavar="N",
                        help=f"Gauss-Newton iteration limit per frame of --method gn (default {gn.max_iterations})")
    parser.add_argument("--no-warm-start", action="store_true",
                        help="start every Gauss-Newton projection from the reference mesh")
    parser.add_argument("--solver", choices=SOLVERS,
                        help="sparse Cholesky backend (default cholmod if cvxopt is installed)")
    parser.add_argument("--workers", type=positive_int, default=1, metavar="N",
                        help="chains of frames computed side by side, N - 1 of them in worker processes "
                             "(default 1; pays for many frames of large meshes, up to the number of cores)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT_PREFIX",
                        help="output prefix: writes OUT_PREFIX_000.ply, OUT_PREFIX_001.ply, ...")
    parser.add_argument("--format", choices=MESH_FORMATS, default=None,
                        help="output mesh format (default: the extension of -o if it is one of these, else ply)")
    add_allow_failure(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object with the results")


def output_format(prefix, given=None, formats=MESH_FORMATS):
    """The mesh format of ``-o PREFIX``: ``--format`` when given, else the prefix's extension when it is one of
    ``formats`` (``-o walk.obj`` writes OBJ files), else ply.

    >>> output_format("walk.obj"), output_format("walk.obj", "ply"), output_format("out/f")
    ('obj', 'ply', 'ply')
    >>> output_format("a.stl", None, ("ply", "obj"))
    'ply'
    """
    if given:
        return given
    extension = os.path.splitext(str(prefix))[1].lower().lstrip(".")
    return extension if extension in formats else "ply"


def output_paths(prefix, n, extension="ply"):
    """``prefix_000.ext ... prefix_{n-1}.ext`` (at least three digits, more if ``n > 1000``); a prefix ending in
    ``.ext`` loses it (``-o walk.ply`` writes ``walk_000.ply``, not ``walk.ply_000.ply``).

    A prefix naming a folder (ending in a separator, or an existing folder) is refused (:class:`CliError`): its
    files would be named ``_000.ply`` in it, or beside it.

    >>> output_paths("walk.ply", 2), output_paths("out/f", 1, "obj")
    (['walk_000.ply', 'walk_001.ply'], ['out/f_000.obj'])
    """
    prefix = str(prefix)
    if prefix.endswith(("/", os.sep)) or os.path.isdir(prefix):
        raise CliError(f"-o {prefix} is a folder: give a file name prefix in it, such as "
                       f"{os.path.join(prefix, 'frame')}")
    if prefix.lower().endswith("." + extension.lower()) and len(prefix) > len(extension) + 1:
        prefix = prefix[:-len(extension) - 1]
    width = max(3, len(str(max(n - 1, 0))))
    return [f"{prefix}_{i:0{width}d}.{extension}" for i in range(n)]


def frame_times(keyframes, n_frames):
    """``n_frames`` evenly spaced times from the first to the last keyframe, inclusive."""
    if n_frames < 1:
        raise CliError(f"--frames must be at least 1, got {n_frames}")
    return np.linspace(float(keyframes[0]), float(keyframes[-1]), int(n_frames))


def _load_shapes(paths):
    """Vertices of all meshes and the topology of the first (:func:`.common.load_meshes_in_correspondence`)."""
    if len(paths) < 2:
        raise CliError(f"interpolation needs at least 2 meshes, got {len(paths)}")
    return load_meshes_in_correspondence(paths)


def _keep_aside(path):
    """A second name, in the same folder, for the file at ``path`` (a hard link, else a copy), so that it can be
    put back after a new frame replaced it."""
    fd, kept = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.lacore-kept.", dir=os.path.dirname(path) or ".")
    os.close(fd)
    os.remove(kept)
    try:
        os.link(path, kept)
    except OSError:  # a file system without hard links
        shutil.copy2(path, kept)
    return kept


def _remove_quietly(path):
    try:
        os.remove(path)
    except OSError:
        pass


def run(args):
    """Run ``lacore interpolate``; returns the exit code (errors are raised for :func:`lacore.cli.main`)."""
    # imported here on purpose: lacore.shapes.interpolation pulls in scipy.interpolate (slow to import), which the other
    # subcommands do not need
    from ..shapes.interpolation import check_keyframes, keyframe_inbetweens

    start = time.perf_counter()
    shapes, topology = _load_shapes(args.meshes)
    keyframes = check_keyframes(args.keyframes, len(shapes))
    if args.t is not None:
        times, mode = np.asarray(args.t, float), "factor"
    else:
        times, mode = frame_times(keyframes, args.frames), "frame"
    if not 0 <= args.reference < len(shapes):
        raise CliError(f"--reference {args.reference} is not the index of one of the {len(shapes)} meshes")
    if not np.all(np.isfinite(times)):
        raise CliError("--t takes finite numbers (keyframe times), got " + " ".join(f"{t:g}" for t in times))
    paths = output_paths(args.output, len(times), output_format(args.output, args.format))
    check_outputs(paths, inputs=args.meshes)
    t_load = time.perf_counter() - start
    if args.method == PATH:
        if args.energy_weights != ReconstructionSettings().weights or args.solver or args.max_iterations is not None:
            raise CliError("--method path takes --bending-weight only of the energy settings (not --energy-weights, "
                           "--solver or --max-iterations)")
        method, options, hybrid = PATH, None, None
    else:
        method, options, hybrid = projection_preset(args.method)
    if args.max_iterations is not None:
        options = replace(options or GaussNewtonOptions(), max_iterations=args.max_iterations)

    t_save = 0.0
    written = []
    replaced = {}  # output path -> a second name of the file it replaced, until the run ends

    def write_frame(i, res):  # stream: every frame is on disk as soon as it is projected
        nonlocal t_save
        t = time.perf_counter()
        if os.path.isfile(paths[i]) and paths[i] not in replaced:
            replaced[paths[i]] = _keep_aside(paths[i])
        save_mesh(paths[i], res.vertices, topology.faces)
        written.append(paths[i])
        t_save += time.perf_counter() - t

    settings = ReconstructionSettings(bending_weight=args.bending_weight, weights=args.energy_weights,
                                      solver=args.solver)
    try:
        if method == PATH:
            result = keyframe_inbetweens(shapes, topology, keyframes, frames=times, smooth=args.smooth_spline,
                                         method=PATH, reference=args.reference, settings=settings,
                                         on_frame=write_frame)
        else:
            result = keyframe_inbetweens(shapes, topology, keyframes, frames=times, smooth=args.smooth_spline,
                                         method=method, reference=args.reference, warm_start=not args.no_warm_start,
                                         settings=settings, options=options, hybrid=hybrid, on_frame=write_frame,
                                         workers=args.workers)
    except InputError:          # bad input found mid-run (exit 2): no partial output, earlier files put back
        for path in written:
            if path in replaced:
                os.replace(replaced.pop(path), path)
            else:
                os.remove(path)
        raise
    finally:
        for kept in replaced.values():
            _remove_quietly(kept)
    seconds = time.perf_counter() - start

    outputs = []
    for i, path in enumerate(paths):
        item = {"file": path, "factor": float(times[i])}
        if mode == "frame":
            item["frame"] = float(times[i])
        item.update({"seconds": float(result.seconds[i]), "energy": json_float(result.energy[i]),
                     "iterations": int(result.iterations[i]),
                     "max_length_error": json_float(result.max_length_error[i]),
                     "max_angle_error": json_float(result.max_angle_error[i]), "status": int(result.status[i]),
                     "warm_start_from": json_float(result.warm_start_times[i])})
        if result.indicator is not None:                  # --method path: no reconstruction per frame
            item.update({"success": bool(result.success), "failure": "" if result.success else "indicator",
                         "indicator": json_float(result.indicator[i])})
        else:
            item.update({"success": bool(result.reconstructions[i].success),
                         "failure": result.reconstructions[i].failure})
        outputs.append(item)
    if args.json:
        summary = {
            "command": "interpolate",
            "inputs": list(args.meshes),
            "keyframes": [float(k) for k in keyframes],
            "mode": mode,
            "method": args.method,
            "smooth_spline": bool(args.smooth_spline),
            "warm_start": not args.no_warm_start,
            "workers": int(result.workers),
            "vertices": int(topology.n_vertices),
            "faces": int(topology.n_faces),
            "outputs": outputs,
            "totals": {
                "outputs": len(outputs),
                "seconds": seconds,
                "projection_seconds": float(np.sum(result.seconds)),
                "iterations": int(result.total_iterations),
                "max_length_error": json_float(np.max(result.max_length_error)),
                "max_angle_error": json_float(np.max(result.max_angle_error)),
                "load_seconds": t_load,
                "save_seconds": t_save,
            },
            "success": bool(result.success),
            "message": result.message,
        }
        print_json(summary)
    else:
        print(f"{len(paths)} frames of {len(shapes)} meshes ({topology.n_vertices} vertices), method {args.method}"
              f"{', cubic spline' if args.smooth_spline else ''}:")
        for i, item in enumerate(outputs):
            print(f"  {item['file']}: {mode} {times[i]:g}, {item['iterations']} iterations, energy "
                  f"{result.energy[i]:.4g}, max length error {result.max_length_error[i]:.3g}, "
                  f"max angle error {result.max_angle_error[i]:.3g} rad, {item['seconds']:.3f} s")
        print(f"  total {seconds:.3f} s")
    return finish("interpolate", result.success, result.message, args)
