"""Hostile input to every command and public reader: one line on stderr naming the problem and what to do, the
documented exit code (2 bad input, 3 a written result that failed its checks, 130 Ctrl-C), no traceback, nothing
written.  Shape-model, marker and mesh files are made here, small, so the whole module stays fast."""

import errno
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from c3d_synthetic import write_c3d_file
from conftest import REPO, shared_mesh

import lacore.cli.fit as cli_fit
import lacore.io.atomic as atomic_io
from lacore.cli import main
from lacore.errors import InputError
from lacore.io.meshes import load_mesh, save_mesh
from lacore.markers.binding import MarkerBinding, surface_points
from lacore.markers.io import MarkerError, MarkerFileError, read_markers, read_marker_arrays
from lacore.models.shape_model import ShapeModel, ShapeModelError
from lacore.samples.bar import bar_mesh, bar_pose

PLATE, PLATE_A = "plate/plate121.ply", "plate/plate121_rolledA.ply"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def listing(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def fails(capsys, folder, *argv, message, code=2):
    """Run ``lacore argv``: exit ``code``, ONE stderr line ``lacore <cmd>: error: ...`` containing ``message``,
    no traceback, no temporary-file name, and ``folder`` exactly as before."""
    before = listing(folder)
    got, out, err = run(capsys, *argv)
    assert got == code, err
    assert err.count("\n") == 1 and err.startswith(f"lacore {argv[0]}: error: "), err
    assert message in err, err
    assert "Traceback" not in err and ".tmp" not in err, err
    assert listing(folder) == before
    return err


@pytest.fixture(scope="module")
def bar_model(tmp_path_factory):
    """A 3-mode model of a small bar, its file, and markers on it (vertices and a take of 3 frames)."""
    d = tmp_path_factory.mktemp("hostile_model")
    X0, F = bar_mesh(n_along=8)
    train = np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 3) for tw in np.linspace(-1, 1, 2)])
    model = ShapeModel.fit(train, F, n_modes=3)
    model.save(d / "model.npz")
    verts = np.random.default_rng(0).choice(len(X0), 10, replace=False)
    true = np.array([bar_pose(X0, 0.5 * s, 0.3 * s) for s in np.linspace(0, 1, 3)])
    x = surface_points(true, F, MarkerBinding.from_vertices(verts, F))
    return d, model, verts, x


