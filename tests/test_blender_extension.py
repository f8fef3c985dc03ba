"""The Blender extension end to end: build the zip, install it into a throw-away
Blender user directory, enable it and run the operator (in a subprocess, see
tests/blender/check_extension.py), then use the bundled wheels without bpy.

The zip is built for the current platform only; its wheels are downloaded once
into ./wheels (cached; later runs do not download).
"""

import json
import subprocess
import sys
import tomllib

import pytest
from conftest import REPO, run_blender_check, shared_mesh

pytest.importorskip("bpy", reason="the bpy module (pip install bpy==5.0.1) is needed for the add-on tests")

CHECK_SCRIPT = REPO / "tests" / "blender" / "check_extension.py"


@pytest.fixture(scope="module")
def blender_run(extension_zip, tmp_path_factory):
    """Run all Blender checks once in a subprocess; returns its JSON result."""
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender"))


def test_zip_contents(extension_zip):
    import zipfile

    names = set(zipfile.ZipFile(extension_zip).namelist())
    assert {"blender_manifest.toml", "__init__.py", "LICENSE", "addon/__init__.py", "addon/operators.py",
            "addon/panels.py", "addon/mesh_access.py", "lacore/__init__.py", "lacore/topology.py"} <= names
    assert not any(n.startswith(("tests/", "scripts/", ".venv/", ".ci/", "benchmarks/")) for n in names), names
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    assert any(n.startswith("wheels/scipy-") for n in names) and any(n.startswith("wheels/trimesh-") for n in names)
    assert any(n.startswith("wheels/cvxopt-") for n in names)


def test_install_and_enable(blender_run):
    assert "install_and_enable" in blender_run["cases"]


def test_cube_lengths_and_angles(blender_run):
    lengths = blender_run["cases"]["cube_values"]["lengths_basis"]
    assert lengths == [2.0, round(2 * 2 ** 0.5, 9)]


def test_encoding_survives_save_and_reload(blender_run):
    assert blender_run["cases"]["bar_and_grid_save_reload"]["objects"] == ["Bar", "Cube", "Grid"]


def test_edit_mode_and_shape_key_io(blender_run):
    assert "edit_mode_and_key_io" in blender_run["cases"]


def test_panel(blender_run):
    assert "panel_draw" in blender_run["cases"]


def test_errors_leave_object_unchanged(blender_run):
    messages = blender_run["cases"]["errors_change_nothing"]["messages"]
    assert set(messages) == {"no_active_object", "not_a_mesh", "no_shape_keys", "non_manifold", "loose_edge",
                             "degenerate_key"}
    assert "non-manifold" in messages["non_manifold"]


def test_blender_time_is_modest(blender_run):
    assert blender_run["seconds"] < 120, blender_run["cases"]


def test_bundled_wheels_run_lacore(blender_run, tmp_path):
    """The wheels Blender installed (pinned scipy, trimesh) run lacore, with numpy 1.26 and without bpy."""
    install = blender_run["cases"]["install_and_enable"]
    with open(REPO / "blender_manifest.toml", "rb") as fh:
        pinned = next(w for w in tomllib.load(fh)["wheels"] if "scipy-" in w).split("-")[1]
    out = tmp_path / "z.npz"
    code = (
        "import sys, json\n"
        f"sys.path[:0] = [{install['bundled_site_packages']!r}, {install['extension_dir']!r}]\n"
        "import scipy, trimesh, numpy\n"
        "from lacore.cli import main\n"
        f"rc = main(['encode', {str(shared_mesh('finger/finger0.ply'))!r}, '-o', {str(out)!r}])\n"
        "print(json.dumps({'rc': rc, 'scipy': scipy.__version__, 'scipy_file': scipy.__file__,\n"
        "                  'trimesh_file': trimesh.__file__, 'numpy': numpy.__version__,\n"
        "                  'bpy_loaded': 'bpy' in sys.modules}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    assert info["rc"] == 0 and not info["bpy_loaded"]
    assert info["scipy"] == pinned
    assert info["scipy_file"].startswith(install["bundled_site_packages"])
    assert info["trimesh_file"].startswith(install["bundled_site_packages"])
    assert out.exists()
