"""Shared test helpers.

The shared meshes live beside the repository: ``<repo>/../shared/data/meshes``
(CI clones main with shared/ beside it).  ``LACORE_SHARED_DATA`` overrides the
location (either the ``data`` folder or its ``meshes`` folder).
"""

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # lacore importable even without `pip install -e .`
    sys.path.insert(0, str(REPO))


def shared_data_dir() -> Path:
    """The ``shared/data`` directory (contains ``meshes/``)."""
    env = os.environ.get("LACORE_SHARED_DATA")
    path = Path(env) if env else REPO.parent / "shared" / "data"
    if path.name == "meshes":
        path = path.parent
    return path


def shared_meshes_dir() -> Path:
    path = shared_data_dir() / "meshes"
    if not path.is_dir():
        pytest.fail(f"shared meshes not found at {path}: put shared/ beside the repository "
                    "or set LACORE_SHARED_DATA", pytrace=False)
    return path


def shared_mesh(relative: str) -> Path:
    """Path of a shared mesh, e.g. ``shared_mesh("finger/finger0.ply")``."""
    path = shared_meshes_dir() / relative
    if not path.is_file():
        pytest.fail(f"shared mesh {relative} not found in {shared_meshes_dir()}", pytrace=False)
    return path


@pytest.fixture(scope="session")
def meshes_dir() -> Path:
    return shared_meshes_dir()
