"""``lacore mixer`` and ``lacore mix``: nonlinear shape-key mixing on the command line.

Usage::

    lacore mixer KEY0.ply KEY1.ply ... -o MIXER.npz [--reduced-size R] [--range LOW HIGH] [--local-vertices N]
                 [--relative-to I1 I2 ...] [--masks MASKS.npy] [--json]
    lacore mix MIXER.npz --weights W1 W2 ... [--weights ...] -o OUT.ply [--polish] [--json]

``lacore mixer`` builds a :class:`lacore.shapes.mixing.ShapeMixer` from two or more meshes in dense
correspondence (the first is the basis, like Blender's relative shape keys) and saves it to one
``.npz``.  ``--relative-to`` gives each non-basis key's relative key (an index of the keys, 0 the basis; Blender's
*Relative To*) and ``--masks`` a ``(K-1, V)`` array of per-vertex factors in ``[0, 1]`` (``.npy``, or text with one
row per non-basis key, ``.txt``/``.csv``; Blender's vertex-group weights of each key): the mixer blends
``z_0 + sum_k w_k m_k (z_k - z_rel(k))`` (:meth:`ShapeMixer.build`).  ``--json`` prints one object with
``vertices``, ``keys``, ``reduced_size``, ``cubature_edges``, ``local_vertices`` (how many vertices the local
correction moves; 0: none), ``megabytes`` (the mixer in memory), ``seconds`` and the wall seconds of each build stage
(``build_seconds``: ``setup``, ``corners`` with masks or relative keys, ``derivatives``, ``basis``,
``newton_vectors``, ``cubature``, plus ``load`` and ``save``) and their CPU seconds (``build_cpu_seconds``).

``lacore mix`` mixes: one weight per non-basis key in each ``--weights`` group.  One group writes
``OUT.ply``; several write ``OUT_000.ply``, ``OUT_001.ply``, ... (one per group, in order; the
format follows the extension of ``OUT``).  ``--json`` prints one object with, per output file, its
``weights``, ``seconds``, ``energy``, ``indicator``, ``in_range``, ``message``, ``iterations`` and
``polished``.  Weights outside the mixer's accurate range (or a large error indicator) are
written and reported on one stderr line, exit code 3 (0 with ``--allow-failure``); ``--polish``
finishes every mix with the full Gauss-Newton projection.

Bad input (fewer than 2 keys, meshes not in correspondence, a damaged or foreign mixer file, the
wrong number of weights) prints one line on stderr and exits with code 2; nothing is written then
(outputs are checked before computing, every file is written atomically).
"""

import os
import time

import numpy as np

from ..io.meshes import MESH_FORMATS, save_mesh
from ..shapes.mixing import MixerError, MixerOptions, ShapeMixer, check_key_count, check_keys, check_masks
from .common import (EXIT_OK, add_allow_failure, check_number, check_outputs, finish, json_float,
                     load_meshes_in_correspondence, positive_int, print_json)
from .interpolate import output_paths

__all__ = ["register", "configure_mixer", "run_mixer", "configure_mix", "run_mix", "mix_output_paths", "read_masks",
           "MIXER_HELP", "MIX_HELP"]

MIXER_HELP = "build a shape mixer (nonlinear blends of shape keys in lengths and angles) from meshes"
MIX_HELP = "mix shape keys with a mixer built by `lacore mixer`: one mesh per --weights group"
#: Largest ``|LOW|``, ``|HIGH|`` of ``--range``: weights of a thousand times a key are far beyond any mix (the
#: default range is -0.5 1.5), and ranges near float64's limit made the mixer's sample shapes overflow.
MAX_MIX_RANGE = 1e3


def register(register_subcommand):
    """Register both subcommands with ``register_subcommand(name, help, configure, run)`` (:mod:`lacore.cli`)."""
    register_subcommand("mixer", MIXER_HELP, configure_mixer, run_mixer)
    register_subcommand("mix", MIX_HELP, configure_mix, run_mix)


