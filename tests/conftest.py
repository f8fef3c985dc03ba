"""Shared test helpers.

The shared meshes live beside the repository: ``<repo>/../shared/data/meshes``
(CI clones main with shared/ beside it).  ``LACORE_SHARED_DATA`` overrides the
location (either the ``data`` folder or its ``meshes`` folder).
"""

import os
import sys
from pathlib import Path

import numpy as np
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


def load_mesh(relative: str):
    """Vertices ``(V, 3)`` float64 and faces ``(F, 3)`` int64 of a shared mesh (file order kept)."""
    import trimesh

    m = trimesh.load(shared_mesh(relative), process=False)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def load_topology(relative: str):
    """Vertices ``(V, 3)`` and the :class:`~lacore.topology.MeshTopology` of a shared mesh."""
    from lacore.topology import MeshTopology

    X, faces = load_mesh(relative)
    return X, MeshTopology.from_faces(faces, n_vertices=len(X))


# ----------------------------------------------------------------------------- Blender subprocess checks
def build_extension_zip(out_dir) -> str:
    """Build the extension zip for the current platform into ``out_dir``; returns its path."""
    import subprocess

    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "build_extension.py"), "--platform", "current",
                           "--output-dir", str(out_dir)], capture_output=True, text=True, cwd=REPO, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    zip_path = proc.stdout.strip().splitlines()[-1]
    assert zip_path.endswith(".zip") and os.path.isfile(zip_path), proc.stdout
    return zip_path


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory) -> str:
    """The extension zip for this platform, built once per test session."""
    pytest.importorskip("bpy", reason="the bpy module (pip install bpy==5.0.1) is needed for the add-on tests")
    return build_extension_zip(tmp_path_factory.mktemp("ext"))


def run_blender_check(script, zip_path, work: Path, timeout=600) -> dict:
    """Run a tests/blender/check_*.py script (installs ``zip_path`` into a throw-away
    BLENDER_USER_RESOURCES under ``work``) in a subprocess; returns its JSON result."""
    import json
    import subprocess

    env = dict(os.environ, BLENDER_USER_RESOURCES=str(work / "user_resources"))
    result = work / "result.json"
    proc = subprocess.run([sys.executable, str(script), "--zip", str(zip_path), "--workdir", str(work / "files"),
                           "--result", str(result)], capture_output=True, text=True, env=env, cwd=work,
                          timeout=timeout)
    details = f"\n--- stdout (tail) ---\n{proc.stdout[-4000:]}\n--- stderr (tail) ---\n{proc.stderr[-6000:]}"
    assert result.exists(), f"the Blender checks wrote no result (exit code {proc.returncode}){details}"
    data = json.loads(result.read_text())
    assert proc.returncode == 0 and data["ok"], data.get("error", "") + details
    return data