# --------------------------------------------------------------------------- mesh files (encode)
def _mesh_files(d):
    X, F = load_mesh(shared_mesh(PLATE))
    save_mesh(d / "good.ply", X, F)
    raw = (d / "good.ply").read_bytes()
    files = {
        "empty.ply": (b"", "not a PLY file"),
        "empty.obj": (b"", "the mesh has no faces"),
        "empty.off": (b"", "not an OFF file"),
        "empty.stl": (b"", "the mesh has no faces"),
        "truncated.ply": (raw[: len(raw) // 2], "truncated or damaged"),
        "header_only.ply": (raw[: raw.index(b"end_header\n") + 11], "truncated or damaged"),
        "short.ply": (b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                      b"property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
                      b"0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n",
                      "announces 4 vertices and 4 faces but the file holds 4 vertices and 2 faces: it is truncated"),
        "negative.ply": (b"ply\nformat ascii 1.0\nelement vertex -4\nend_header\n", "negative count"),
        "garbage.stl": (bytes(range(256)) * 3, "cannot read mesh"),
        "huge_index.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "cannot read mesh"),
        "text.obj": (b"v a b c\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "is it a valid OBJ file?"),
        "quad.obj": (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n", "triangulate the mesh first"),
        "counts.off": (b"OFF\nx y 0\n", "is it a valid OFF file?"),
        "nan.obj": (b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "nan.obj: vertices has NaN or infinite coordinates"),
        "unknown.xyz": (b"1 2 3\n", "unsupported mesh format '.xyz'"),
    }
    for name, (data, _) in files.items():
        (d / name).write_bytes(data)
    (d / "folder.ply").mkdir()
    return files


def test_hostile_mesh_files_one_line_each(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    files = _mesh_files(src)
    for name, (_, message) in files.items():
        fails(capsys, out, "encode", src / name, "-o", out / "z.npz", message=message)
        assert "triangulate" not in message or name == "quad.obj"
    err = fails(capsys, out, "encode", src / "short.ply", "-o", out / "z.npz", message="truncated or damaged")
    assert "triangulate" not in err
    fails(capsys, out, "encode", src / "folder.ply", message="is a folder, not a mesh file")
    fails(capsys, out, "encode", src / "missing.ply", message="missing.ply: no such mesh file")
    with pytest.raises(InputError, match="truncated or damaged"):
        load_mesh(src / "truncated.ply")


def test_outputs_that_cannot_be_written_name_the_file(tmp_path, capsys, monkeypatch):
    mesh = shared_mesh(PLATE)
    (tmp_path / "taken.npz").mkdir()
    (tmp_path / "taken.ply").mkdir()
    fails(capsys, tmp_path, "encode", mesh, "-o", tmp_path / "taken.npz", message="taken.npz: it is a folder")
    fails(capsys, tmp_path, "encode", mesh, "-o", f"{tmp_path}/sub/", message="it is a folder: give a file name")
    fails(capsys, tmp_path, "encode", mesh, "-o", tmp_path / "no" / "z.npz",
          message=f"cannot write {tmp_path / 'no' / 'z.npz'}: its folder does not exist")
    for argv in (("reconstruct", "--ref", mesh, "--target", shared_mesh(PLATE_A), "-o", tmp_path / "taken.ply"),
                 ("interpolate", mesh, shared_mesh(PLATE_A), "--t", "0.5", "-o", tmp_path / "no" / "f"),
                 ("model", mesh, shared_mesh(PLATE_A), "-o", tmp_path / "taken.npz")):
        fails(capsys, tmp_path, *argv, message="cannot write")

    # a read-only folder (simulated: root may write anywhere) and a rename that fails: the user's file is named
    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / ".z.npz.abc123.tmp"))

    with monkeypatch.context() as m:
        m.setattr(atomic_io.tempfile, "mkstemp", denied)
        fails(capsys, tmp_path, "encode", mesh, "-o", tmp_path / "z.npz",
              message=f"cannot write {tmp_path / 'z.npz'}: permission denied: choose a folder you can write to")

    def replace_fails(src, dst):
        raise IsADirectoryError(errno.EISDIR, "Is a directory", src, dst)

    with monkeypatch.context() as m:
        m.setattr(atomic_io.os, "replace", replace_fails)
        fails(capsys, tmp_path, "encode", mesh, "-o", tmp_path / "z.npz", message="cannot write")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="needs a user whom a read-only folder stops")
def test_read_only_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        fails(capsys, tmp_path, "encode", shared_mesh(PLATE), "-o", ro / "z.npz", message="permission denied")
    finally:
        ro.chmod(0o755)


# --------------------------------------------------------------------------- reconstruct, interpolate
def test_hostile_targets_and_options(tmp_path, capsys):
    ref, other = shared_mesh(PLATE), shared_mesh(PLATE_A)
    X, F = load_mesh(ref)
    np.savez(tmp_path / "objects.npz", faces=np.array([1, "a"], dtype=object), edges=np.zeros((2, 2), int),
             lengths=np.zeros(2), angles=np.zeros(2))
    np.savez(tmp_path / "floats.npz", faces=F.astype(float), edges=np.zeros((2, 2), int), lengths=np.zeros(2),
             angles=np.zeros(2))
    (tmp_path / "folder.npz").mkdir()
    out = tmp_path / "r.ply"
    base = ("reconstruct", "--ref", ref, "-o", out, "--target")
    fails(capsys, tmp_path, *base, tmp_path / "objects.npz", message="cannot read 'faces'")
    fails(capsys, tmp_path, *base, tmp_path / "floats.npz", message="'faces' must hold integers")
    fails(capsys, tmp_path, *base, tmp_path / "folder.npz", message="is a folder")
    fails(capsys, tmp_path, *base, other, "--weights", "nan", message="the weights must be finite")
    fails(capsys, tmp_path, *base, other, "--fixed-face", "99999999999999999999", message="fixed_face")
    inter = ("interpolate", ref, other, "-o", tmp_path / "f")
    for t in ("nan", "inf"):
        fails(capsys, tmp_path, *inter, "--t", t, message="--t takes finite numbers")
    fails(capsys, tmp_path, *inter, "--t", "0.5", "--keyframes", "0", "nan", message="keyframe")
    with pytest.raises(SystemExit) as exit_info:  # argparse: usage line and error, exit 2
        main([str(a) for a in (*inter, "--frames", "10000000000")])
    assert exit_info.value.code == 2 and "must be at most 100000" in capsys.readouterr().err
    assert listing(tmp_path) == ["floats.npz", "folder.npz", "objects.npz"]


# --------------------------------------------------------------------------- shape models
def test_model_of_meshes_too_large_for_double_precision(tmp_path, capsys):
    for name in (PLATE, PLATE_A):
        X, F = load_mesh(shared_mesh(name))
        save_mesh(tmp_path / name.split("/")[1], X * 1e200, F)
    fails(capsys, tmp_path, "model", tmp_path / "plate121.ply", tmp_path / "plate121_rolledA.ply", "-o",
          tmp_path / "m.npz", message="too large or too small for the model's weights and variances in double "
                                      "precision: scale the meshes toward unit size")


@pytest.mark.parametrize("field, value, message", [
    ("variances", lambda a: -a["variances"], "variances must be positive"),
    ("variances", lambda a: a["variances"] * np.nan, "variances has NaN or infinite entries"),
    ("modes", lambda a: np.array([None, 1], dtype=object), "cannot read 'modes'"),
    ("modes", lambda a: a["modes"][:0], "the model has no modes"),
    ("tangent", lambda a: np.array("weird"), "tangent must be one of ambient, projected, got 'weird'"),
    ("bending_weight", lambda a: np.array("x"), "bending_weight must be a finite number, got 'x'"),
    ("bending_weight", lambda a: np.array(-1.0), "bending_weight must be >= 0"),
    ("format_version", lambda a: np.array([1, 2]), "format version [1, 2]"),
    ("explained_variance_ratio", lambda a: np.array([2.0, -1.0, 0.5]), "must be in [0, 1]"),
    ("total_variance", lambda a: np.array(-1.0), "total_variance must be positive"),
    ("faces", lambda a: a["faces"].astype(float), "faces must hold integers, got float64 values"),
    ("mean_z", lambda a: -a["mean_z"], "mean_z has lengths <= 0"),
])
def test_invalid_model_files_are_rejected_on_load(bar_model, tmp_path, capsys, field, value, message):
    d, model, verts, x = bar_model
    with np.load(d / "model.npz") as f:
        arrays = dict(f)
    arrays[field] = value(arrays)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ShapeModelError, match="bad.npz") as info:
        ShapeModel.load(tmp_path / "bad.npz")
    assert message in str(info.value) and "\n" not in str(info.value)
    fails(capsys, tmp_path, "model-sweep", tmp_path / "bad.npz", "--mode", "0", "-o", tmp_path / "s", message=message)
    np.savez(tmp_path / "markers.npz", positions=x, vertices=verts)
    fails(capsys, tmp_path, "fit", tmp_path / "bad.npz", "--markers", tmp_path / "markers.npz", "-o",
          tmp_path / "f.npz", message=message)


def test_model_save_goes_through_the_atomic_writer(bar_model, tmp_path, monkeypatch):
    d, model, verts, x = bar_model
    target = tmp_path / "m.npz"
    target.write_bytes(b"OLD")
    real = os.fdopen

    class Full:
        def __init__(self, fh):
            self.fh, self.n = fh, 0

        def write(self, b):
            self.n += len(b)
            if self.n > 1000:
                raise OSError(errno.ENOSPC, "No space left on device")
            return self.fh.write(b)

        def __getattr__(self, name):
            return getattr(self.fh, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    monkeypatch.setattr(atomic_io.os, "fdopen", lambda fd, mode="r", **kw: Full(real(fd, mode, **kw)))
    with pytest.raises(OSError, match=f"cannot write {target}: No space left on device"):
        model.save(target)
    assert target.read_bytes() == b"OLD" and listing(tmp_path) == ["m.npz"]
    monkeypatch.undo()
    assert model.save(tmp_path / "noext") == str(tmp_path / "noext.npz")


def test_sweep_failures_are_reported(bar_model, tmp_path, capsys):
    """A sweep whose frames fail their checks writes them, says so on stderr and exits 3 (0 and a warning with
    --allow-failure); one too far out for any mesh exits 2 and writes nothing."""
    d, model, verts, x = bar_model
    sweep = ("model-sweep", d / "model.npz", "--mode", "0", "--frames", "1", "--range")
    code, out, err = run(capsys, *sweep, "20", "20", "-o", tmp_path / "a")
    assert code == 3 and err.count("\n") == 1 and err.startswith("lacore model-sweep: failed: 1 of 1 frames failed")
    assert "folded" in err and "try a smaller --range" in err and listing(tmp_path) == ["a_000.ply"]
    code, out, err = run(capsys, *sweep, "20", "20", "-o", tmp_path / "b", "--allow-failure")
    assert code == 0 and err.startswith("lacore model-sweep: warning: 1 of 1 frames failed")
    fails(capsys, tmp_path, *sweep, "50", "50", "-o", tmp_path / "c", message="too far from the training poses")
    fails(capsys, tmp_path, *sweep, "nan", "0", "-o", tmp_path / "c", message="--range must be two finite numbers")
    fails(capsys, tmp_path, *sweep, "1e300", "1e300", "-o", tmp_path / "c",
          message="beyond what double precision can reconstruct")
    fails(capsys, tmp_path, "model-sweep", d / "model.npz", "--mode", "7", "-o", tmp_path / "c",
          message="--mode 7 is not a mode")


# --------------------------------------------------------------------------- markers and fit
@pytest.mark.parametrize("case, message", [
    ("no_frames", "no frames (positions of shape (0, M, 3))"),
    ("no_markers", "no markers (positions of shape (T, 0, 3))"),
    ("huge", "marker positions reach"),
    ("all_nan", "no marker is visible in any frame"),
    ("objects", "cannot read 'positions'"),
    ("object_vertices", "cannot read 'vertices'"),
    ("float_vertices", "'vertices' must hold integers"),
    ("complex", "'positions' must hold real numbers"),
    ("string_offsets", "'offsets' must hold real numbers"),
    ("nan_barycentric", "not finite"),
    ("infinite", "infinite"),
    ("single_array", "holds a single array"),
    ("text", "is not a readable .npz markers file"),
])
def test_hostile_marker_files(bar_model, tmp_path, capsys, case, message):
    d, model, verts, x = bar_model
    f = tmp_path / f"{case}.npz"
    b = MarkerBinding.from_vertices(verts, model.faces)
    arrays = {"no_frames": {"positions": x[:0], "vertices": verts},
              "no_markers": {"positions": x[:, :0], "vertices": verts[:0]},
              "huge": {"positions": x * 1e200, "vertices": verts},
              "all_nan": {"positions": x * np.nan, "vertices": verts},
              "objects": {"positions": np.array([None, 1], dtype=object), "vertices": verts},
              "object_vertices": {"positions": x, "vertices": np.array([None] * 10, dtype=object)},
              "float_vertices": {"positions": x, "vertices": verts + 0.5},
              "complex": {"positions": x.astype(complex), "vertices": verts},
              "string_offsets": {"positions": x, "vertices": verts, "offsets": np.array(["a"] * 10)},
              "nan_barycentric": {"positions": x, "faces": b.faces, "barycentric": b.barycentric * np.nan},
              "infinite": {"positions": np.where(np.arange(10)[:, None] == 2, np.inf, x), "vertices": verts}}
    if case == "single_array":
        np.save(tmp_path / "single.npy", x)
        os.replace(tmp_path / "single.npy", f)
    elif case == "text":
        f.write_text("positions")
    else:
        np.savez(f, **arrays[case])
    with pytest.raises(InputError) as info:
        read_marker_arrays(f, model.faces, model.topology.n_vertices)
    assert message in str(info.value) and "\n" not in str(info.value)
    fails(capsys, tmp_path, "fit", d / "model.npz", "--markers", f, "-o", tmp_path / "out.npz", message=message)


def test_markers_far_beyond_the_models_scale_fail_without_a_traceback(bar_model, tmp_path, capsys):
    """Markers 1e60 times the model's size: the command names the unit mismatch (exit 2, nothing written); the
    library's fit, given them anyway, finds every frame's system not finite and says so instead of raising."""
    d, model, verts, x = bar_model
    np.savez(tmp_path / "far.npz", positions=x * 1e60, vertices=verts)
    code, out, err = run(capsys, "fit", d / "model.npz", "--markers", tmp_path / "far.npz", "-o", tmp_path / "o.npz")
    assert code == 2 and "times as far apart as the points they are bound to" in err, err
    assert not (tmp_path / "o.npz").exists()
    with np.errstate(all="ignore"):  # the overflow is expected here: the result says what went wrong
        summary = cli_fit.fit_markers(model, x * 1e60, MarkerBinding.from_vertices(verts, model.faces)).summary()
    assert not summary["success"] and summary["message"] == "3 frames: the linear system could not be solved"


def test_a_failed_fit_says_so(bar_model, tmp_path, capsys, monkeypatch):
    d, model, verts, x = bar_model
    np.savez(tmp_path / "m.npz", positions=x, vertices=verts)
    real = cli_fit.fit_markers

    def failing(*args, **kwargs):
        res = real(*args, **kwargs)
        res.success, res.message = False, "frame 1: the line search found no decrease"
        return res

    monkeypatch.setattr(cli_fit, "fit_markers", failing)
    code, out, err = run(capsys, "fit", d / "model.npz", "--markers", tmp_path / "m.npz", "-o", tmp_path / "o.npz")
    assert code == 3 and err == "lacore fit: failed: frame 1: the line search found no decrease\n"
    assert (tmp_path / "o.npz").is_file()
    code, out, err = run(capsys, "fit", d / "model.npz", "--markers", tmp_path / "m.npz", "-o", tmp_path / "o.npz",
                         "--allow-failure")
    assert code == 0 and err.startswith("lacore fit: warning: ")


def test_marker_take_readers(tmp_path):
    header = "PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n"
    names = "Frame#\tTime\tA\t\t\n\t\tX1\tY1\tZ1\n\n"
    cases = {"inf_frame": (header + "100\t100\t2\t1\tmm\n" + names + "inf\t0\t1\t2\t3\n2\t0.01\t1\t2\t3\n",
                           "frame number inf"),
             "huge_frame": (header + "100\t100\t1\t1\tmm\n" + names + "1e300\t0\t1\t2\t3\n", "frame number 1e\\+300"),
             "nan_rate": (header + "nan\t100\t1\t1\tmm\n" + names + "1\t0\t1\t2\t3\n", "frame rate must be positive"),
             "inf_markers": (header + "100\t100\t1\tinf\tmm\n" + names + "1\t0\t1\t2\t3\n", "malformed TRC header")}
    for name, (text, message) in cases.items():
        (tmp_path / f"{name}.trc").write_text(text)
        with pytest.raises(MarkerError, match=message) as info:
            read_markers(tmp_path / f"{name}.trc")
        assert "\n" not in str(info.value)
    (tmp_path / "folder.c3d").mkdir()
    with pytest.raises(MarkerFileError, match="cannot read the file"):
        read_markers(tmp_path / "folder.c3d")


@pytest.mark.parametrize("optimize", [False, True])
def test_c3d_with_damaged_analog_rate(tmp_path, optimize):
    """The c3d package checks ANALOG:RATE with assert only: lacore checks it itself, also under python -O."""
    paths = [tmp_path / f"analog{i}.c3d" for i in range(2)]
    for path, rate in zip(paths, (float("nan"), -100.0), strict=True):
        write_c3d_file(path, np.arange(27.0).reshape(3, 3, 3), ["A", "B", "C"], 100.0, analog=(2, rate))
    code = ("import sys\nfrom lacore.markers.io import read_markers\nfor path in sys.argv[1:]:\n"
            "    try:\n        read_markers(path)\n    except Exception as e:\n        print(type(e).__name__, e)\n")
    proc = subprocess.run([sys.executable, *(["-O"] if optimize else []), "-c", code, *map(str, paths)],
                          capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 2 and all(line.startswith("MarkerFileError ") for line in lines), proc.stdout
    assert all(("invalid analog channels" if optimize else "inconsistent analog rate") in line for line in lines)


def test_point_caches(tmp_path):
    from lacore.io.point_cache import PointCacheError, read_pc2, write_pc2

    with pytest.raises(PointCacheError, match="do not fit the float32 numbers of a PC2 file"):
        write_pc2(tmp_path / "big.pc2", np.full((2, 3, 3), 1e300))
    with pytest.raises(PointCacheError, match="non-finite"):
        write_pc2(tmp_path / "nan.pc2", np.full((2, 3, 3), np.nan))
    assert listing(tmp_path) == []
    write_pc2(tmp_path / "ok.pc2", np.ones((2, 3, 3)))
    raw = (tmp_path / "ok.pc2").read_bytes()
    (tmp_path / "short.pc2").write_bytes(raw[:-5])
    with pytest.raises(PointCacheError, match="short.pc2: 99 bytes, the header .2 samples of 3 points. needs 104"):
        read_pc2(tmp_path / "short.pc2")


# --------------------------------------------------------------------------- Ctrl-C and worker processes
def _default_sigint():
    """In the child: Ctrl-C as in a terminal, even when the suite runs with SIGINT ignored (a shell's `make test &`
    without job control ignores it, and children inherit that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(argv, **kw):
    return subprocess.Popen([sys.executable, "-m", "lacore.cli", *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, start_new_session=True,
                            preexec_fn=_default_sigint, env={**os.environ, "PYTHONPATH": str(REPO)}, **kw)


def test_ctrl_c_stops_a_run_with_workers_in_one_line(tmp_path):
    """SIGINT to the whole process group (as a terminal's Ctrl-C): one line, exit 130, no worker traceback."""
    proc = _start(["interpolate", shared_mesh("finger/finger0.ply"), shared_mesh("finger/finger1.ply"), "--frames",
                   "400", "--workers", "2", "-o", tmp_path / "f"])
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(tmp_path.glob("f_*.ply")):  # the run is under way
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and err == "lacore interpolate: interrupted\n", err
    assert not list(tmp_path.glob(".*.tmp"))


def test_a_closed_stdout_ends_the_command_quietly():
    """`lacore encode ... --json | head -c 0`: the reader is gone; no error message, no traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run([sys.executable, "-m", "lacore.cli", "encode", str(shared_mesh(PLATE)), "--json"],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, cwd=REPO, timeout=120,
                              env={**os.environ, "PYTHONPATH": str(REPO)})
    finally:
        os.close(write_end)
    assert proc.returncode == 141 and proc.stderr == "", proc.stderr


def test_a_worker_whose_caller_died_ends_quietly(tmp_path):
    """The caller is killed while its worker still sends messages: the worker ends at the next one, silently."""
    (tmp_path / "slow_job.py").write_text(
        "import time\n\ndef job(n, send):\n    for i in range(n):\n        send(i)\n        time.sleep(0.1)\n"
        "    return n\n")
    caller = ("import os, sys, time\nsys.path.insert(0, sys.argv[1])\nfrom slow_job import job\n"
              "from lacore.parallel import WorkerProcess\n"
              "w = WorkerProcess(job, (400,))\nw.messages.get(timeout=60)\n"
              "print(w._process.pid, flush=True)\nos._exit(1)\n")
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", caller, str(tmp_path)], capture_output=True, text=True, cwd=REPO,
                          timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})
    # the worker shares the caller's stderr, so run() returns once the worker has ended too: silently, and long
    # before its 400 messages (40 s) were sent
    assert proc.stderr == "" and proc.stdout.split()[0].isdigit(), proc.stderr
    assert time.monotonic() - start < 30


def test_obj_whitespace_and_comments(tmp_path):
    """OBJ records separated by tabs, indented, or with trailing comments are read like plain ones."""
    plain = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    for name, text in (("tabs.obj", b"v\t0\t0\t0\nv\t1\t0\t0\nv\t0\t1\t0\nf\t1\t2\t3\n"),
                       ("indented.obj", b"  v 0 0 0\n  v 1 0 0\n\tv 0 1 0\n  f 1 2 3\n"),
                       ("comments.obj", b"# a triangle\nv 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3 # the face\n")):
        (tmp_path / name).write_bytes(text)
        (tmp_path / "plain.obj").write_bytes(plain)
        X, F = load_mesh(tmp_path / name)
        Xp, Fp = load_mesh(tmp_path / "plain.obj")
        assert np.array_equal(X, Xp) and np.array_equal(F, Fp), name


def test_nan_input_of_the_jacobian_and_the_integrability_maps_is_refused():
    """NaN in, one-line error out (as ``lengths_and_angles`` and ``check_integrability`` do), not NaN out."""
    from lacore import (MeshTopology, euler_integrability_map, integrability_violation, lengths_and_angles,
                        lengths_and_angles_jacobian)
    from lacore.errors import LengthsAnglesError, MeshError
    X, F = bar_mesh(n_along=4, n_side=1)
    topo = MeshTopology.from_faces(F)
    z = lengths_and_angles(X, topo)
    z[5] = np.nan
    for f in (integrability_violation, euler_integrability_map):
        with pytest.raises(LengthsAnglesError, match=r"NaN or infinite entries \(1\)"):
            f(z, topo)
    Y = X.copy()
    Y[3] = np.nan
    with pytest.raises(MeshError, match="NaN or infinite coordinates at vertices 3"):
        lengths_and_angles_jacobian(Y, topo)
    with pytest.raises(MeshError):
        lengths_and_angles_jacobian(X[None], topo)


def test_option_values_and_types_are_checked():
    """Bad option values and types: one-line InputErrors naming the option, not a silent 'not integrable', a
    coarsening with NaN weights or an AttributeError deep inside."""
    from lacore import MeshTopology, check_integrability, lengths_and_angles
    from lacore.multiresolution import coarsen, vertex_rotations
    from lacore.shapes.geodesics import discrete_geodesic
    X, F = bar_mesh(n_along=4, n_side=1)
    topo = MeshTopology.from_faces(F)
    z = lengths_and_angles(X, topo)
    for tol in (-1.0, np.nan, "a"):
        with pytest.raises(InputError, match="local_tolerance must be a finite number >= 0"):
            check_integrability(z, topo, local_tolerance=tol)
    for kw, words in (({"boundary_weight": np.nan}, "boundary_weight must be a number >= 0"),
                      ({"min_quality": 2.0}, r"min_quality must be a number in \[0, 1\]"),
                      ({"max_normal_angle": 0.0}, r"max_normal_angle must be a number in \(0, 180\]")):
        with pytest.raises(InputError, match=words):
            coarsen(X, F, 10, **kw)
    Y = bar_pose(X, 0.3, 0.1)
    for kw, words in (({"options": {"tol": 1e-3}}, "options must be a GeodesicOptions, got dict"),
                      ({"settings": "x"}, "settings must be a ReconstructionSettings, got str")):
        with pytest.raises(InputError, match=words):
            discrete_geodesic(X, Y, topo, 3, **kw)
    with pytest.raises(InputError, match="NaN or infinite"):
        vertex_rotations(X, np.full_like(X, np.nan), topo.edges)


def test_more_option_values_are_checked():
    """pcg settings of the multiresolution reconstruction, the synthesis' length floor, a bending weight that is no
    number: one-line errors naming them."""
    from lacore import MeshTopology, ShapeModel
    from lacore.energies.quadratic import QuadraticEnergy
    from lacore.multiresolution import MultiresolutionReconstruction
    from lacore.samples.bar import bar_family
    X, F = bar_mesh(n_along=12, n_side=2)
    topo = MeshTopology.from_faces(F)
    with pytest.raises(InputError, match="bending_weight must be finite and >= 0, got 'x'"):
        QuadraticEnergy(topo, reference_vertices=X, bending_weight="x")
    mr = MultiresolutionReconstruction(np.stack([X, bar_pose(X, 0.5, 0.0)]), topo, 20)
    for kw, words in (({"pcg_rtol": -1.0}, r"pcg_rtol must be a number in \(0, 1\)"),
                      ({"pcg_maxiter": 0}, "pcg_maxiter must be a positive integer")):
        with pytest.raises(InputError, match=words):
            mr.reconstruct([0.5, 0.5], fine_solver="reference", **kw)
    poses, faces, _ = bar_family([0.0, 0.2, 0.4], [0.0, 0.1, 0.2], n_along=4, n_side=1)
    model = ShapeModel.fit(poses, faces, n_modes=2)
    with pytest.raises(InputError, match=r"min_length_ratio must be a number in \[0, 1\)"):
        model.synthesize([0.0, 0.0], min_length_ratio=2.0)
