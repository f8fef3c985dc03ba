"""What every ``lacore`` subcommand shares: the input-error type, exit codes, JSON output."""

import json
import sys

import numpy as np

from ..errors import InputError

__all__ = ["CliError", "EXIT_OK", "EXIT_USAGE", "print_json", "json_float"]

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
