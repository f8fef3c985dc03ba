"""What every ``lacore`` subcommand shares: the input-error type, exit codes, JSON output."""

import argparse
import json
import os
import sys

import numpy as np

from ..errors import MAX_WEIGHT, InputError, MeshError
from ..geometry.lengths_angles import check_nondegenerate
from ..io.atomic import check_writable
from ..io.meshes import load_mesh
from ..geometry.topology import MeshTopology

__all__ = ["CliError", "EXIT_OK", "EXIT_USAGE", "EXIT_FAILED_CHECKS", "EXIT_INTERRUPTED", "print_json", "json_float",
           "nonnegative_int", "positive_int", "frame_count", "MAX_FRAMES", "MAX_WEIGHT", "check_number",
           "weight", "add_allow_failure", "exit_code", "finish",
           "error_message", "check_outputs", "load_meshes_in_correspondence", "mesh_topology", "checked_vertices"]

EXIT_OK = 0
EXIT_USAGE = 2  # bad input or usage, same code argparse uses
#: The command ran and wrote its output, but the result failed its checks
#: (:mod:`lacore.reconstruction.checks`); ``--allow-failure`` turns this into 0.
EXIT_FAILED_CHECKS = 3
#: Stopped by Ctrl-C (SIGINT), as shells report it (128 + 2).
EXIT_INTERRUPTED = 130


#: Most output frames one command writes (``--frames``): more are a typing error, not a request.
MAX_FRAMES = 100_000


def check_number(option, value, low, high, low_open=False):
    """``value`` as a float if it is finite and within ``[low, high]`` (``(low, high]`` with ``low_open``);
    else :class:`CliError` naming ``option`` and the range, e.g. ``--prior-weight must be a number in (0, 1e+06],
    got 1e+308``."""
    v = float(value)
    if not (np.isfinite(v) and (v > low if low_open else v >= low) and v <= high):
        raise CliError(f"{option} must be a number in {'(' if low_open else '['}{low:g}, {high:g}], got {v:g}")
    return v


def weight(text):
    """argparse type of weights that may be 0 (``--bending-weight``): a number in ``[0, MAX_WEIGHT]``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (np.isfinite(value) and 0 <= value <= MAX_WEIGHT):
        raise argparse.ArgumentTypeError(f"must be a number in [0, {MAX_WEIGHT:g}], got {value:g}")
    return value


def _int_at_least(low, what, high=None):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be {what}, got {value}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"must be at most {high}, got {value}")
        return value
    parse.__name__ = "integer"
    return parse


#: argparse type of counts that may be 0 (``--max-iterations``, ``--smoothing-iterations``).
nonnegative_int = _int_at_least(0, "a non-negative integer")
#: argparse type of counts that must be at least 1 (``--modes``, ``--workers``).
positive_int = _int_at_least(1, "a positive integer")
#: argparse type of frame counts: 1 to :data:`MAX_FRAMES`.
frame_count = _int_at_least(1, "a positive integer", MAX_FRAMES)


def add_allow_failure(parser):
    """Declare ``--allow-failure`` (exit 0 instead of :data:`EXIT_FAILED_CHECKS`)."""
    parser.add_argument("--allow-failure", action="store_true",
                        help=f"exit 0 even when the result fails its checks (default: exit {EXIT_FAILED_CHECKS}; "
                             "the output is written either way)")


def exit_code(success, args):
    """:data:`EXIT_OK`, or :data:`EXIT_FAILED_CHECKS` for a failed result without ``--allow-failure``."""
    return EXIT_OK if success or getattr(args, "allow_failure", False) else EXIT_FAILED_CHECKS


def finish(command, success, message, args):
    """The exit code of a command whose result is written; a failed result is also reported on stderr.

    Prints ``lacore <command>: failed: <message>`` (``warning`` with
    ``--allow-failure``) as one line when ``success`` is false; returns
    :func:`exit_code`.
    """
    if not success:
        label = "warning" if getattr(args, "allow_failure", False) else "failed"
        text = " ".join(str(message).split()) or "the result failed its checks"
        print(f"lacore {command}: {label}: {text}", file=sys.stderr, flush=True)
    return exit_code(success, args)


def error_message(exc):
    """One line for the user from an error of bad input or of the system (file, memory)."""
    if isinstance(exc, MemoryError):
        return "not enough memory: use a smaller input or fewer frames"
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


class CliError(InputError):
    """Bad command-line input, reported as ``lacore <cmd>: error: <message>`` with exit code 2."""


def print_json(obj):
    """Print ONE JSON object on stdout (NaN/inf are an error: use :func:`json_float`)."""
    json.dump(obj, sys.stdout, allow_nan=False)
    sys.stdout.write("\n")
    sys.stdout.flush()


def json_float(x):
    """A float for JSON (NaN/inf are not valid JSON: they become None)."""
    x = float(x)
    return x if np.isfinite(x) else None


def check_outputs(paths, inputs=()):
    """Fail before computing unless every output file can be written: its folder exists and takes a new file,
    and no folder stands at its path (:func:`lacore.io.atomic.check_writable`; the OSError names the file), and
    none of them is one of the ``inputs`` (:class:`CliError`: an output would replace its own input)."""
    for i, path in enumerate(paths):
        if i == 0 or os.path.isdir(path):
            check_writable(path)
    existing = [p for p in inputs if p and os.path.isfile(p)]
    for path in paths:
        if os.path.isfile(path):
            same = next((p for p in existing if os.path.samefile(p, path)), None)
            if same is not None:
                raise CliError(f"the output {path} is the input {same}: write the result to another file")


def load_meshes_in_correspondence(paths):
    """Vertices of every mesh file and the topology of the first.

    Returns ``(shapes, topology)``: a list of ``(V, 3)`` arrays (each checked for
    degenerate triangles) and the :class:`~lacore.geometry.topology.MeshTopology` of the first
    file.  A mesh with another vertex count or other faces than the first raises
    :class:`~lacore.errors.MeshError` ("... is not in dense correspondence with ...").
    """
    X0, faces = load_mesh(paths[0])
    topology = mesh_topology(paths[0], faces, len(X0))
    shapes = [checked_vertices(paths[0], X0, topology)]
    for path in paths[1:]:
        X, F = load_mesh(path)
        if len(X) != len(X0) or F.shape != faces.shape or not np.array_equal(F, faces):
            raise MeshError(f"{path} ({len(X)} vertices, {len(F)} faces) is not in dense correspondence with "
                            f"{paths[0]} ({len(X0)} vertices, {len(faces)} faces)")
        shapes.append(checked_vertices(path, X, topology))
    return shapes, topology


def mesh_topology(path, faces, n_vertices):
    """:meth:`MeshTopology.from_faces` of a mesh file's faces; its MeshError names the file."""
    try:
        return MeshTopology.from_faces(faces, n_vertices=n_vertices)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None


def checked_vertices(path, vertices, topology):
    """:func:`~lacore.geometry.lengths_angles.check_nondegenerate` of a mesh file's vertices; its MeshError names
    the file."""
    try:
        return check_nondegenerate(vertices, topology)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
