"""``lacore reconstruct``: reconstruct a mesh from (combinations of) lengths and angles.

Usage::

    lacore reconstruct --ref REF.ply --target T1 [T2 ...] [--weights w1 w2 ...]
                       [--method gn|bfs|mst|spt|lsq|hybrid] [--energy quadratic|shells]
                       [--bending-weight B] -o OUT.ply [--json]

Every target is a mesh in correspondence with the reference (same faces) or an
``.npz`` written by ``lacore encode`` (keys ``faces, edges, lengths, angles``;
its faces must be the reference's).  The target lengths and angles are the
weighted sum ``z* = sum_i w_i z_i`` (default ``w_i = 1/n``; the weights need not
sum to 1, which extrapolates).  The result is written in the reference's frame
(``.ply``, ``.obj``, ``.off``, ``.stl``, or ``.npz`` with keys ``vertices,
faces, z``).

Defaults: Gauss-Newton with ``W_q``, weights (3.20) from the reference,
``eta = 1e-3``.  ``--json`` prints one JSON object with at least ``method,
iterations, seconds, energy, max_length_error, max_angle_error, success,
failure, checks``.  Bad input (missing files, meshes not in correspondence,
negative counts, ...) exits with code 2 and writes nothing.  A result that
fails its checks (:mod:`lacore.reconstruction.checks`: ``success`` false,
``failure`` names the check) is still written, but the exit code is 3 unless
``--allow-failure`` is given.  Output is written atomically (an existing file
is replaced only by a complete one).

The subcommand is registered in :mod:`lacore.cli` with :func:`configure` and :func:`run`.
"""

import os
import time

import numpy as np

from ..errors import MeshError
from ..geometry.lengths_angles import lengths_and_angles
from ..io.atomic import npz_path, save_npz_atomic
from ..io.meshes import SUPPORTED_EXTENSIONS, load_mesh, save_mesh
from ..io.npz import open_npz, read_array
from ..reconstruction import (METHODS, GaussNewtonOptions, HybridOptions, ReconstructionSettings, reconstruct,
                              reconstruction_errors)
from ..reconstruction.settings import ENERGIES, FRAME_KINDS, HYBRID_STARTS, SOLVERS, WEIGHTS
from .common import (CliError, add_allow_failure, check_outputs, checked_vertices, finish, json_float, mesh_topology,
                     nonnegative_int, print_json, weight)

__all__ = ["HELP", "configure", "run", "load_target", "combine_targets"]

HELP = "reconstruct a mesh from (weighted sums of) lengths and angles"


