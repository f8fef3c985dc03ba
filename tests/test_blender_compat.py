"""addon/compat.py (F-curves of an ID across Blender 4.2 .. 5.2) in the installed extension, once per
tested Blender (subprocess: tests/blender/check_compat.py)."""

import pytest
from conftest import REPO, run_blender_check

CHECK_SCRIPT = REPO / "tests" / "blender" / "check_compat.py"


@pytest.fixture(scope="module")
def run(extension_zip, tmp_path_factory):
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender_compat"))


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
