"""`lacore encode`: .npz contents, --json summary, errors (exit code 2, no traceback)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, shared_mesh

from lacore.cli import SUBCOMMANDS, Subcommand, main
from lacore.errors import MeshError
from lacore.io.meshes import load_mesh, save_mesh

JSON_KEYS = {"vertices", "edges", "faces", "integrable", "max_integrability_violation", "integrability_tolerances",
             "genus", "boundary_loops", "loops", "seconds"}

MESHES = [
    "simple/square4.ply",
    "simple/square4_bent.ply",
    "simple/SteffensPolyhedron.ply",
    "plate/plate121.ply",
    "plate/plate121_rolledA.ply",
    "hyperbolic/monkey_saddle_1.ply",
    "sphere/unitSphere1.ply",
    "finger/finger0.ply",
    "octa/octa_src_small.ply",
    "octa/octa_trg_small.ply",
]


def run_main(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("relative", MESHES)
def test_encode_npz_and_json(relative, tmp_path, capsys):
    mesh = shared_mesh(relative)
    out = tmp_path / "z.npz"
    code, stdout, stderr = run_main(capsys, "encode", mesh, "-o", out, "--json")
    assert code == 0, stderr
    summary = json.loads(stdout)  # exactly one JSON object
    assert JSON_KEYS <= set(summary)
    X, faces = load_mesh(mesh)
    data = np.load(out)
    assert {"faces", "edges", "lengths", "angles", "vertices"} <= set(data.files)
    V, F, E = len(X), len(faces), len(data["edges"])
    assert (summary["vertices"], summary["faces"], summary["edges"]) == (V, F, E)
    np.testing.assert_array_equal(data["faces"], faces)  # file order kept
    np.testing.assert_array_equal(data["vertices"], X)
    assert data["faces"].shape == (F, 3) and data["edges"].shape == (E, 2)
    assert data["lengths"].shape == (E,) and data["angles"].shape == (E,)
    assert data["lengths"].dtype == np.float64 and data["angles"].dtype == np.float64
    # the edges are exactly the triangle edges, each once
    tri_edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    np.testing.assert_array_equal(np.unique(tri_edges, axis=0), np.unique(np.sort(data["edges"], 1), axis=0))
    assert len(np.unique(np.sort(data["edges"], 1), axis=0)) == E
    # lengths are the distances of the edge end points
    np.testing.assert_allclose(data["lengths"], np.linalg.norm(X[data["edges"][:, 1]] - X[data["edges"][:, 0]],
                                                               axis=1), rtol=1e-13)
    # angles: radians in (-pi, pi], exactly 0 on boundary edges (edges with one face)
    assert np.all(np.abs(data["angles"]) <= np.pi)
    counts = {}
    for a, b in tri_edges.tolist():
        counts[(a, b)] = counts.get((a, b), 0) + 1
    boundary = np.array([counts[tuple(sorted(e))] == 1 for e in data["edges"].tolist()])
    assert np.all(data["angles"][boundary] == 0.0)
    assert summary["boundary_edges"] == int(boundary.sum())
    # an embedded mesh is integrable: tr I_v = 3 up to round-off; the shared meshes have no holes or handles to check
    assert summary["integrable"] is True and summary["loops"] == []
    violation = summary["max_integrability_violation"]
    assert violation["local"] < 1e-8 and violation["holonomy"] == violation["translation"] == 0
    assert summary["seconds"] > 0


def test_known_values(tmp_path, capsys):
    """Flat meshes have zero angles; closed genus-0 meshes satisfy Euler's formula."""
    for relative in ("simple/square4.ply", "plate/plate121.ply"):
        out = tmp_path / "flat.npz"
        assert run_main(capsys, "encode", shared_mesh(relative), "-o", out)[0] == 0
        np.testing.assert_allclose(np.load(out)["angles"], 0.0, atol=1e-12)
    out = tmp_path / "bent.npz"
    assert run_main(capsys, "encode", shared_mesh("simple/square4_bent.ply"), "-o", out)[0] == 0
    assert np.abs(np.load(out)["angles"]).max() > 0.1
    _code, stdout, _ = run_main(capsys, "encode", shared_mesh("finger/finger0.ply"), "--json")
    s = json.loads(stdout)
    assert s["vertices"] - s["edges"] + s["faces"] == 2 and s["boundary_edges"] == 0


