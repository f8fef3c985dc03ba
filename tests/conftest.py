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
    """Vertices ``(V, 3)`` and the :class:`~lacore.geometry.topology.MeshTopology` of a shared mesh."""
    from lacore.geometry.topology import MeshTopology

    X, faces = load_mesh(relative)
    return X, MeshTopology.from_faces(faces, n_vertices=len(X))


# ----------------------------------------------------------------------------- Blender subprocess checks
# The Blender checks (tests/blender/check_*.py) run in SUBPROCESSES, in venvs holding only bpy (a venv
# with SciPy installed would hide the extension's bundled wheels).  One venv per tested Blender:
#   4.2: bpy 4.2.x, Python 3.11, NumPy 1.26 (the oldest supported LTS)
#   5.2: bpy 5.2.x, Python 3.13, NumPy 2.5 (the newest)
# `make test` creates them and passes their interpreters in LACORE_BLENDER_PYTHONS
# ("4.2=/path/bin/python:5.2=/path/bin/python") with LACORE_REQUIRE_BLENDERS=1 (a missing one FAILS).
# By hand, the default locations <repo>/.venv-blender42 and .venv-blender52 are used and a missing
# one is SKIPPED with the reason.
BLENDER_VENVS = {"4.2": ".venv-blender42", "5.2": ".venv-blender52"}  # oldest supported LTS, newest


def _configured_labels():
    env = os.environ.get("LACORE_BLENDER_PYTHONS", "").strip()
    labels = [item.split("=", 1)[0].strip() for item in env.split(":") if item.strip()] if env else []
    return tuple(labels) or tuple(BLENDER_VENVS)


# Blender version labels the add-on checks run in (more by hand: LACORE_BLENDER_PYTHONS="4.5=...:...").
BLENDERS = _configured_labels()


def blender_python_version(label: str) -> tuple:
    """The Python a Blender version embeds: 3.11 for 4.2 .. 5.0, 3.13 for 5.1 and later."""
    return (3, 11) if tuple(int(x) for x in label.split(".")[:2]) < (5, 1) else (3, 13)


def blender_pythons() -> dict:
    """``{Blender version label: interpreter path}`` of the configured bpy venvs (existing or not)."""
    env = os.environ.get("LACORE_BLENDER_PYTHONS", "").strip()
    if env:
        pairs = (item.split("=", 1) for item in env.split(":") if item.strip())
        return {label.strip(): path.strip() for label, path in pairs}
    return {label: str(REPO / venv / "bin" / "python") for label, venv in BLENDER_VENVS.items()}


def blender_python(label: str) -> str:
    """The interpreter of Blender ``label``; skips (fails under LACORE_REQUIRE_BLENDERS=1) if missing."""
    path = blender_pythons().get(label)
    problem = None
    if path is None:
        problem = f"Blender {label} is not configured in LACORE_BLENDER_PYTHONS"
    elif not os.path.isfile(path):
        problem = f"no bpy venv for Blender {label}: {path} is missing (`make venv-blender` creates it)"
    if problem:
        if os.environ.get("LACORE_REQUIRE_BLENDERS") == "1":
            pytest.fail(problem, pytrace=False)
        pytest.skip(problem)
    return path


class ExtensionZip(str):
    """Path of the extension zip, carrying the Blender (``label``, ``python``) it is to be tested in.

    ``run_blender_check(script, zip_path, work)`` runs the check in that Blender's interpreter, so every
    test using the ``extension_zip`` fixture runs once per tested Blender.
    """

    def __new__(cls, path, label, python):
        obj = super().__new__(cls, path)
        obj.label, obj.python = label, python
        return obj


