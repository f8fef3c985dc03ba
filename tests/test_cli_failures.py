"""Issue 12 at the command line: exit code 3 for results failing their checks, atomic outputs (a write that
fails midway keeps the old file and leaves no temporary file), streamed interpolation frames, the reported
output name is the file written, negative counts rejected, degenerate / huge input."""

import errno
import gc
import io
import json
import os

import numpy as np
import pytest
from conftest import shared_mesh

import lacore.io.atomic as atomic_io
import lacore.shapes.interpolation as interpolation
import lacore.shapes.projection as projection
from lacore.io.atomic import atomic_write, npz_path, save_npz_atomic
from lacore.cli import main
from lacore.io.meshes import load_mesh, save_mesh

FINGER0, FINGER1 = "finger/finger0.ply", "finger/finger1.ply"


def run_main(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


class _DiskFull(io.RawIOBase):
    """A file whose writes fail with ENOSPC once ``limit`` bytes were written (a full disk)."""

    def __init__(self, fh, limit):
        self.fh, self.limit, self.written = fh, limit, 0

    def writable(self):
        return True

    def write(self, b):
        n = len(b)
        if self.written + n > self.limit:
            part = max(self.limit - self.written, 0)
            self.fh.write(bytes(b[:part]) if not isinstance(b, str) else b[:part])
            self.written += part
            raise OSError(errno.ENOSPC, "No space left on device (simulated)")
        self.fh.write(b)
        self.written += n
        return n

    def fileno(self):
        return self.fh.fileno()

    def flush(self):
        if not self.fh.closed:
            self.fh.flush()

    def close(self):
        if not self.closed:
            self.fh.close()
            super().close()

    def tell(self):
        return self.fh.tell()

    def seek(self, *args):
        return self.fh.seek(*args)

    def seekable(self):
        return self.fh.seekable()


@pytest.fixture
def disk_full(monkeypatch):
    """Patch the one writer (lacore.io.atomic) so that every output fails after 100 bytes."""
    real = os.fdopen

    def fdopen(fd, mode="r", **kw):
        return _DiskFull(real(fd, mode, **kw), 100)

    monkeypatch.setattr(atomic_io.os, "fdopen", fdopen)


def _old_file(path, content=b"OLD CONTENT"):
    path.write_bytes(content)
    return content


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
@pytest.mark.parametrize("name", ["z.npz", "noext"])
def test_encode_write_failure_keeps_the_old_file(name, tmp_path, capsys, disk_full):
    target = tmp_path / npz_path(name)
    old = _old_file(target)
    code, out, err = run_main(capsys, "encode", shared_mesh(FINGER0), "-o", tmp_path / name)
    gc.collect()  # an unclosed ZipFile would print its __del__ traceback now (turned into an error above)
    assert code == 2 and "No space left on device" in err and err.count("\n") == 1
    assert target.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]  # no temporary file left


@pytest.mark.parametrize("ext", [".ply", ".obj", ".off", ".stl", ".npz"])
def test_reconstruct_write_failure_keeps_the_old_file(ext, tmp_path, capsys, disk_full):
    target = tmp_path / f"out{ext}"
    old = _old_file(target)
    code, out, err = run_main(capsys, "reconstruct", "--ref", shared_mesh(FINGER0), "--target",
                              shared_mesh(FINGER1), "--method", "bfs", "-o", target)
    assert code == 2 and "No space left on device" in err
    assert target.read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


def test_atomic_write_helpers(tmp_path):
    p = tmp_path / "a.txt"
    with atomic_write(p, "w") as fh:
        fh.write("hello\n")
    assert p.read_text() == "hello\n" and oct(p.stat().st_mode & 0o777) != "0o600"
    with pytest.raises(RuntimeError):
        with atomic_write(p, "w") as fh:
            fh.write("partial")
            raise RuntimeError("writer bug")
    assert p.read_text() == "hello\n" and [q.name for q in tmp_path.iterdir()] == ["a.txt"]
    out = save_npz_atomic(tmp_path / "arrays", x=np.arange(3), y=np.eye(2))
    assert out == str(tmp_path / "arrays.npz")
    with np.load(out) as data:
        assert data["x"].tolist() == [0, 1, 2] and data["y"].shape == (2, 2)
    with pytest.raises(FileNotFoundError):
        save_npz_atomic(tmp_path / "missing_dir" / "x.npz", x=np.zeros(1))
    assert save_npz_atomic(tmp_path / "UPPER.NPZ", x=np.zeros(1)) == str(tmp_path / "UPPER.NPZ")  # any case


