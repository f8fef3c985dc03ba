"""The Interpolate and Bake Keyframes operators of the INSTALLED extension, end to end in Blender
(subprocess: tests/blender/check_interpolate.py), with real numbers from real computations:

* a quad box bar (1058 vertices) bent 180 degrees by Blender's Simple Deform (applied as a shape
  key): the lengths-and-angles in-between at t = 0.5 matches Blender's own 90-degree bend to
  0.04 % of the bounding-box diagonal (RMS after a rigid fit), where the linear shape-key blend
  is 2 % off;
* end points reproduce the keys, extrapolation is finite, redo replaces, errors change nothing;
* the shared finger pair: the in-between keeps the interpolated edge lengths;
* bake: one key at 1 per frame (CONSTANT F-curves through the Key's channelbag), re-bake
  replaces only its own keys and curves, save/reload keeps everything.
"""

import pytest
from conftest import REPO, run_blender_check

CHECK_SCRIPT = REPO / "tests" / "blender" / "check_interpolate.py"


@pytest.fixture(scope="module")
def run(extension_zip, tmp_path_factory):
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender_interpolate"))


def test_operators_registered(run):
    assert run["cases"]["install_and_enable"]["operators"] == [
        "LENGTHS_ANGLES_OT_bake_keyframes", "LENGTHS_ANGLES_OT_clear_bake", "LENGTHS_ANGLES_OT_interpolate"]


def test_interpolate_keys_and_end_points(run):
    res = run["cases"]["interpolate_bar"]
    assert res["vertices"] == 1058
    assert res["keys"] == ["Basis", "Bend180", "SimpleDeform90", "LA Basis>Bend180 0.000", "LA Basis>Bend180 0.250",
                           "LA Basis>Bend180 0.500", "LA Basis>Bend180 1.000", "LA Basis>Bend180 1.500",
                           "LA Basis>Bend180 0.750", "LA Bend180>Basis 0.500"]
    assert res["end_point_max_abs_error"] < 1e-5  # float32 storage; placed on the keys themselves
    assert res["end_point_rigid_max_abs_error"] < 1e-5


def test_bar_blend_quality_vs_simple_deform_90(run):
    """The README figure's numbers: lengths and angles at 0.5 vs Blender's 90-degree bend.

    Measured (2026-11-23): RMS distance per diagonal 3.99e-4 (README: 0.040 %), Gauss-Newton 3.98e-4,
    Preview 3.20e-4; edge lengths vs the 90-degree bend 3.19e-5 (README: 0.003 %), Preview 1.49e-3; the
    linear blend 2.00 % RMS and 29.3 % edge error; extrapolation to 1.5 vs the 270-degree bend 2.46e-3.
    Bounds: 2-3x these values."""
    res = run["cases"]["interpolate_bar"]
    la, lin, ref = res["lengths_angles"], res["linear"], res["simple_deform_90"]
    assert la["rms_error_per_diagonal"] < 1.0e-3
    assert res["gauss_newton"]["rms_error_per_diagonal"] < 1.0e-3
    assert res["preview"]["rms_error_per_diagonal"] < 8e-4  # least-squares relaxation alone
    assert res["preview"]["max_edge_error_vs_reference"] < 4e-3
    assert 0.019 < lin["rms_error_per_diagonal"] < 0.021
    # edge lengths: the in-between has (almost) the reference's, the linear blend shrinks edges a lot
    assert la["max_edge_error_vs_reference"] < 1e-4
    assert 0.28 < lin["max_edge_error_vs_reference"] < 0.30
    assert lin["max_edge_change_vs_straight"] > 2 * ref["max_edge_change_vs_straight"]
    # extrapolation to t = 1.5 is a 270-degree bend (lengths and angles continue linearly)
    assert res["extrapolated_1_5_vs_simple_deform_270"]["rms_error_per_diagonal"] < 6e-3
    # placement: rigidly fitted to the linear blend, so the centroids coincide
    assert res["centroid_shift"] < 1e-6 * res["diagonal"]


