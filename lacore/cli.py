"""Command line interface: ``lacore <subcommand> ...``.

Subcommands are registered in :data:`SUBCOMMANDS` (name -> :class:`Subcommand`).
To add one (e.g. ``reconstruct`` or ``interpolate``), write a ``_configure_x(parser)``
function that declares its arguments and a ``_run_x(args) -> int`` function,
then add ``Subcommand("x", help, _configure_x, _run_x)`` to the registry (or call
:func:`register_subcommand` from another module imported here).

Conventions shared by all subcommands:

* ``--json`` prints exactly ONE JSON object on stdout (nothing else on stdout);
* bad input (missing file, invalid mesh, ...) prints ``lacore <cmd>: error: ...``
  on stderr and exits with code 2, without a traceback;
* results go to ``.npz`` files (``numpy.load``) with documented keys.
"""

import argparse
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import cli_fit, cli_interpolate, cli_model, cli_reconstruct

__all__ = ["main", "Subcommand", "SUBCOMMANDS", "register_subcommand", "CliError"]

EXIT_OK = 0
EXIT_USAGE = 2  # bad input or usage, same code argparse uses


class CliError(Exception):
    """An error to report as ``lacore <cmd>: error: <message>`` with exit code 2."""


@dataclass(frozen=True)
class Subcommand:
    name: str
    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


SUBCOMMANDS: dict[str, Subcommand] = {}


def register_subcommand(name, help, configure, run):
    """Register (or replace) a subcommand; see the module docstring."""
    SUBCOMMANDS[name] = Subcommand(name, help, configure, run)


def _print_json(obj):
    json.dump(obj, sys.stdout, allow_nan=False)
    sys.stdout.write("\n")
    sys.stdout.flush()


def _json_float(x):
    """A float for JSON (NaN/inf are not valid JSON: they become None)."""
    x = float(x)
    return x if np.isfinite(x) else None


# --------------------------------------------------------------------------- encode
def _configure_encode(parser):
    parser.add_argument("mesh", metavar="MESH", help="triangle mesh (.ply, .obj, .off, .stl)")
    parser.add_argument("-o", "--output", metavar="OUT.npz",
                        help="write faces, edges, vertices, lengths, angles (and z) to this .npz file")
    parser.add_argument("--json", action="store_true", help="print one JSON object with counts and timings")


def encode_mesh(vertices, faces):
    """Encode one mesh: returns ``(topology, z, violation, timings)``."""
    from .integrability import integrability_violation
    from .lengths_angles import check_nondegenerate, lengths_and_angles
    from .topology import MeshTopology

    t0 = time.perf_counter()
    topology = MeshTopology.from_faces(faces, n_vertices=len(vertices))
    vertices = check_nondegenerate(vertices, topology)  # shape, NaN/inf, zero-area triangles
    t1 = time.perf_counter()
    z = np.asarray(lengths_and_angles(vertices, topology), dtype=np.float64)
    t2 = time.perf_counter()
    violation = np.asarray(integrability_violation(z, topology), dtype=np.float64)
    t3 = time.perf_counter()
    timings = {"topology": t1 - t0, "lengths_angles": t2 - t1, "integrability": t3 - t2}
    return topology, z, violation, timings


def _run_encode(args):
    from .mesh_io import load_mesh

    start = time.perf_counter()
    vertices, faces = load_mesh(args.mesh)
    t_load = time.perf_counter() - start
    topology, z, violation, timings = encode_mesh(vertices, faces)
    E = topology.n_edges
    lengths, angles = z[:E], z[E:]
    t_save = 0.0
    if args.output:
        t = time.perf_counter()
        out = args.output if args.output.endswith(".npz") else args.output + ".npz"
        np.savez(out, vertices=vertices, faces=topology.faces, edges=topology.edges,
                 lengths=lengths, angles=angles, z=z, integrability_violation=violation)
        t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    max_violation = float(violation.max()) if violation.size else 0.0
    summary = {
        "command": "encode",
        "mesh": args.mesh,
        "output": args.output,
        "vertices": int(topology.n_vertices),
        "edges": int(E),
        "faces": int(topology.n_faces),
        "boundary_edges": int(np.count_nonzero(topology.is_boundary_edge)),
        "boundary_vertices": len(topology.boundary_vertices),
        "min_length": _json_float(lengths.min()),
        "max_length": _json_float(lengths.max()),
        "max_abs_angle": _json_float(np.abs(angles).max()),
        "max_integrability_violation": _json_float(max_violation),
        "seconds": seconds,
        "timings": {"load": t_load, **timings, "save": t_save},
    }
    if args.json:
        _print_json(summary)
    else:
        print(f"{args.mesh}: {summary['vertices']} vertices, {E} edges ({summary['boundary_edges']} on the "
              f"boundary), {summary['faces']} faces")
        print(f"  lengths in [{lengths.min():.6g}, {lengths.max():.6g}], max |angle| {np.abs(angles).max():.6g} rad, "
              f"max integrability violation {max_violation:.3g}")
        if args.output:
            print(f"  wrote {args.output}")
        print(f"  {seconds:.3f} s")
    return EXIT_OK


register_subcommand("encode", "encode a mesh as edge lengths and dihedral angles", _configure_encode, _run_encode)
register_subcommand("reconstruct", cli_reconstruct.HELP, cli_reconstruct.configure, cli_reconstruct.run)
register_subcommand("interpolate", cli_interpolate.HELP, cli_interpolate.configure, cli_interpolate.run)
cli_model.register(register_subcommand)  # model, model-sweep
cli_fit.register(register_subcommand)  # fit


# --------------------------------------------------------------------------- main
def build_parser():
    parser = argparse.ArgumentParser(
        prog="lacore", description="Lengths & Angles: shape processing in lengths and dihedral angles.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for cmd in SUBCOMMANDS.values():
        p = sub.add_parser(cmd.name, help=cmd.help, description=cmd.help)
        cmd.configure(p)
        p.set_defaults(_subcommand=cmd)
    return parser


def main(argv=None):
    """Entry point of the ``lacore`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    cmd = args._subcommand
    from .errors import MeshError

    try:
        return int(cmd.run(args) or 0)
    except (CliError, MeshError, FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"lacore {cmd.name}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (ValueError, OSError) as exc:  # other bad-input errors (e.g. LengthsAnglesError, unreadable file)
        print(f"lacore {cmd.name}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