def configure_mixer(parser):
    """Arguments of ``lacore mixer``."""
    parser.add_argument("keys", nargs="+", metavar="KEY",
                        help="two or more meshes in dense correspondence; the first is the basis")
    parser.add_argument("-o", "--output", required=True, metavar="MIXER.npz", help="mixer file to write")
    parser.add_argument("--reduced-size", type=positive_int, default=None, metavar="R",
                        help="largest size of the reduced space (default: automatic)")
    parser.add_argument("--range", type=float, nargs=2, default=(MixerOptions.low, MixerOptions.high),
                        metavar=("LOW", "HIGH"),
                        help=f"weights the mixer is built accurate for, per key (default {MixerOptions.low:g} "
                             f"{MixerOptions.high:g}); outside, a mix is flagged")
    parser.add_argument("--local-vertices", type=int, default=MixerOptions.local_vertices, metavar="N",
                        help="vertices of the local correction, where the reduced space misses most (default "
                             "%(default)s; 0: none)")
    parser.add_argument("--max-keys", type=positive_int, default=MixerOptions.max_keys, metavar="N",
                        help="most keys mixed besides the basis (default %(default)s: the build grows steeply with "
                             "every key)")
    parser.add_argument("--relative-to", type=int, nargs="+", default=None, metavar="I",
                        help="each non-basis key's relative key, an index of the keys (0: the basis, the default)")
    parser.add_argument("--masks", default=None, metavar="MASKS.npy",
                        help="per-vertex factors in [0, 1] of each non-basis key, one row per key (.npy, or text: "
                             ".txt, .csv); default 1")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the mixer's summary")