def test_path_method(run):
    """Method Path on the 1058-vertex bar (Basis to a 180-degree bend): within 0.3 % of Gauss-Newton with an
    estimate per in-between (measured RMS 1e-6 of the diagonal, estimates 0.05-0.15 %); the default from
    PATH_MIN_VERTICES vertices, not with Spline."""
    res = run["cases"]["path_method"]
    assert max(res["rms_to_gauss_newton_per_diagonal"]) < 1e-4
    assert all(0 < e <= 3e-3 for e in res["job_indicator"]) and not res["job_failures"]
    assert res["job_summary"].startswith("estimated error at most")
    assert (res["small_default"], res["big_default"], res["big_spline_default"]) == ("FAST", "PATH", "FAST")
    assert res["bake_keys"] == 6                          # frames 2-4 and 6-8
    assert "Spline" in res["spline_message"]
    # a modal run computes in a worker process: the same in-betweens
    assert res["worker_processes"] == 2 and res["worker_difference_per_diagonal"] < 1e-9


def test_redo_replaces_keys(run):
    res = run["cases"]["redo_replaces"]
    assert res["keys"].count("LA Basis>Bend180 0.500") == 1
    assert res["max_abs_difference_of_rerun"] < 1e-5


def test_ngons_and_edit_mode(run):
    res = run["cases"]["quads_ngons_and_edit_mode"]
    assert abs(res["cube_edge_at_0.5"] - 2.5) < 1e-4  # lengths interpolate linearly (edge 2 -> 3)
    # hexagonal prism height 1 -> 3: about 2 (the target is not admissible: the side quads' diagonals do not
    # average to those of a prism of height 2; measured 2.2e-4 off with Fast, 4.8e-5 with the previous Fast)
    assert abs(res["prism_height_at_0.5"] - 2.0) < 6e-4


def test_errors_leave_object_unchanged(run):
    messages = run["cases"]["errors_change_nothing"]["messages"]
    assert set(messages) == {"no_active_object", "missing_key", "same_key", "unparsable_factors", "infinite_factor",
                             "bake_count_mismatch", "bake_not_increasing", "bake_unknown_key", "bake_bad_frame",
                             "bake_one_key", "bake_foreign_animation", "no_shape_keys", "not_a_mesh",
                             "non_manifold", "bake_non_manifold", "bake_no_active_object", "bake_driven_key",
                             "vertex_group_key", "bake_vertex_group_key", "relative_key", "bake_absolute_keys"}
    assert 'enum "Nope" not found' in messages["missing_key"]  # the key picker offers only the mesh's keys



def test_library_meshes_refused(run):
    """A mesh linked from a library, or a library override (the bar linked into a shot as a collection made a
    library override): without the check, In-betweens and Bake FINISHED there, added keys equal to the basis (the bulk
    write dropped) and the keys were gone when the shot was saved and opened again (bpy 4.2 and 5.2).  Now they,
    Clear Bake and Remove Data (which FINISHED there, reporting the bake, encoding and model removed from a mesh
    whose data the shot takes from the library) are refused in one line naming the mesh, the library and what to
    do, and the keys stay as they were."""
    res = run["cases"]["library_meshes"]
    assert res["linked_mesh"] == [True, False] and res["override_mesh"] == [False, True]
    for kind in ("linked", "override"):
        assert res[f"{kind}_keys"] == ["Basis", "Bend180", "SimpleDeform90", "LA bake 002"]  # baked in the library
        for what, verb in (("interpolate", "make the in-betweens"), ("bake", "bake"), ("clear_bake", "clear the bake"),
                           ("remove_data", "remove the Lengths & Angles data")):
            msg = res[f"{kind}_{what}"]
            lead = "is linked from '" if kind == "linked" else "is a library override of '"
            assert msg.startswith(f"mesh 'Bar' {lead}") and msg.count("bar_library.blend'") == 1, msg
            assert f"{verb} in that file" in msg and "Make Local > Selected Objects and Data" in msg, msg
            assert "\n" not in msg, msg


