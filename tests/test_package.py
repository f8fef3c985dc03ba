"""The top-level ``lacore`` namespace: every advertised name resolves, heavy modules load on first use."""

import subprocess
import sys

import pytest

import lacore


def test_all_names_resolve():
    for name in lacore.__all__:
        assert callable(getattr(lacore, name)) or isinstance(getattr(lacore, name), type), name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        lacore.nope  # noqa: B018


def test_interpolation_is_imported_lazily():
    code = ("import sys, lacore; a = 'scipy.interpolate' in sys.modules; lacore.interpolate; "
            "print(a, 'scipy.interpolate' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True"]
