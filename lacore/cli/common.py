"""What every ``lacore`` subcommand shares: the input-error type, exit codes, JSON output."""

import json
import os
import sys
import tempfile
from contextlib import contextmanager

import numpy as np

from ..errors import InputError

__all__ = ["CliError", "EXIT_OK", "EXIT_USAGE", "print_json", "json_float", "atomic_outputs"]

EXIT_OK = 0
EXIT_USAGE = 2  # bad input or usage, same code argparse uses


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


@contextmanager
def atomic_outputs(paths):
    """Write several output files all or nothing.

    Yields one temporary path per entry of ``paths`` (in the same directory,
    with the same extension, so writers that pick the format from it work).
    When the block finishes, every temporary file is moved onto its target
    with :func:`os.replace`; when it raises, the temporary files are removed and
    no target is touched.
    """
    temps = []
    try:
        for path in paths:
            directory = os.path.dirname(os.path.abspath(path))
            base = os.path.basename(path)
            fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{base}.", suffix=os.path.splitext(base)[1])
            os.close(fd)
            temps.append(tmp)
        yield list(temps)
        for tmp, path in zip(temps, paths, strict=True):
            os.replace(tmp, path)
        temps = []
    finally:
        for tmp in temps:
            if os.path.exists(tmp):
                os.remove(tmp)