def test_encode_lists_the_loops_of_holes_and_handles(tmp_path, capsys):
    """A torus with two holes: two handle loops and one hole loop, each closing to round-off."""
    from lacore.samples.surfaces import pretzel_with_holes
    X, F = pretzel_with_holes(1, 2)
    save_mesh(tmp_path / "torus.ply", X, F)
    code, stdout, stderr = run_main(capsys, "encode", tmp_path / "torus.ply", "--json")
    assert code == 0, stderr
    s = json.loads(stdout)
    assert s["integrable"] is True and s["genus"] == [1] and s["boundary_loops"] == [2]
    assert [loop["kind"] for loop in s["loops"]] == ["handle", "handle", "hole"]
    assert all(loop["closes"] and loop["holonomy"] < 1e-13 and loop["translation"] < 1e-14 for loop in s["loops"])
    violation = s["max_integrability_violation"]
    assert violation["local"] < 1e-28 and violation["holonomy"] < 1e-13 and violation["translation"] < 1e-14
    assert s["integrability_tolerances"] == {"local": 1e-8, "holonomy": 1e-4, "translation": 1e-4}
    code, stdout, _ = run_main(capsys, "encode", tmp_path / "torus.ply")
    assert code == 0 and "integrable: the frames close around every vertex" in stdout and "3 loops" in stdout


def test_octa_meshes_are_not_in_correspondence(capsys):
    """Each octa mesh encodes on its own, but their sizes differ (600 vs 601 vertices)."""
    sizes = []
    for name in ("octa/octa_src_small.ply", "octa/octa_trg_small.ply"):
        code, stdout, stderr = run_main(capsys, "encode", shared_mesh(name), "--json")
        assert code == 0, stderr
        s = json.loads(stdout)
        sizes.append((s["vertices"], s["edges"], s["faces"]))
    assert sizes == [(600, 1794, 1196), (601, 1797, 1198)]


def test_console_script_and_module(tmp_path):
    """The installed `lacore` script (and `python -m lacore.cli`) run in a fresh process."""
    script = Path(sys.executable).parent / "lacore"
    cmds = [[sys.executable, "-m", "lacore.cli"]]
    if script.exists():
        cmds.append([str(script)])
    for cmd in cmds:
        out = tmp_path / "square.npz"
        proc = subprocess.run([*cmd, "encode", str(shared_mesh("simple/square4_bent.ply")), "-o", str(out), "--json"],
                              capture_output=True, text=True, cwd=REPO, timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert JSON_KEYS <= set(json.loads(proc.stdout))
        assert out.exists()


def test_missing_file_exit_code_2_no_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "lacore.cli", "encode", str(tmp_path / "missing.ply"), "--json"],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2
    assert "missing.ply" in proc.stderr and "error" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("case, fragment", [
    ("quad.ply", "triangle"),
    ("quad.obj", "triangle"),
    ("nonmanifold.obj", "non-manifold"),
    ("degenerate.obj", "degenerate"),
    ("empty.off", "no faces"),
    # a point cloud: used to be called truncated ("holds 0 vertices") though it holds its 3 vertices
    ("points.ply", "has no faces"),
    ("points_no_face_element.ply", "has no faces"),
    ("notamesh.txt", "unsupported"),
    ("garbage.ply", "not a ply"),
    ("badindex.obj", "outside"),
])
def test_bad_meshes_exit_code_2(case, fragment, tmp_path, capsys):
    ply_header = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    files = {
        "quad.ply": ply_header + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
        "quad.obj": "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
        # three triangles on the edge (1, 2)
        "nonmanifold.obj": "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1 0 1\nf 1 2 3\nf 2 4 3\nf 2 3 5\n",
        "degenerate.obj": "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n",
        "empty.off": "OFF\n0 0 0\n",
        "points.ply": ply_header.replace("vertex 4", "vertex 3").replace("face 1", "face 0") + "0 0 0\n1 0 0\n1 1 0\n",
        "points_no_face_element.ply": ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                       "property float z\nend_header\n0 0 0\n1 0 0\n1 1 0\n"),
        "notamesh.txt": "hello\n",
        "garbage.ply": "this is not a ply file\n",
        "badindex.obj": "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 7\n",
    }
    path = _write(tmp_path / case, files[case])
    code, stdout, stderr = run_main(capsys, "encode", path, "--json")
    assert code == 2
    assert stdout == ""
    assert stderr.startswith("lacore encode: error:") and fragment in stderr.lower(), stderr
    assert "Traceback" not in stderr