def test_bake_one_key_per_frame(run):
    res = run["cases"]["bake_and_rebake"]
    assert res["baked_keys"] == [f"LA bake {f:03d}" for f in (2, 3, 4, 5, 7, 8, 9, 10, 11)]
    hot = res["hot_per_frame"]
    assert hot["1"] == ["Basis"] and hot["6"] == ["Bend180"] and hot["12"] == ["Twist180"]
    assert hot["4"] == ["LA bake 004"] and hot["-1"] == ["Basis"] and hot["14"] == ["Twist180"]
    assert all(len(v) == 1 for v in hot.values())
    # the baked bend follows Blender's own Simple Deform at the same angle (measured: at most 4.0e-4 RMS per
    # diagonal; the twist keeps its edge lengths to 1.26e-2)
    assert max(res["bend_rms_per_diagonal"].values()) < 1e-3
    assert res["twist_max_relative_length_error"] < 0.03


def test_rebake_replaces_and_survives_reload(run):
    res = run["cases"]["bake_and_rebake"]
    assert res["rebaked_keys"] == [f"LA bake {f:03d}" for f in (2, 3, 5, 6, 7)]
    assert res["smooth_vs_linear_max_abs"] > 1e-3


def test_finger_pair_keeps_lengths(run):
    """Shared finger0 -> finger1 (2046 vertices): the in-between has the interpolated edge lengths
    (measured RMS 0.035 %, max 0.58 %), the linear blend misses them by about 10 % RMS (up to ~48 %)."""
    res = run["cases"]["finger_pair"]
    la, lin = res["lengths_angles"], res["linear"]
    assert res["vertices"] == 2046
    assert la["rms_relative_length_error"] < 1e-3 and la["max_relative_length_error"] < 0.015
    assert 0.09 < lin["rms_relative_length_error"] < 0.11
    assert lin["rms_relative_length_error"] > 10 * la["rms_relative_length_error"]


def test_panel_buttons(run):
    ops = run["cases"]["panel_buttons"]["operators"]
    assert ops == ["lengths_angles.interpolate", "lengths_angles.bake_keyframes", "lengths_angles.encode",
                   "lengths_angles.remove_data"]


def test_failed_checks_are_written_with_a_warning(run):
    """success=False in the add-on: the in-between is written and a WARNING names the failure (issue 12)."""
    res = run["cases"]["failed_checks_warn"]
    assert len(res["preview_failures"]) == 1 and res["preview_failures"][0].startswith("t = 1.25: folded")
    assert res["fast_failures"] == []  # Fast continues from t = 0.5 and reaches an unfolded t = 1.25
    assert res["warning"].startswith("1 in-between failed the reconstruction checks and was written anyway")
    assert res["status"] == ["FINISHED"] and res["written"]


def test_processes_side_by_side(run):
    """Two processes (a worker process importing the installed lacore under bl_ext) give the frames of one;
    cancelling the modal run after one tick kills the worker process.

    Measured (2026-11-25, 1058-vertex bar, 6 in-betweens, bpy 4.2.23 and 5.2.3): Gauss-Newton 3.7e-11 of the
    diagonal apart (both converged), Fast 1.4e-8 (other warm starts in the second chain), the operator's keys
    2.8e-8 (float32)."""
    res = run["cases"]["processes_side_by_side"]
    assert res["processes"] == {"GAUSS_NEWTON 1": 1, "GAUSS_NEWTON 2": 2, "FAST 1": 1, "FAST 2": 2}
    assert res["max_difference_per_diagonal"]["GAUSS_NEWTON"] < 2e-10
    assert res["max_difference_per_diagonal"]["FAST"] < 1e-7
    assert res["operator_keys"] == 6 and res["operator_max_difference_per_diagonal"] < 1e-6
    assert res["auto_small_mesh"] == 1 and res["auto_large_mesh"] >= 1
    assert res["running_after_tick"] == 1 and res["running_after_cancel"] == 0
    # no worker (it cannot start, or it dies after the first frame): this process computes its frames, says so
    for case in ("worker_cannot_start", "worker_died"):
        fallback = res[case]
        assert fallback["processes"] == 1 and fallback["difference"] < 2e-10, (case, fallback)
        assert len(fallback["notes"]) == 1 and "computed in this process instead" in fallback["notes"][0]
    # the modal operators' mode: both chains in worker processes, none in Blender's; cancel kills them
    every = res["all_in_workers"]
    assert every["processes"] == 2 and every["local_frames"] == 0 and every["difference"] < 2e-10
    assert every["cancel"]["running"] == 0