def configure(parser):
    """Declare the arguments of ``lacore reconstruct`` (defaults from the settings dataclasses)."""
    settings, gn, hybrid = ReconstructionSettings(), GaussNewtonOptions(), HybridOptions()

    parser.add_argument("--ref", required=True, metavar="REF",
                        help="reference mesh: weights of the energy, start of Gauss-Newton, output frame")
    parser.add_argument("--target", required=True, nargs="+", metavar="T",
                        help="target meshes (same faces as REF) or .npz files written by 'lacore encode'")
    parser.add_argument("--weights", nargs="+", type=float, metavar="W",
                        help="weight of every target in z* = sum w_i z_i (default 1/n each; need not sum to 1)")
    parser.add_argument("--method", choices=METHODS, default="gn",
                        help="gn: Gauss-Newton (default); bfs/mst/spt: frame-based; lsq: least squares; "
                             "hybrid: least-squares (or tree) start + Gauss-Newton smoothing")
    parser.add_argument("--energy", choices=ENERGIES, default=settings.energy,
                        help=f"energy W[z*, Z(X)] minimized and reported (default {settings.energy} W_q)")
    parser.add_argument("--bending-weight", type=weight, default=settings.bending_weight, metavar="ETA",
                        help=f"bending weight eta (default {settings.bending_weight:g})")
    parser.add_argument("--energy-weights", choices=WEIGHTS, default=settings.weights,
                        help="weights of W_q: (3.20) (default), (3.21) or 1")
    parser.add_argument("--hybrid-start", choices=[s for s in HYBRID_STARTS if s != "given"], default=hybrid.start,
                        help="start of --method hybrid: least-squares relaxation (default) or a tree walk")
    parser.add_argument("--hybrid-kind", choices=FRAME_KINDS, default=hybrid.kind,
                        help=f"spanning tree of the tree-walk start of --method hybrid (default {hybrid.kind})")
    parser.add_argument("--smoothing-iterations", type=nonnegative_int, default=hybrid.smoothing_iterations,
                        metavar="K",
                        help=f"at most K Gauss-Newton iterations of --method hybrid "
                             f"(default {hybrid.smoothing_iterations})")
    parser.add_argument("--max-iterations", type=nonnegative_int, default=gn.max_iterations, metavar="N",
                        help=f"Gauss-Newton iteration limit (default {gn.max_iterations})")
    parser.add_argument("--fixed-face", type=int, metavar="F",
                        help="face fixing the rigid motion (default: a central, well-shaped face)")
    parser.add_argument("--solver", choices=SOLVERS,
                        help="sparse Cholesky backend (default cholmod if cvxopt is installed)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help="output mesh (.ply, .obj, .off, .stl) or .npz (vertices, faces, z)")
    add_allow_failure(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object with the results")


def _error(msg):
    """Bad input about meshes or targets (reported by :func:`lacore.cli.main` with exit code 2)."""
    return MeshError(msg)


def load_target(path, reference_faces, topology):
    """Lengths and angles ``(2E,)`` of one target (mesh or ``lacore encode`` .npz), in ``topology``'s edge order."""
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: no such file")
    if path.lower().endswith(".npz"):
        what = "'lacore encode'"
        with open_npz(path, what, MeshError) as data:
            missing = [k for k in ("faces", "edges", "lengths", "angles") if k not in data.files]
            if missing:
                raise _error(f"{path}: not a 'lacore encode' file (missing keys {', '.join(missing)})")
            faces = read_array(data, "faces", path, what, MeshError, kind="i", ndim=2)
            edges = read_array(data, "edges", path, what, MeshError, kind="i", ndim=2)
            lengths = read_array(data, "lengths", path, what, MeshError, kind="f", ndim=1)
            angles = read_array(data, "angles", path, what, MeshError, kind="f", ndim=1)
        _check_faces(path, faces, reference_faces)
        return _edge_order(path, edges, lengths, angles, topology)
    vertices, faces = load_mesh(path)
    if len(vertices) != topology.n_vertices:
        raise _error(f"{path} has {len(vertices)} vertices but the reference has {topology.n_vertices}: "
                     "the meshes are not in correspondence")
    _check_faces(path, faces, reference_faces)
    vertices = checked_vertices(path, vertices, topology)
    return lengths_and_angles(vertices, topology)


def _check_faces(path, faces, reference_faces):
    if faces.shape != reference_faces.shape:
        raise _error(f"{path} has {len(faces)} faces but the reference has {len(reference_faces)}: "
                     "the meshes are not in correspondence")
    if not np.array_equal(faces, reference_faces):
        bad = np.flatnonzero(np.any(faces != reference_faces, axis=1))
        raise _error(f"{path}: faces differ from the reference's (first at face {bad[0]}, {bad.size} in all): "
                     "the meshes are not in correspondence")


def _edge_order(path, edges, lengths, angles, topology):
    E = topology.n_edges
    if edges.shape != (E, 2) or lengths.shape != (E,) or angles.shape != (E,):
        raise _error(f"{path}: expected {E} edges, lengths and angles, got shapes {edges.shape}, "
                     f"{lengths.shape}, {angles.shape}")
    if np.array_equal(edges, topology.edges):
        return np.concatenate([lengths, angles])
    V = topology.n_vertices
    ours = np.sort(topology.edges, axis=1) @ [V, 1]
    theirs = np.sort(edges.astype(np.int64), axis=1) @ [V, 1]
    order = np.argsort(theirs)
    pos = np.searchsorted(theirs[order], ours)
    pos = np.minimum(pos, E - 1)
    if not np.array_equal(theirs[order][pos], ours):
        raise _error(f"{path}: its edges are not the edges of the reference mesh")
    idx = order[pos]  # angles do not depend on the edge orientation
    return np.concatenate([lengths[idx], angles[idx]])


def combine_targets(zs, weights=None):
    """``sum_i w_i z_i`` (default ``w_i = 1/n``)."""
    zs = np.asarray(zs, float)
    if weights is None:
        weights = np.full(len(zs), 1.0 / len(zs))
    weights = np.asarray(weights, float)
    if weights.shape != (len(zs),):
        raise CliError(f"got {len(weights)} weights for {len(zs)} targets")
    if not np.all(np.isfinite(weights)):
        raise CliError("the weights must be finite numbers")
    return weights @ zs, weights


def _save(path, vertices, faces, z):
    """Write the result atomically; returns the path written."""
    if path.lower().endswith(".npz"):
        return save_npz_atomic(path, vertices=vertices, faces=faces, z=z)
    save_mesh(path, vertices, faces)
    return path


def run(args):
    """Run ``lacore reconstruct``; returns the exit code (errors are raised for :func:`lacore.cli.main`)."""
    start = time.perf_counter()
    out_ext = os.path.splitext(args.output)[1].lower()
    if out_ext not in SUPPORTED_EXTENSIONS + (".npz",):
        raise _error(f"{args.output}: unsupported output format {out_ext or '(none)'!r}; use one of "
                     f"{', '.join(SUPPORTED_EXTENSIONS + ('.npz',))}")
    check_outputs([npz_path(args.output) if out_ext == ".npz" else args.output],
                  inputs=[args.ref, *args.target])
    ref_vertices, ref_faces = load_mesh(args.ref)
    topology = mesh_topology(args.ref, ref_faces, len(ref_vertices))
    ref_vertices = checked_vertices(args.ref, ref_vertices, topology)
    zs = [load_target(t, topology.faces, topology) for t in args.target]
    z_target, weights = combine_targets(zs, args.weights)
    t_load = time.perf_counter() - start

    settings = ReconstructionSettings(energy=args.energy, weights=args.energy_weights,
                                      bending_weight=args.bending_weight, fixed_face=args.fixed_face,
                                      solver=args.solver)
    hybrid = HybridOptions(start=args.hybrid_start, kind=args.hybrid_kind,
                           smoothing_iterations=args.smoothing_iterations)
    result = reconstruct(z_target, topology, ref_vertices, method=args.method, settings=settings,
                         options=GaussNewtonOptions(max_iterations=args.max_iterations), hybrid=hybrid)
    if np.all(np.isfinite(result.vertices)):
        errors = reconstruction_errors(result.vertices, z_target, topology)
    else:
        errors = dict.fromkeys(("max_length_error", "max_relative_length_error", "length_error_per_size",
                                "max_angle_error", "rms_length_error", "rms_angle_error"), float("nan"))
    t = time.perf_counter()
    z_out = lengths_and_angles(result.vertices, topology) if np.all(np.isfinite(result.vertices)) else \
        np.full(2 * topology.n_edges, np.nan)
    written = _save(args.output, result.vertices, topology.faces, z_out)
    t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    if args.json:
        summary = {
            "command": "reconstruct",
            "reference": args.ref,
            "targets": list(args.target),
            "weights": [float(w) for w in weights],
            "output": written,
            "vertices": int(topology.n_vertices),
            "faces": int(topology.n_faces),
            **result.summary(),
            **{k: json_float(v) for k, v in errors.items()},
            "seconds": seconds,
            "reconstruction_seconds": result.timings.get("total"),
            "load_seconds": t_load,
            "save_seconds": t_save,
        }
        print_json(summary)
    else:
        print(f"{written}: {result.method} reconstruction of {len(args.target)} target(s), "
              f"{topology.n_vertices} vertices")
        print(f"  {result.message}; {result.iterations} iterations, energy {result.energy:.6g} "
              f"({result.energy_name})")
        print(f"  max length error {errors['max_length_error']:.3g}, max angle error "
              f"{errors['max_angle_error']:.3g} rad; {seconds:.3f} s")
    return finish("reconstruct", result.success, result.message, args)
