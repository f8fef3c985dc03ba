"""addon/compat.py (F-curves of an ID across Blender 4.2 .. 5.2) in the installed extension, and the .blend files
of blend_samples/ and `make demo` opening, once per tested Blender (subprocess: tests/blender/check_compat.py)."""

import os
import re
import shutil
import subprocess
import sys
import sysconfig

import pytest
from conftest import REPO, blender_python, blender_python_version, run_blender_check

CHECK_SCRIPT = REPO / "tests" / "blender" / "check_compat.py"
OLDEST = "4.2"  # blender_manifest.toml's blender_version_min: `make demo` and `make samples` save with it
# the demo's steps that save .blend files (scripts/demo.py)
DEMO_BLEND_STEPS = ("blender_encode", "blender_interpolate", "blender_mocap_fit", "blender_live_mix")


@pytest.fixture(scope="module")
def demo_output(tmp_path_factory):
    """The output of `make demo`'s steps that save .blend files, run as the Makefile runs them: in the oldest
    supported Blender's bpy, finding SciPy & co. in this interpreter's site-packages (the same Python)."""
    python = blender_python(OLDEST)
    if sys.version_info[:2] != blender_python_version(OLDEST):
        problem = (f"the demo's Blender {OLDEST} steps need this interpreter's packages: Python "
                   f"{'.'.join(map(str, blender_python_version(OLDEST)))} (make test's), not {sys.version.split()[0]}")
        if os.environ.get("LACORE_REQUIRE_BLENDERS") == "1":
            pytest.fail(problem, pytrace=False)
        pytest.skip(problem)
    out = tmp_path_factory.mktemp("demo_output")
    env = dict(os.environ, LACORE_DEMO_BLENDER_PYTHON=python,
               LACORE_DEMO_BLENDER_PYTHONPATH=sysconfig.get_paths()["purelib"])
    only = [arg for step in DEMO_BLEND_STEPS for arg in ("--only", step)]
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "demo.py"), "--output", str(out), *only],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def run(extension_zip, demo_output, tmp_path_factory):
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender_compat"),
                             env={"LACORE_DEMO_OUTPUT": str(demo_output)})


def test_api_path_per_version(run, extension_zip):
    res = run["cases"]["install_and_enable"]
    assert res["slotted"] == (tuple(res["version"]) >= (4, 4, 0))
    if extension_zip.label == "4.2":
        assert not res["slotted"]  # Action.fcurves
    if extension_zip.label == "5.2":
        assert res["slotted"]  # channelbags (Action.fcurves is gone since 5.0)


def test_object_fcurves_created_and_evaluated(run):
    res = run["cases"]["object_fcurves"]
    assert res["values_at_6"] == pytest.approx([5.0, 10.0, 15.0], abs=1e-6)
    assert res["location_at_6"] == pytest.approx([5.0, 10.0, 15.0], abs=1e-5)


def test_shape_key_fcurves_survive_reload(run):
    assert run["cases"]["shape_key_fcurves_survive_reload"]["value_at_3"] == pytest.approx(0.5, abs=1e-6)


def test_sample_files_open(run):
    """The sample .blend files open in every supported Blender (saved by the oldest, 4.2) and encode."""
    opened = run["cases"]["sample_files_open"]["opened"]
    assert set(opened) == {"bar_bend.blend", "bar_twist.blend", "finger.blend", "plate4SD_rolled.blend",
                           "plate_rolled.blend", "shape_keys.blend"}
    assert opened["shape_keys.blend"] == ["Bar", "Cube", "Grid"] and opened["finger.blend"] == ["Finger"]


def test_demo_files_open(run):
    """Every .blend file `make demo` writes opens in every supported Blender (saved by the oldest, 4.2), with the
    encodings, in-betweens, baked motion, the Mesh Cache modifier playing its PC2 and the live mixer mixing."""
    res = run["cases"]["demo_files_open"]
    assert {name: version[:2] for name, version in res["saved_in"].items()} == {
        "demo_scene.blend": [4, 2], "bar_inbetweens.blend": [4, 2], "human_mocap_fit.blend": [4, 2],
        "human_live_mix.blend": [4, 2]}
    assert res["encoded"] == {"Cube": ["Basis", "Rigid", "Scaled"], "Bar": ["Basis", "Bend", "Rigid", "Twist"],
                              "Grid": ["Basis", "Roll", "Wave"]}
    assert res["inbetweens"] == ["LA Basis>Bend180 0.250", "LA Basis>Bend180 0.500", "LA Basis>Bend180 0.750"]
    assert res["baked_keys"] == 45
    assert res["modifier"] == "MESH_CACHE" and res["cache_frames"] == 20
    assert res["cache_moved"] > 0.5  # decimetres: the body moves between the first and the middle frame
    assert res["played_vs_cache"] < 1e-5
    # the live mixer saved by 4.2 mixes the keyframed sliders: the arm at 0.5 differs from the linear mix by
    # decimetres (the linear mix shortens it by 0.9 dm), and unmuting the mix key brings the mix back exactly
    live = res["live_mix"]
    assert live["status"] == "" and live["arm_value"] == 0.5, live
    assert live["mixed_vs_linear"] > 0.5 and live["unmuted_again"] < 1e-5, live


def test_make_demo_saves_with_the_oldest_blender(tmp_path):
    """`make demo` creates the bpy 4.2 venv when it is missing and runs the steps that save .blend files in it
    (the panel pictures in 5.2): what :func:`demo_output` reproduces."""
    make = shutil.which("make")
    if make is None:
        pytest.skip("no make on the PATH")
    venvs = {name: tmp_path / name.lower() for name in ("VENV", "VENV_NP2", "VENV_BLENDER42", "VENV_BLENDER52")}
    proc = subprocess.run([make, "-n", "demo", *(f"{name}={path}" for name, path in venvs.items())], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    b42, b52 = venvs["VENV_BLENDER42"], venvs["VENV_BLENDER52"]
    assert re.search(rf'^{re.escape(str(b42))}/bin/python -m pip install "bpy=={re.escape(OLDEST)}\.', proc.stdout,
                     re.M), proc.stdout
    assert f"LACORE_DEMO_BLENDER_PYTHON={b42}/bin/python " in proc.stdout, proc.stdout
    assert f"LACORE_DEMO_PANEL_BLENDER_PYTHON={b52}/bin/python " in proc.stdout, proc.stdout
