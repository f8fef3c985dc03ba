"""How the operators of the INSTALLED extension name bad input and refuse what Blender would not keep, end to end in
Blender (subprocess: tests/blender/check_operator_inputs.py):

* faces of no area on a quad grid: every operator checking for them names the mesh, the shape key and the faces as
  Blender numbers them (before: Encode, In-betweens, Bake and Live Mixing named fan-triangle numbers);
* a character linked into a shot (a linked object, a library override with its mesh linked or an override too):
  Blender drops custom properties set in the shot when it is opened again, so Encode, Pin Marker, Remove Pin, Bind
  Markers and Calibrate & Fit are refused in one line naming the datablock, the library and Make Local (before: they
  finished and kept nothing); made local, their records are kept;
* Import Markers with Start Frame -5: refused with Set Frame Range (before: the scene's range silently started at
  0), keyed from frame -5 without it;
* typed key lists naming keys with commas (quoted, or matched against the mesh's keys).
"""

import pytest
from conftest import REPO, run_blender_check

CHECK_SCRIPT = REPO / "tests" / "blender" / "check_operator_inputs.py"
MAKE_LOCAL = "(Object > Relations > Make Local > Selected Objects and Data)"


@pytest.fixture(scope="module")
def run(extension_zip, tmp_path_factory):
    return run_blender_check(CHECK_SCRIPT, extension_zip, tmp_path_factory.mktemp("blender_operator_inputs"))


@pytest.mark.parametrize("operator", ["encode", "inbetweens", "bake", "build_model", "live_mix"])
def test_degenerate_faces_named_by_blender_face(run, operator):
    """Edge (12, 13) of the 4 x 4 quad grid collapsed in the key 'Flat': quads 6 and 10 (fan triangles 13 and 20)."""
    res = run["cases"]["degenerate_faces"]
    assert res["polygons"] == [6, 10] and res["triangles"] == [13, 20], res
    got = res[operator]
    assert got["result"] == ["ERROR"] and got["one_line"] and got["unchanged"], got
    assert got["message"].startswith("mesh 'Grid': shape key 'Flat' has faces of no area (or needle-thin): "
                                     "faces 6, 10 (Blender face indices); move their vertices apart in that key"), got


@pytest.mark.parametrize("kind", ["linked", "override", "override_mesh"])
def test_blender_drops_properties_set_in_a_shot(run, kind):
    """The premise of the refusals: a custom property set in the shot on the object or the mesh, and a pin of the
    library changed in the shot, are gone when the shot is opened again."""
    res = run["cases"]["library_data"][kind]
    assert res["datablocks"] == {"linked": [True, False, True, False], "override": [False, True, True, False],
                                 "override_mesh": [False, True, False, True]}[kind]
    # the add-on's object settings, Placement and the mode sliders, are kept on an override (before: reset to
    # Automatic and 0 on reopening); a linked object cannot be edited in the shot
    settings = None if kind == "linked" else ["PLACED", 1.5]
    assert res["kept_after_reopen"] == {"object_prop": False, "mesh_prop": False, "pin_changed": False,
                                        "settings": settings}


@pytest.mark.parametrize("kind", ["linked", "override", "override_mesh"])
@pytest.mark.parametrize("operator, what, datablock", [
    ("encode", "encode the shape keys", "mesh"), ("pin_marker", "pin the markers", "object"),
    ("remove_pin", "remove the pin", "object"), ("bind_markers", "bind the markers", "object"),
    ("calibrate_fit", "calibrate and fit", "object")])
def test_records_that_would_be_lost_are_refused(run, kind, operator, what, datablock):
    res = run["cases"]["library_data"][kind][operator]
    assert res["result"] == ["ERROR"] and res["one_line"] and res["unchanged"], res
    msg = res["message"]
    linked = kind == "linked" or (kind == "override" and datablock == "mesh")
    how = "is linked from '" if linked else "is a library override of '"
    assert msg.startswith(f"{datablock} 'Body' {how}") and "body_library.blend'" in msg, msg
    assert f"so what the add-on stores on it here would be lost: {what} in that file, or make the {datablock} " \
           f"local first {MAKE_LOCAL}" in msg, msg


def test_made_local_records_are_kept(run):
    res = run["cases"]["library_data"]["made_local"]
    assert res["datablocks"] == [False, False, False, False]
    assert res["encode"]["result"] == ["FINISHED"] and res["pin_marker"]["result"] == ["FINISHED"]
    assert res["kept_after_reopen"] == {"encoding": True, "pins": {"LFHD": 0, "RFHD": 1}}


def test_fit_on_an_override_says_its_quality_is_not_kept(run):
    """Fit to Markers on a library override: the point cache is kept; the report (a WARNING now, an INFO line
    before) says that the fit's quality, custom properties of the object, is not; on a linked object refused."""
    res = run["cases"]["fit_on_override"]
    assert res["override_result"] == ["FINISHED"], res
    (kind, text), = res["override_reports"]
    assert kind == "WARNING" and text.startswith("fitted 5 frames to //Body_take.pc2"), res
    assert ("the fit's quality shown in the panel, and the 'LA marker RMS' property its curve keys, are not kept when "
            "the shot is opened again: object 'Body' is a library override of '") in text, text
    assert res["quality_before_reopen"] and res["reopened"] == {"modifier": True, "quality": False,
                                                                "rms_property": False}, res
    linked = res["linked"]
    assert linked["result"] == ["ERROR"] and linked["one_line"] and linked["unchanged"], linked
    assert linked["message"].startswith("object 'Body' is linked from '") and "fit to the markers in that file" in \
        linked["message"], linked


def test_negative_start_frame(run):
    res = run["cases"]["negative_start_frame"]
    assert res["set_range"].startswith("Start Frame -5 is before frame 0, and a scene's frame range cannot start "
                                       "before 0: turn off Set Frame Range to key the take from frame -5"), res
    assert res["set_range_unchanged"], res
    assert res["no_range"] == ["FINISHED"] and res["take_frame_start"] == -5.0 and res["first_key"] == -5.0, res
    assert res["scene_range"] == [3, 40] and res["read_at_minus_5"], res
    assert res["zero_with_range"] == ["FINISHED"] and res["zero_scene_start"] == 0, res


def test_key_names_with_commas(run):
    res = run["cases"]["comma_key_names"]
    assert res["keys"][-2:] == ["Arm, left", "Arm"]
    for case, keys in (("quoted", ["Basis", "Arm, left"]), ("plain", ["Arm, left", "Basis"]),
                       ("two", ["Arm", "Basis"])):
        assert res[f"bake_{case}"]["result"] == ["FINISHED"], res[f"bake_{case}"]
        assert res[f"bake_{case}_keys"] == keys, (case, res[f"bake_{case}_keys"])
    assert res["bake_unclosed"]["result"] == ["ERROR"] and res["bake_unclosed"]["unchanged"]
    assert res["bake_unclosed"]["message"].startswith("Keys: a quote is not closed in"), res["bake_unclosed"]
    assert res["bake_missing"]["message"].startswith("Mesh 'Bar': no shape key 'Leg', 'right'"), res["bake_missing"]
    assert res["model"]["result"] == ["FINISHED"] and res["model_keys"] == ["Bend", "Arm, left", "Twist"], res