def configure_mix(parser):
    """Arguments of ``lacore mix``."""
    parser.add_argument("mixer", metavar="MIXER.npz", help="a mixer written by `lacore mixer`")
    parser.add_argument("--weights", type=float, nargs="+", action="append", required=True, metavar="W",
                        help="one weight per non-basis key; repeat for several meshes")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.ply",
                        help="mesh to write (several --weights: OUT_000.ply, OUT_001.ply, ...)")
    parser.add_argument("--polish", action="store_true",
                        help="finish every mix with the full Gauss-Newton projection (exact, slower)")
    add_allow_failure(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run_mixer(args):
    """Run ``lacore mixer``; returns the exit code (bad input raises for :func:`lacore.cli.main`)."""
    start = time.perf_counter()
    if not args.output.lower().endswith(".npz"):
        raise MixerError(f"the mixer file must end in .npz, got {args.output}")
    check_outputs([args.output], inputs=args.keys)
    if len(args.keys) < 2:
        raise MixerError(f"a mixer needs at least 2 keys (the basis and one more), got {len(args.keys)}")
    for value in args.range:
        check_number("--range", value, -MAX_MIX_RANGE, MAX_MIX_RANGE)
    options = MixerOptions(reduced_size=args.reduced_size, low=args.range[0], high=args.range[1],
                           local_vertices=args.local_vertices, max_keys=args.max_keys)  # checks --range and others
    check_key_count(len(args.keys), options, raise_with="raise --max-keys")
    shapes, topology = load_meshes_in_correspondence(args.keys)
    names = [repr(k) for k in args.keys]
    check_keys(shapes, topology.faces, names=names)                        # names the files, before the build
    masks = None if args.masks is None else read_masks(args.masks)
    masks, relative_to = check_masks(masks, args.relative_to, len(shapes), len(shapes[0]), names=names)
    t_load = time.perf_counter() - start
    mixer = ShapeMixer.build(np.stack(shapes), topology.faces, options, masks=masks, relative_to=relative_to,
                             names=names)
    t = time.perf_counter()
    mixer.save(args.output)
    t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    stages = {"load": t_load, **{k: v for k, v in mixer.build_seconds.items() if k != "total"}, "save": t_save}
    summary = {"command": "mixer", "output": args.output, "vertices": int(mixer.n_vertices),
               "keys": int(mixer.n_keys), "reduced_size": mixer.reduced_size,
               "cubature_edges": mixer.cubature_size, "local_vertices": len(mixer.local_vertices),
               "megabytes": mixer.nbytes / 2 ** 20, "seconds": seconds, "build_seconds": stages,
               "build_cpu_seconds": {k: v for k, v in mixer.build_cpu_seconds.items() if k != "total"}}
    if args.json:
        print_json(summary)
    else:
        print(f"mixer of {mixer.n_keys} keys ({mixer.n_vertices} vertices): reduced size {mixer.reduced_size}, "
              f"{mixer.cubature_size} cubature edges")
        print("  stages: " + ", ".join(f"{k} {v:.3f} s" for k, v in stages.items()))
        print(f"  wrote {args.output} in {seconds:.3f} s")
    return EXIT_OK


def read_masks(path):
    """The ``(K-1, V)`` array of a ``--masks`` file: ``.npy``, or text (``.txt``, ``.csv``: one row per key)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".npy", ".txt", ".csv"):
        raise MixerError(f"--masks {path}: use a .npy file or a text file (.txt, .csv) with one row per non-basis key")
    try:
        if ext == ".npy":
            a = np.load(path, allow_pickle=False)
        else:
            a = np.loadtxt(path, delimiter="," if ext == ".csv" else None, ndmin=2)
        if np.iscomplexobj(a):  # (float() would drop the imaginary parts)
            raise TypeError("complex numbers")
        return np.asarray(a, float)
    except OSError as exc:
        raise MixerError(f"--masks {path}: cannot read it ({exc.strerror or exc})") from None
    except (ValueError, TypeError) as exc:  # (TypeError: an .npz archive named .npy)
        raise MixerError(f"--masks {path}: not an array of numbers ({str(exc).splitlines()[0]})") from None


def mix_output_paths(output, n):
    """``[output]`` for one mix, else ``stem_000.ext ... stem_{n-1}.ext``; the extension gives the format."""
    stem, ext = os.path.splitext(output)
    fmt = ext[1:].lower()
    if fmt not in MESH_FORMATS:
        raise MixerError(f"the output must end in {', '.join('.' + f for f in MESH_FORMATS)}, got {output}")
    return [output] if n == 1 else output_paths(stem, n, fmt)


def run_mix(args):
    """Run ``lacore mix``; returns the exit code."""
    start = time.perf_counter()
    groups = [np.asarray(g, float) for g in args.weights]
    for g in groups:
        if not np.all(np.isfinite(g)):
            raise MixerError(f"--weights must be finite numbers, got {' '.join(f'{v:g}' for v in g)}")
    paths = mix_output_paths(args.output, len(groups))
    check_outputs(paths, inputs=[args.mixer])
    mixer = ShapeMixer.load(args.mixer)
    m = mixer.n_keys - 1
    for g in groups:
        if len(g) != m:
            raise MixerError(f"--weights needs {m} numbers (one per non-basis key of {args.mixer}), got {len(g)}")
    t_load = time.perf_counter() - start
    results = [mixer.mix(g, polish=args.polish) for g in groups]
    for path, r in zip(paths, results, strict=True):
        save_mesh(path, r.vertices, mixer.faces)  # each file atomically (lacore.io.atomic)
    seconds = time.perf_counter() - start
    outputs = [{"file": p, "weights": [float(v) for v in r.weights], "seconds": float(r.seconds),
                "energy": json_float(r.energy), "indicator": json_float(r.indicator), "in_range": bool(r.in_range),
                "message": r.message, "iterations": int(r.iterations), "polished": bool(r.polished)}
               for p, r in zip(paths, results, strict=True)]
    off = [i for i, r in enumerate(results) if not r.in_range]
    if args.json:
        print_json({"command": "mix", "mixer": args.mixer, "vertices": int(mixer.n_vertices),
                    "keys": int(mixer.n_keys), "reduced_size": mixer.reduced_size, "outputs": outputs,
                    "load_seconds": t_load, "seconds": seconds, "success": not off, "out_of_range": off})
    else:
        for o in outputs:
            note = "" if o["in_range"] else f" ({o['message']})"
            print(f"  {o['file']}: weights {' '.join(f'{v:g}' for v in o['weights'])}, {1e3 * o['seconds']:.1f} ms, "
                  f"energy {o['energy']:.4g}{note}")
        print(f"  total {seconds:.3f} s")
    message = ""
    if off:
        message = (f"{len(off)} of {len(results)} mixes are outside the mixer's accurate range (mix {off[0]}: "
                   f"{results[off[0]].message})")
    return finish("mix", not off, message, args)