def test_an_upper_case_npz_output_is_written_as_named(tmp_path, capsys):
    code, out, err = run_main(capsys, "encode", shared_mesh(FINGER0), "-o", tmp_path / "z.NPZ")
    assert code == 0 and sorted(p.name for p in tmp_path.iterdir()) == ["z.NPZ"]
    code, out, err = run_main(capsys, "model", shared_mesh(FINGER0), shared_mesh(FINGER1), "-o", tmp_path / "m.NPZ")
    assert code == 0 and (tmp_path / "m.NPZ").is_file() and not (tmp_path / "m.NPZ.npz").exists()


def test_encode_reports_the_file_it_wrote(tmp_path, capsys):
    code, out, err = run_main(capsys, "encode", shared_mesh(FINGER0), "-o", tmp_path / "noext", "--json")
    assert code == 0 and json.loads(out)["output"] == str(tmp_path / "noext.npz")
    assert (tmp_path / "noext.npz").is_file() and not (tmp_path / "noext").exists()
    code, out, err = run_main(capsys, "encode", shared_mesh(FINGER0), "-o", tmp_path / "noext")
    assert code == 0 and f"wrote {tmp_path / 'noext.npz'}" in out


@pytest.mark.parametrize("argv", [
    ("reconstruct", "--max-iterations", "-5"),
    ("reconstruct", "--smoothing-iterations", "-1"),
    ("interpolate", "--max-iterations", "-5"),
    ("interpolate", "--frames", "0"),
    ("interpolate", "--frames", "-3"),
])
def test_negative_counts_are_rejected(argv, tmp_path, capsys):
    cmd, *opt = argv
    if cmd == "reconstruct":
        args = [cmd, "--ref", shared_mesh(FINGER0), "--target", shared_mesh(FINGER1), *opt, "-o", tmp_path / "x.ply"]
    else:
        args = [cmd, shared_mesh(FINGER0), shared_mesh(FINGER1), *opt, "-o", tmp_path / "f"]
        if "--frames" not in opt:
            args += ["--t", "0.5"]
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert opt[0] in err and ("non-negative" in err or "positive" in err)
    assert list(tmp_path.iterdir()) == []


def test_failed_checks_exit_3_unless_allowed(tmp_path, capsys):
    out = tmp_path / "avg.ply"
    args = ["reconstruct", "--ref", shared_mesh(FINGER0), "--target", shared_mesh(FINGER0), shared_mesh(FINGER1),
            "--method", "bfs", "-o", out, "--json"]
    code, stdout, stderr = run_main(capsys, *args)
    summary = json.loads(stdout)
    assert code == 3 and not summary["success"] and summary["failure"] == "not_reproduced"
    assert summary["checks"]["max_relative_length_error"] > 0.1  # measured 0.57
    assert "failed" in stderr and "not reproduced" in stderr and out.is_file()
    code, stdout, stderr = run_main(capsys, *args, "--allow-failure")
    assert code == 0 and "warning" in stderr and json.loads(stdout)["failure"] == "not_reproduced"
    code, stdout, _ = run_main(capsys, *[a if a != "bfs" else "gn" for a in args])
    assert code == 0 and json.loads(stdout)["success"]


def test_interpolate_exit_3_and_per_frame_failures(tmp_path, capsys):
    code, stdout, stderr = run_main(capsys, "interpolate", shared_mesh(FINGER0), shared_mesh(FINGER1), "--t", "0",
                                    "0.5", "--method", "lsq", "-o", tmp_path / "f", "--json")
    summary = json.loads(stdout)
    assert code == 3 and not summary["success"] and "t = [0.5]" in summary["message"]
    assert [o["success"] for o in summary["outputs"]] == [True, False]
    assert [o["failure"] for o in summary["outputs"]] == ["", "not_reproduced"]
    assert all(os.path.isfile(o["file"]) for o in summary["outputs"])