def test_usage_errors_exit_code_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["encode"])
    assert exc.value.code == 2
    capsys.readouterr()
    code, _, err = run_main(capsys, "encode", shared_mesh("finger/finger0.ply"), "-o", "")
    assert code == 2 and "-o/--output is empty" in err, err


def test_subcommand_registry():
    assert "encode" in SUBCOMMANDS
    assert callable(SUBCOMMANDS["encode"].run) and callable(SUBCOMMANDS["encode"].configure)


@pytest.mark.parametrize("ext", [".ply", ".obj", ".off"])
def test_mesh_io_roundtrip_keeps_order(ext, tmp_path):
    X, faces = load_mesh(shared_mesh("finger/finger0.ply"))
    X = X + np.random.default_rng(1).normal(scale=1e-3, size=X.shape)  # full float64 digits
    path = tmp_path / f"m{ext}"
    save_mesh(path, X, faces)
    X2, faces2 = load_mesh(path)
    np.testing.assert_array_equal(X2, X)
    np.testing.assert_array_equal(faces2, faces)


def test_mesh_io_stl_merges_soup(tmp_path):
    X, faces = load_mesh(shared_mesh("simple/SteffensPolyhedron.ply"))
    save_mesh(tmp_path / "m.stl", X, faces)
    X2, faces2 = load_mesh(tmp_path / "m.stl")
    assert X2.shape == X.shape and faces2.shape == faces.shape
    np.testing.assert_allclose(X2[faces2], X[faces], atol=1e-6)  # same triangles, vertices renumbered


def test_mesh_io_keeps_unreferenced_vertices(tmp_path):
    path = _write(tmp_path / "u.obj", "v 0 0 0\nv 9 9 9\nv 1 0 0\nv 0 1 0\nf 1 3 4\n")
    X, faces = load_mesh(path)
    assert len(X) == 4 and faces.tolist() == [[0, 2, 3]]
    ply = tmp_path / "u.ply"
    save_mesh(ply, X, faces)
    X2, faces2 = load_mesh(ply)
    np.testing.assert_array_equal(faces2, faces)
    np.testing.assert_array_equal(X2, X)


def test_only_input_errors_are_reported_as_bad_input(monkeypatch, tmp_path, capsys):
    """An InputError exits 2 with one line; any other exception is a bug and propagates (traceback)."""
    from lacore.cli import encode

    def buggy(args):
        raise ValueError("a bug deep in NumPy code")

    def bad_input(args):
        raise MeshError("the mesh is not manifold at vertex 3")

    for run, outcome in ((buggy, ValueError), (bad_input, 2)):
        monkeypatch.setitem(SUBCOMMANDS, "encode", Subcommand("encode", encode.HELP, encode.configure, run))
        if outcome == 2:
            assert main(["encode", str(tmp_path / "x.ply")]) == 2
            assert capsys.readouterr().err == "lacore encode: error: the mesh is not manifold at vertex 3\n"
        else:
            with pytest.raises(ValueError, match="a bug deep in NumPy code"):
                main(["encode", str(tmp_path / "x.ply")])
