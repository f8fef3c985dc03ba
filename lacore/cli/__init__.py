"""Command line interface: ``lacore <subcommand> ...`` (also ``python -m lacore.cli``).

One module per subcommand (:mod:`.encode`, :mod:`.reconstruct`,
:mod:`.interpolate`), each with ``HELP``, ``configure(parser)`` (declares its
arguments) and ``run(args) -> int``; they are registered in :data:`SUBCOMMANDS`
(name -> :class:`Subcommand`) by :func:`register_subcommand` below.  To add one,
write such a module and register it here.

Conventions shared by all subcommands:

* ``--json`` prints exactly ONE JSON object on stdout (nothing else on stdout);
* bad input -- a :class:`lacore.errors.InputError` (invalid mesh, target,
  option; :class:`CliError` is one) or an ``OSError`` (missing, unreadable or
  unwritable file) -- prints ``lacore <cmd>: error: ...`` on stderr and exits
  with code 2, without a traceback; any other exception is a bug and shows its
  traceback;
* a command that ran but whose result failed its checks
  (:mod:`lacore.reconstruction.checks`) writes its output, prints
  ``lacore <cmd>: failed: ...`` on stderr and exits with code 3
  (:data:`EXIT_FAILED_CHECKS`), or 0 with ``--allow-failure``; the JSON has
  ``success`` and ``failure``;
* results go to ``.npz`` files (``numpy.load``) with documented keys, and every
  output is written atomically (:mod:`lacore.io.atomic`): a failed write leaves
  an existing file unchanged and no temporary file.
"""

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass

from ..errors import InputError
from . import encode, fit, interpolate, model, reconstruct
from .common import EXIT_FAILED_CHECKS, EXIT_OK, EXIT_USAGE, CliError
from .encode import encode_mesh

__all__ = ["main", "Subcommand", "SUBCOMMANDS", "register_subcommand", "CliError", "encode_mesh", "EXIT_OK",
           "EXIT_USAGE", "EXIT_FAILED_CHECKS"]


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


register_subcommand("encode", encode.HELP, encode.configure, encode.run)
register_subcommand("reconstruct", reconstruct.HELP, reconstruct.configure, reconstruct.run)
register_subcommand("interpolate", interpolate.HELP, interpolate.configure, interpolate.run)
model.register(register_subcommand)  # model, model-sweep
fit.register(register_subcommand)  # fit


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
    """Entry point of the ``lacore`` console script; returns the exit code.

    Examples
    --------
    >>> import os, tempfile
    >>> from lacore.cli import main
    >>> from lacore.io.meshes import save_mesh
    >>> from lacore.samples.bar import bar_mesh
    >>> path = os.path.join(tempfile.mkdtemp(), "bar.ply")
    >>> save_mesh(path, *bar_mesh(n_along=4, n_side=1))
    >>> main(["encode", path])                       # prints a summary, returns the exit code
    /...bar.ply: 22 vertices, 60 edges (0 on the boundary), 40 faces
      lengths in [0.707107, 1.80278], max |angle| 1.5708 rad
      integrable: the frames close around every vertex ...
      ... s
    0
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    cmd = args._subcommand
    try:
        return int(cmd.run(args) or 0)
    except (InputError, OSError) as exc:
        print(f"lacore {cmd.name}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
