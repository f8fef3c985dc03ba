"""Command line interface: ``lacore <subcommand> ...`` (also ``python -m lacore.cli``).

One module per subcommand (:mod:`.encode`, :mod:`.reconstruct`,
:mod:`.interpolate`), each with ``HELP``, ``configure(parser)`` (declares its
arguments) and ``run(args) -> int``; they are registered in :data:`SUBCOMMANDS`
(name -> :class:`Subcommand`) by :func:`register_subcommand` below.  To add one,
write such a module and register it here.

Conventions shared by all subcommands:

* ``--json`` prints exactly ONE JSON object on stdout (nothing else on stdout);
* a usage error (an unknown option, a missing or unreadable argument) prints ONE line
  ``lacore <cmd>: error: ... (usage: lacore <cmd> --help)`` and exits with code 2;
* bad input -- a :class:`lacore.errors.InputError` (invalid mesh, target,
  option; :class:`CliError` is one), an ``OSError`` (missing, unreadable or
  unwritable file) or a ``MemoryError`` -- prints ONE line
  ``lacore <cmd>: error: ...`` on stderr and exits with code 2, without a
  traceback; any other exception is a bug and shows its traceback;
* a command that ran but whose result failed its checks
  (:mod:`lacore.reconstruction.checks`) writes its output, prints
  ``lacore <cmd>: failed: ...`` on stderr (:func:`.common.finish`) and exits
  with code 3 (:data:`EXIT_FAILED_CHECKS`), or 0 with ``--allow-failure``
  (then the line says ``warning``); the JSON has ``success`` and ``failure``;
* NumPy's floating-point RuntimeWarnings are not shown (the checks and the
  messages say what went wrong);
* Ctrl-C prints ``lacore <cmd>: interrupted`` and exits with code 130
  (:data:`EXIT_INTERRUPTED`); a closed stdout (``lacore ... --json | head``)
  ends the command quietly with code 141;
* results go to ``.npz`` files (``numpy.load``) with documented keys, and every
  output is written atomically (:mod:`lacore.io.atomic`): a failed write leaves
  an existing file unchanged and no temporary file.
"""

import argparse
import os
import re
import signal
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass

from .. import __version__
from ..errors import InputError
from . import encode, fit, interpolate, mixer, model, reconstruct
from .common import EXIT_FAILED_CHECKS, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, CliError, error_message
from .encode import encode_mesh

__all__ = ["main", "Subcommand", "SUBCOMMANDS", "register_subcommand", "CliError", "encode_mesh", "EXIT_OK",
           "EXIT_USAGE", "EXIT_FAILED_CHECKS", "EXIT_INTERRUPTED"]


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
mixer.register(register_subcommand)  # mixer, mix


# --------------------------------------------------------------------------- main
class _Parser(argparse.ArgumentParser):
    """argparse with the conventions above: a usage error is ONE line (with where to read the usage), and numbers
    written with an exponent (``-1e6``) are values, not options."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (usage: {self.prog} --help)\n")


def build_parser():
    parser = _Parser(
        prog="lacore", description="Lengths & Angles: shape processing in lengths and dihedral angles.")
    parser.add_argument("--version", action="version", version=f"lacore {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)
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
    try:
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        return _interrupted("lacore", owns_process=argv is None)
    cmd = args._subcommand
    try:
        with warnings.catch_warnings():
            # NumPy's floating-point warnings (overflow in an extreme input...) are not for the user: the result's
            # checks or the error message say what went wrong, in one line
            warnings.filterwarnings("ignore", message=_FLOATING_POINT_WARNINGS, category=RuntimeWarning)
            return int(cmd.run(args) or 0)
    except KeyboardInterrupt:
        return _interrupted(f"lacore {cmd.name}", owns_process=argv is None)
    except BrokenPipeError:  # stdout closed by the reader (`lacore ... --json | head`): nothing left to say
        _silence_stdout()
        return 141  # as a shell reports a process ended by SIGPIPE (128 + 13)
    except (InputError, OSError, MemoryError) as exc:
        print(f"lacore {cmd.name}: error: {error_message(exc)}", file=sys.stderr)
        return EXIT_USAGE


_FLOATING_POINT_WARNINGS = r"(overflow|underflow|invalid value|divide by zero) encountered"


def _interrupted(who, owns_process):
    """Say ``<who>: interrupted`` and return :data:`EXIT_INTERRUPTED`.  As the process's program, the command
    has cleaned up (outputs are atomic, workers joined): it ignores further Ctrl-C and leaves at once with 130,
    so that a late signal during the interpreter's teardown cannot end it by signal instead."""
    _ignore_further_interrupts(owns_process)
    print(f"{who}: interrupted", file=sys.stderr)
    if owns_process:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(EXIT_INTERRUPTED)
    return EXIT_INTERRUPTED


def _ignore_further_interrupts(owns_process):
    """After the first Ctrl-C the command only cleans up and exits 130: a second one must not turn that into a
    traceback or a death by signal.  Only when :func:`main` runs as the process's program (``argv`` not given:
    the console script, ``python -m lacore.cli``), never for a caller that goes on after it returns."""
    if not owns_process:
        return
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread (main() called from a thread)
        pass


def _silence_stdout():
    """Point stdout at the null device, so that the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass
