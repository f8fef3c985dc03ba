"""The Blender extension end to end: build the zip, install it into a throw-away
Blender user directory, enable it and run the operator (in a subprocess, see
tests/blender/check_extension.py), then use the bundled wheels without bpy.  Every test runs once per tested Blender
(bpy 4.2.x / Python 3.11 and bpy 5.2.x / Python 3.13, see tests/conftest.py), on the same zip.

The zip is built for the current platform only; its wheels are downloaded once
into ./wheels (cached; later runs do not download).
"""

import json
import re
import subprocess
import tomllib

import pytest
from conftest import REPO, blender_python_version, run_blender_check, shared_mesh

CHECK_SCRIPT = REPO / "tests" / "blender" / "check_extension.py"


@pytest.fixture(scope="module")
def blender_run(extension_zip, tmp_path_factory):
    """Run all Blender checks once in a subprocess; returns its JSON result."""
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender"))


def test_zip_contents(extension_zip):
    import zipfile

    names = set(zipfile.ZipFile(extension_zip).namelist())
    assert {"blender_manifest.toml", "__init__.py", "LICENSE", "addon/__init__.py", "addon/operators.py",
            "addon/panels.py", "addon/mesh_access.py", "lacore/__init__.py", "lacore/geometry/topology.py",
            "lacore/markers/io.py"} <= names
    assert not any(n.startswith(("tests/", "scripts/", ".venv/", ".ci/", "benchmarks/")) for n in names), names
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    assert any(n.startswith("wheels/scipy-") for n in names) and any(n.startswith("wheels/trimesh-") for n in names)
    assert any(n.startswith("wheels/cvxopt-") for n in names) and any(n.startswith("wheels/pymetis-") for n in names)


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
    # the mesh named, what to do, and where Blender shows the faces
    assert re.search(r"Mesh '.*' cannot be encoded: non-manifold edges .*keep at most two faces on each edge .*"
                     r"\(in Edit Mode, Select > Select All by Trait > Non Manifold selects them\)",
                     messages["non_manifold"]), messages["non_manifold"]


def test_blender_time_is_modest(blender_run):
    assert blender_run["seconds"] < 120, blender_run["cases"]


def test_zip_wheel_tags(extension_zip):
    """The built zip holds exactly its manifest's wheels, one usable per distribution for Python 3.11 and 3.13."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("check_wheel_tags", REPO / "scripts" / "check_wheel_tags.py")
    tags = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tags)
    assert tags.check_zip(extension_zip) == []


def test_installed_for_this_blender(blender_run, extension_zip):
    """Blender installed the wheels of ITS Python from the same zip: cp311 on 4.2 (NumPy 1.26, SciPy 1.16.3),
    cp313 on 5.2 (NumPy 2.5, SciPy 1.16.2); CHOLMOD (cvxopt) is the sparse Cholesky and METIS (pymetis) orders
    it on Linux for both."""
    install = blender_run["cases"]["install_and_enable"]
    major, minor = blender_python_version(extension_zip.label)
    assert install["python"] == f"python{major}.{minor}"
    assert install["numpy"].startswith("1.26." if minor == 11 else "2.")  # what Blender ships (5.2: 2.5)
    scipy = "1.16.3" if minor == 11 else "1.16.2"
    assert sorted(install["bundled"]) == ["c3d-0.6.0.dist-info", "cvxopt-1.3.2.dist-info",
                                          "pymetis-2025.2.2.dist-info", f"scipy-{scipy}.dist-info",
                                          "trimesh-5.2.0.dist-info", "typing_extensions-4.16.0.dist-info"]
    assert install["scipy"] == scipy
    # Early 4.2.x (4.2.0) ignore Python tags and install the cp313 cvxopt and pymetis, which 3.11 cannot
    # import: SciPy's factorization and lacore's geometric ordering
    assert install["sparse_cholesky"] == ("cholmod" if install["installer_matches_python_tags"] else "scipy")
    assert install["metis"] == install["installer_matches_python_tags"]
    if extension_zip.label in ("4.2", "5.2"):  # what make test installs: bpy 4.2.23 and 5.2.3
        assert install["installer_matches_python_tags"]


def test_bundled_wheels_run_lacore(blender_run, extension_zip, tmp_path):
    """The wheels Blender installed (pinned scipy, trimesh) run lacore in that Blender's Python, without bpy."""
    install = blender_run["cases"]["install_and_enable"]
    cp = "cp" + install["python"][len("python"):].replace(".", "")
    with open(REPO / "blender_manifest.toml", "rb") as fh:
        pinned = next(w for w in tomllib.load(fh)["wheels"] if "scipy-" in w and f"-{cp}-" in w).split("-")[1]
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
    proc = subprocess.run([extension_zip.python, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    assert info["rc"] == 0 and not info["bpy_loaded"]
    assert info["scipy"] == pinned
    assert info["scipy_file"].startswith(install["bundled_site_packages"])
    assert info["trimesh_file"].startswith(install["bundled_site_packages"])
    assert out.exists()