def build_extension_zip(out_dir, python=None) -> str:
    """Build the extension zip for the current platform into ``out_dir``; returns its path.

    ``python`` must have bpy (Blender's blender_ext.py builds the zip); default: the newest Blender's.
    """
    import subprocess

    if python is None:
        configured = blender_pythons()
        newest = sorted(configured, key=lambda label: tuple(int(x) for x in label.split(".")[:2]), reverse=True)
        python = next((p for label in newest if os.path.isfile(p := configured[label])), sys.executable)
    proc = subprocess.run([python, str(REPO / "scripts" / "build_extension.py"), "--platform", "current",
                           "--output-dir", str(out_dir)], capture_output=True, text=True, cwd=REPO, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    zip_path = proc.stdout.strip().splitlines()[-1]
    assert zip_path.endswith(".zip") and os.path.isfile(zip_path), proc.stdout
    return zip_path


@pytest.fixture(scope="session")
def _extension_zip_file(tmp_path_factory) -> str:
    """The extension zip for this platform (wheels for Python 3.11 and 3.13), built once per session."""
    return build_extension_zip(tmp_path_factory.mktemp("ext"))


@pytest.fixture(scope="session", params=BLENDERS, ids=[f"blender{b}" for b in BLENDERS])
def extension_zip(request) -> ExtensionZip:
    """The SAME extension zip, once per tested Blender (parametrizes every test that uses it)."""
    python = blender_python(request.param)
    return ExtensionZip(request.getfixturevalue("_extension_zip_file"), request.param, python)


def run_blender_check(script, zip_path, work: Path, timeout=600, env=None) -> dict:
    """Run a tests/blender/check_*.py script (installs ``zip_path`` into a throw-away
    BLENDER_USER_RESOURCES under ``work``) in a subprocess; returns its JSON result.

    The subprocess is the bpy interpreter of the Blender ``zip_path`` (an :class:`ExtensionZip`) is for; ``env``:
    more environment variables for it.
    """
    import json
    import subprocess

    python = getattr(zip_path, "python", None) or blender_python(BLENDERS[-1])  # a plain path: the newest
    env = dict(os.environ, **(env or {}), BLENDER_USER_RESOURCES=str(work / "user_resources"))
    env.pop("PYTHONPATH", None)  # the bpy venv alone: the extension's bundled wheels must be the ones used
    result = work / "result.json"
    proc = subprocess.run([python, str(script), "--zip", str(zip_path), "--workdir", str(work / "files"),
                           "--result", str(result)], capture_output=True, text=True, env=env, cwd=work,
                          timeout=timeout)
    details = f"\n--- stdout (tail) ---\n{proc.stdout[-4000:]}\n--- stderr (tail) ---\n{proc.stderr[-6000:]}"
    assert result.exists(), f"the Blender checks wrote no result (exit code {proc.returncode}){details}"
    data = json.loads(result.read_text())
    assert proc.returncode == 0 and data["ok"], data.get("error", "") + details
    label = getattr(zip_path, "label", None)
    if label is not None:  # the check really ran in the Blender it was meant for
        version = data.get("blender", "")  # e.g. "4.2.23 LTS" for label 4.2 (or 4.2.23)
        assert version == label or version.startswith((label + ".", label + " ")), (label, version)
    return data



@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector):
    """Under `make test` (LACORE_REQUIRE_BLENDERS=1), a Blender test module skipped at import (e.g. by
    ``pytest.importorskip("bpy")``: bpy is NOT in the pytest venv) fails instead of passing silently."""
    report = yield
    if (os.environ.get("LACORE_REQUIRE_BLENDERS") == "1" and report.skipped
            and Path(str(collector.path)).name.startswith("test_blender_")):
        report.outcome = "failed"
        report.longrepr = (f"{report.nodeid} was skipped at import ({report.longrepr}): the Blender checks run in "
                           "bpy venvs through run_blender_check / the extension_zip fixture, so do not import or "
                           "importorskip bpy in the test module")
    return report


def pytest_report_header(config):
    """Name the compute kernels chosen by the environment (scripts/other_kernels.py) in the run's header."""
    chosen = [f"{k}={os.environ[k]}" for k in ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE") if k in os.environ]
    return f"kernels: {' '.join(chosen)}" if chosen else None