def test_interpolate_streams_frames(tmp_path, capsys, monkeypatch):
    """Frames are on disk as soon as they are projected: a run stopped (Ctrl-C) at the third frame keeps two."""
    real, calls = projection.reconstruct, []

    def stopping(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(projection, "reconstruct", stopping)
    code, out, err = run_main(capsys, "interpolate", shared_mesh(FINGER0), shared_mesh(FINGER1), "--t", "0", "0.5",
                              "1", "-o", tmp_path / "f")
    assert code == 130 and err == "lacore interpolate: interrupted\n"  # Ctrl-C: one line, no traceback
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_000.ply", "f_001.ply"]
    X, _ = load_mesh(tmp_path / "f_001.ply")
    assert np.all(np.isfinite(X)) and len(X) == 2046


def test_interpolation_on_frame_callback():
    from conftest import load_topology

    X0, topo = load_topology(FINGER0)
    X1, _ = load_topology(FINGER1)
    seen = []
    res = interpolation.interpolate([X0, X1], topo, [0.75, 0.25], on_frame=lambda i, r: seen.append((i, r)))
    assert [i for i, _ in seen] == [1, 0]  # in time order, indices of the given order
    assert all(r is res.reconstructions[i] for i, r in seen)


def test_encode_rejects_the_needle_and_handles_huge_coordinates(tmp_path, capsys):
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 2e-8, 0], [0.5, -0.8, 0.3], [0.5, 0.9, 0.2]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [2, 1, 4]])
    save_mesh(tmp_path / "needle.ply", V, F)
    code, out, err = run_main(capsys, "encode", tmp_path / "needle.ply", "-o", tmp_path / "n.npz")
    assert code == 2 and "degenerate triangles" in err and "faces 0" in err
    assert not (tmp_path / "n.npz").exists()
    X, F = load_mesh(shared_mesh(FINGER0))
    for scale in (1e80, 1e-80):
        save_mesh(tmp_path / "big.ply", X * scale, F)
        code, out, err = run_main(capsys, "encode", tmp_path / "big.ply", "--json")
        s = json.loads(out)
        assert code == 0 and s["max_abs_angle"] == pytest.approx(1.0675, abs=1e-4)
        assert s["max_length"] == pytest.approx(0.204828 * scale, rel=1e-5)
        assert s["max_integrability_violation"] is not None


def test_an_output_never_replaces_an_input(tmp_path, capsys):
    """Exit 2 before computing when an output file is one of the inputs (also through another name); the input is
    left as it was."""
    X0, F = load_mesh(shared_mesh(FINGER0))
    X1, _ = load_mesh(shared_mesh(FINGER1))
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    save_mesh(a, X0, F)
    save_mesh(b, X1, F)
    os.symlink(a, tmp_path / "alias.ply")
    before = a.read_bytes()
    for argv in (["reconstruct", "--ref", a, "--target", b, "-o", a],
                 ["reconstruct", "--ref", a, "--target", b, "-o", tmp_path / "alias.ply"],
                 ["interpolate", a, b, "--t", 0.5, "-o", tmp_path / "a"]):          # writes a_000.ply: allowed
        code, out, err = run_main(capsys, *argv)
        if argv[0] == "interpolate":
            assert code == 0, err
            continue
        assert code == 2 and "is the input" in err and err.count("\n") == 1, err
    assert a.read_bytes() == before


def test_usage_errors_are_one_line_and_exponents_are_numbers(tmp_path, capsys):
    """argparse's errors in one line (exit 2) naming where the usage is; ``-1e6`` is a value, not an option."""
    for argv, words in ((["interpolate", "a.ply", "b.ply", "--frames", "0", "-o", "x"], "--frames"),
                        (["reconstruct", "--nope"], "the following arguments are required"),
                        (["frobnicate"], "invalid choice")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and err.count("\n") == 1 and "--help)" in err, err
    a = shared_mesh(FINGER0)
    code, out, err = run_main(capsys, "interpolate", a, shared_mesh(FINGER1), "--t", "-1e6", "-o", tmp_path / "x")
    assert code == 2 and "t = -1e+06" in err, err         # parsed as a factor: too far to extrapolate


def test_version(capsys):
    """``lacore --version`` prints the package's version and exits 0 (a pipeline checks what it runs)."""
    import lacore
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out == f"lacore {lacore.__version__}\n"
