"""`lacore interpolate`: output files in order, --json summary, keyframes, spline, errors (exit code 2)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, shared_mesh

from lacore.cli import SUBCOMMANDS, main
from lacore.cli.interpolate import frame_times, output_paths
from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.io.meshes import load_mesh
from lacore.geometry.topology import MeshTopology

PLATES = [shared_mesh(f"plate/{n}.ply") for n in ("plate121", "plate121_rolledA", "plate121_rolledB")]
FRAME_KEYS = {"file", "factor", "seconds", "energy", "iterations", "max_length_error", "max_angle_error"}


def run_main(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _z(path, topo=None):
    X, F = load_mesh(path)
    topo = topo or MeshTopology.from_faces(F, n_vertices=len(X))
    return lengths_and_angles(X, topo), topo


def test_registered():
    assert "interpolate" in SUBCOMMANDS
    assert callable(SUBCOMMANDS["interpolate"].run)


def test_helpers():
    assert output_paths("out/a", 3) == ["out/a_000.ply", "out/a_001.ply", "out/a_002.ply"]
    assert output_paths("a", 1001, "obj")[-1] == "a_1000.obj"
    assert output_paths("walk.ply", 1) == ["walk_000.ply"] and output_paths("w.OBJ", 1, "obj") == ["w_000.obj"]
    assert output_paths(".ply", 1) == [".ply_000.ply"] and output_paths("a.obj", 1) == ["a.obj_000.ply"]
    np.testing.assert_allclose(frame_times([0.0, 3.0, 10.0], 5), [0.0, 2.5, 5.0, 7.5, 10.0])
    with pytest.raises(ValueError, match="at least 1"):
        frame_times([0.0, 1.0], 0)


def test_factors_json_and_files(tmp_path, capsys):
    prefix = tmp_path / "inb"
    code, out, err = run_main(capsys, "interpolate", PLATES[1], PLATES[2], "--t", 0, 0.5, 1, -0.25, "-o", prefix,
                              "--json")
    assert code == 0, err
    s = json.loads(out)  # exactly one JSON object on stdout
    assert s["command"] == "interpolate" and s["mode"] == "factor"
    files = [o["file"] for o in s["outputs"]]
    assert files == [f"{prefix}_{i:03d}.ply" for i in range(4)]
    assert [o["factor"] for o in s["outputs"]] == [0.0, 0.5, 1.0, -0.25]
    for o in s["outputs"]:
        assert FRAME_KEYS <= set(o)
        assert o["seconds"] >= 0 and o["energy"] >= 0
    assert s["totals"]["outputs"] == 4 and s["totals"]["seconds"] > 0
    assert s["totals"]["iterations"] == sum(o["iterations"] for o in s["outputs"])
    # files are written in the order given: t = 0 and t = 1 reproduce the inputs
    zA, topo = _z(PLATES[1])
    zB, _ = _z(PLATES[2], topo)
    z0, _ = _z(files[0], topo)
    z1, _ = _z(files[2], topo)
    assert np.abs(z0 - zA).max() < 1e-8 and np.abs(z1 - zB).max() < 1e-8
    assert s["outputs"][0]["max_length_error"] < 1e-10
    # the in-between is a different shape, with a positive residual energy (not admissible)
    zm, _ = _z(files[1], topo)
    assert np.abs(zm - zA).max() > 0.1 and s["outputs"][1]["energy"] > 1e-6
    # all frames in the frame of the first mesh: its fixed triangle does not move
    XA, _ = load_mesh(PLATES[1])
    Xs = [load_mesh(f)[0] for f in files]
    still = np.flatnonzero(np.all([np.abs(X - XA).max(1) < 1e-9 for X in Xs], axis=0))
    assert still.size >= 1


def test_frames_with_keyframes_and_spline(tmp_path, capsys):
    lin, spl = tmp_path / "lin", tmp_path / "spl"
    code, out, err = run_main(capsys, "interpolate", *PLATES, "--frames", 5, "--keyframes", 0, 3, 10, "-o", lin,
                              "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["mode"] == "frame" and s["keyframes"] == [0.0, 3.0, 10.0]
    assert [o["frame"] for o in s["outputs"]] == [0.0, 2.5, 5.0, 7.5, 10.0]
    code, out, err = run_main(capsys, "interpolate", *PLATES, "--frames", 5, "--keyframes", 0, 3, 10,
                              "--smooth-spline", "-o", spl, "--json")
    assert code == 0, err
    assert json.loads(out)["smooth_spline"] is True
    z_first, topo = _z(PLATES[0])
    z_last, _ = _z(PLATES[2], topo)
    for prefix in (lin, spl):
        assert np.abs(_z(f"{prefix}_000.ply", topo)[0] - z_first).max() < 1e-8   # frame 0 = keyframe 0
        assert np.abs(_z(f"{prefix}_004.ply", topo)[0] - z_last).max() < 1e-8    # frame 10 = keyframe 10
    # between the keys the spline differs from the piecewise linear path
    d = np.abs(_z(f"{lin}_002.ply", topo)[0] - _z(f"{spl}_002.ply", topo)[0]).max()
    assert d > 1e-2


def test_text_output(tmp_path, capsys):
    code, out, err = run_main(capsys, "interpolate", PLATES[0], PLATES[1], "--t", 0.5, "-o", tmp_path / "x",
                              "--format", "obj")
    assert code == 0, err
    assert "x_000.obj" in out and (tmp_path / "x_000.obj").exists()


def test_output_extension_sets_the_format(tmp_path, capsys):
    """``-o walk.obj`` writes ``walk_000.obj`` ... (not ``walk.obj_000.ply``); ``--format`` still decides."""
    code, out, err = run_main(capsys, "interpolate", PLATES[0], PLATES[1], "--t", 0, 1, "-o", tmp_path / "walk.obj")
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk_000.obj", "walk_001.obj"]
    X, F = load_mesh(PLATES[1])
    Y, G = load_mesh(tmp_path / "walk_001.obj")
    topo = MeshTopology.from_faces(F, n_vertices=len(X))
    assert np.array_equal(F, G)
    assert np.abs(lengths_and_angles(Y, topo) - lengths_and_angles(X, topo)).max() < 1e-6   # key 1 itself
    code, out, err = run_main(capsys, "interpolate", PLATES[0], PLATES[1], "--t", 0, "-o", tmp_path / "w.obj",
                              "--format", "off")
    assert code == 0 and (tmp_path / "w.obj_000.off").exists(), err


@pytest.mark.parametrize("argv, fragment", [
    (["octa/octa_src_small.ply", "octa/octa_trg_small.ply", "--t", "0.5"], "601 vertices"),
    (["plate/plate121.ply", "plate/plate121_rolledA.ply", "--t", "0.5", "--keyframes", "0", "1", "2"],
     "3 keyframes given for 2 shapes"),
    (["plate/plate121.ply", "plate/plate121_rolledA.ply", "--frames", "3", "--keyframes", "4", "4"],
     "strictly increasing"),
    (["plate/plate121.ply", "--t", "0.5"], "at least 2 meshes"),
    (["plate/plate121.ply", "plate/plate121_rolledA.ply", "--t", "0.5", "--reference", "5"], "--reference"),
    (["plate/plate121.ply", "MISSING", "--t", "0.5"], "missing.ply"),
    (["plate/plate121.ply", "simple/square4.ply", "--t", "0.5"], "dense correspondence"),
    # found mid-run, after two frames were written: they are removed
    (["plate/plate121.ply", "plate/plate121_rolledA.ply", "--t", "0", "0.5", "1e160"], "at t = 1e+160"),
])
def test_bad_input_exit_code_2(argv, fragment, tmp_path, capsys):
    def arg(a):
        if a == "MISSING":
            return str(tmp_path / "missing.ply")
        return str(shared_mesh(a)) if a.endswith(".ply") else a

    args = [arg(a) for a in argv]
    code, out, err = run_main(capsys, "interpolate", *args, "-o", tmp_path / "o", "--json")
    assert code == 2
    assert out == ""
    assert err.startswith("lacore interpolate: error:") and fragment in err, err
    assert "Traceback" not in err
    assert not list(tmp_path.glob("o_*"))


def test_usage_errors(tmp_path, capsys):
    for argv in (["interpolate", str(PLATES[0]), str(PLATES[1]), "-o", str(tmp_path / "o")],  # no --t/--frames
                 ["interpolate", str(PLATES[0]), str(PLATES[1]), "--t", "0.5", "--frames", "3", "-o", "x"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
    capsys.readouterr()


def test_module_entry_point(tmp_path):
    """`python -m lacore.cli interpolate` in a fresh process: files, one JSON object; errors without traceback."""
    prefix = tmp_path / "m"
    proc = subprocess.run([sys.executable, "-m", "lacore.cli", "interpolate", str(PLATES[0]), str(PLATES[1]),
                           "--t", "0.25", "0.75", "-o", str(prefix), "--json"],
                          capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert len(json.loads(proc.stdout)["outputs"]) == 2
    assert (tmp_path / "m_000.ply").exists() and (tmp_path / "m_001.ply").exists()
    octa = [str(shared_mesh(f"octa/octa_{n}_small.ply")) for n in ("src", "trg")]
    proc = subprocess.run([sys.executable, "-m", "lacore.cli", "interpolate", *octa, "--t", "0.5", "-o", str(prefix)],
                          capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 2
    assert "not in dense correspondence" in proc.stderr and "Traceback" not in proc.stderr


def test_a_failed_frame_write_keeps_finished_frames_whole(tmp_path, monkeypatch):
    """Frames are streamed as they finish (each written atomically): a write failure at frame 2 of 3 exits 2,
    keeps frame 0 complete, leaves no frame 1 and no temporary file, and writes nothing after it."""
    import lacore.io.meshes as mesh_io

    calls = []
    original = mesh_io.atomic_write

    def failing(path, *args, **kwargs):
        calls.append(str(path))
        if len(calls) == 2:
            raise OSError("disk full")
        return original(path, *args, **kwargs)

    monkeypatch.setattr(mesh_io, "atomic_write", failing)
    prefix = tmp_path / "frame"
    code = main(["interpolate", str(PLATES[0]), str(PLATES[1]), "--t", "0.25", "0.5", "0.75", "-o", str(prefix)])
    assert code == 2 and len(calls) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_000.ply"]
    X, _ = mesh_io.load_mesh(tmp_path / "frame_000.ply")
    assert X.shape == (121, 3) and np.isfinite(X).all()


def test_method_path(tmp_path, capsys):
    """--method path: the same frames as --method gn within the path's tolerance, an indicator per frame."""
    prefix = tmp_path / "path"
    code, out, err = run_main(capsys, "interpolate", PLATES[0], PLATES[1], "--t", 0.25, 0.5, 0.75, "-o", prefix,
                              "--method", "path", "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["method"] == "path" and s["success"]
    assert all(0 < o["indicator"] <= 3e-3 and o["success"] for o in s["outputs"])
    code, out, err = run_main(capsys, "interpolate", PLATES[0], PLATES[1], "--t", 0.25, 0.5, 0.75, "-o",
                              tmp_path / "gn", "--method", "gn", "--json")
    assert code == 0, err
    XA, _ = load_mesh(PLATES[0])
    diag = float(np.linalg.norm(np.ptp(XA, axis=0)))
    for o, g in zip(s["outputs"], json.loads(out)["outputs"], strict=True):
        X, Y = load_mesh(o["file"])[0], load_mesh(g["file"])[0]
        assert np.sqrt(((X - Y) ** 2).sum(axis=1).mean()) / diag < 3e-3
    code, out, err = run_main(capsys, "interpolate", PLATES[1], PLATES[2], "--t", 0.5, "-o", tmp_path / "bad",
                              "--method", "path", "--max-iterations", 5)
    assert code == 2 and "--method path" in err


def test_bad_input_found_mid_run_removes_the_frames_written(tmp_path, capsys):
    """t = 1e160 between a sphere and the same sphere 1000 times larger: the frames at 0 and 0.5 are written, then
    the third target's energy overflows (exit 2): no frame is left behind."""
    from lacore.io.meshes import load_mesh, save_mesh

    X, F = load_mesh(shared_mesh("sphere/defSphere0.ply"))
    save_mesh(tmp_path / "big.ply", 1000.0 * X, F)
    code, out, err = run_main(capsys, "interpolate", shared_mesh("sphere/defSphere0.ply"), tmp_path / "big.ply",
                              "--t", 0, 0.5, 1e160, "-o", tmp_path / "o")
    assert code == 2 and "at t = 1e+160" in err and "overflows" in err and err.count("\n") == 1, err
    assert not list(tmp_path.glob("o_*"))


def test_bad_input_found_mid_run_keeps_the_frames_it_replaced(tmp_path, capsys):
    """Frames of an earlier run at the output's names: a run that fails on bad input after writing over two of them
    used to remove them, losing the earlier frames; now they are put back as they were."""
    from lacore.io.meshes import load_mesh, save_mesh

    X, F = load_mesh(shared_mesh("sphere/defSphere0.ply"))
    save_mesh(tmp_path / "big.ply", 1000.0 * X, F)
    old = {name: f"frame {name} of an earlier run\n" for name in ("o_000.ply", "o_001.ply")}
    for name, text in old.items():
        (tmp_path / name).write_text(text)
    code, out, err = run_main(capsys, "interpolate", shared_mesh("sphere/defSphere0.ply"), tmp_path / "big.ply",
                              "--t", 0, 0.5, 1e160, "-o", tmp_path / "o")
    assert code == 2 and "at t = 1e+160" in err, err
    assert {p.name: p.read_text() for p in tmp_path.glob("o_*")} == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.ply", "o_000.ply", "o_001.ply"]


@pytest.mark.parametrize("folder", ["frames/", "existing"])
def test_output_prefix_naming_a_folder_is_refused(folder, tmp_path, capsys):
    """``-o frames/`` (or an existing folder) would write ``frames/_000.ply`` (or ``existing_000.ply`` beside it):
    refused in one line suggesting a prefix in it, nothing written."""
    (tmp_path / "existing").mkdir()
    (tmp_path / "frames").mkdir()
    before = sorted(p.name for p in tmp_path.rglob("*"))
    prefix = str(tmp_path / folder) + ("/" if folder.endswith("/") else "")
    code, out, err = run_main(capsys, "interpolate", shared_mesh("plate/plate121.ply"),
                              shared_mesh("plate/plate121_rolledA.ply"), "--t", "0.5", "-o", prefix)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert "is a folder: give a file name prefix in it, such as" in err and "frame" in err, err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
