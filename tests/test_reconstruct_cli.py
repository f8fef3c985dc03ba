"""`lacore reconstruct`: weighted targets (meshes or `lacore encode` .npz), --json, outputs, errors (exit code 2)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, shared_mesh

from lacore.cli import SUBCOMMANDS, main
from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.io.meshes import load_mesh, save_mesh
from lacore.reconstruction import reconstruct, reconstruction_errors
from lacore.geometry.topology import MeshTopology

JSON_KEYS = {"method", "iterations", "seconds", "energy", "max_length_error", "max_angle_error", "success",
             "message", "weights", "targets", "output"}


def run_main(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def finger():
    X0, F = load_mesh(shared_mesh("finger/finger0.ply"))
    X1, _ = load_mesh(shared_mesh("finger/finger1.ply"))
    topo = MeshTopology.from_faces(F, n_vertices=len(X0))
    return topo, X0, X1, lengths_and_angles(X0, topo), lengths_and_angles(X1, topo)


def test_reconstruct_is_registered():
    assert "reconstruct" in SUBCOMMANDS


def test_average_of_two_meshes_matches_the_library(finger, tmp_path, capsys):
    topo, X0, X1, z0, z1 = finger
    out = tmp_path / "avg.ply"
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", shared_mesh("finger/finger0.ply"), "--target",
                                    shared_mesh("finger/finger0.ply"), shared_mesh("finger/finger1.ply"),
                                    "-o", out, "--json")
    assert code == 0, stderr
    summary = json.loads(stdout)  # exactly one JSON object
    assert JSON_KEYS <= set(summary)
    assert summary["method"] == "gn" and summary["weights"] == [0.5, 0.5] and summary["success"]
    za = 0.5 * (z0 + z1)
    api = reconstruct(za, topo, X0)
    assert summary["iterations"] == api.iterations <= 12
    assert summary["energy"] == pytest.approx(api.energy, rel=1e-12)
    assert summary["energy"] / 2 == pytest.approx(9.2149e-4, abs=0.5e-8)  # GOAST's final energy (E/2)
    V, F = load_mesh(out)
    np.testing.assert_array_equal(F, topo.faces)
    assert np.abs(V - api.vertices).max() < 1e-12  # output in the reference's frame, float64 PLY
    err = reconstruction_errors(V, za, topo)
    assert summary["max_length_error"] == pytest.approx(err["max_length_error"], rel=1e-9)
    assert summary["max_angle_error"] == pytest.approx(err["max_angle_error"], rel=1e-9)
    assert summary["max_angle_error"] > 1e-3  # the average is not admissible


def test_encoded_npz_target_and_frame_based_method(finger, tmp_path, capsys):
    topo, X0, X1, z0, z1 = finger
    npz = tmp_path / "finger1.npz"
    code, _, stderr = run_main(capsys, "encode", shared_mesh("finger/finger1.ply"), "-o", npz)
    assert code == 0, stderr
    out = tmp_path / "out.npz"
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", shared_mesh("finger/finger0.ply"),
                                    "--target", npz, "--method", "spt", "-o", out, "--json")
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["method"] == "spt" and summary["iterations"] == 0
    assert summary["max_length_error"] < 1e-12 and summary["max_angle_error"] < 1e-11
    data = np.load(out)
    assert {"vertices", "faces", "z"} <= set(data.files)
    np.testing.assert_allclose(data["z"], z1, rtol=0, atol=1e-11)
    a = topo.faces[summary["fixed_face"], 0]
    assert np.abs(data["vertices"][a] - X0[a]).max() < 1e-12  # placed in the reference's frame


def test_weights_extrapolate(finger, tmp_path, capsys):
    topo, X0, X1, z0, z1 = finger
    out = tmp_path / "extra.obj"
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", shared_mesh("finger/finger0.ply"), "--target",
                                    shared_mesh("finger/finger0.ply"), shared_mesh("finger/finger1.ply"),
                                    "--weights", "-0.5", "1.5", "--method", "hybrid", "-o", out, "--json")
    # 10 smoothing iterations from the least-squares start leave 4 folded faces here (energy 3.2 vs 0.067 of
    # full Gauss-Newton): the result is written, but the command exits 3 and the JSON names the failure
    assert code == 3, stderr
    summary = json.loads(stdout)
    assert summary["weights"] == [-0.5, 1.5] and summary["method"] == "hybrid-lsq"
    assert not summary["success"] and summary["failure"] == "folded" and summary["checks"]["folded_faces"] >= 1
    assert "folded" in stderr
    api = reconstruct(-0.5 * z0 + 1.5 * z1, topo, X0, method="hybrid")
    assert summary["energy"] == pytest.approx(api.energy, rel=1e-9)
    assert np.all(np.isfinite(load_mesh(out)[0]))
    code, stdout, _ = run_main(capsys, "reconstruct", "--ref", shared_mesh("finger/finger0.ply"), "--target",
                               shared_mesh("finger/finger0.ply"), shared_mesh("finger/finger1.ply"),
                               "--weights", "-0.25", "1.25", "--method", "gn", "-o", out, "--json")
    summary = json.loads(stdout)
    assert code == 0 and summary["success"] and summary["failure"] == "" and summary["energy"] < 0.02  # 0.0112


def test_thin_shells_energy_and_text_output(tmp_path, capsys):
    out = tmp_path / "plate.off"
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", shared_mesh("plate/plate121_rolledA.ply"),
                                    "--target", shared_mesh("plate/plate121_rolledA.ply"),
                                    shared_mesh("plate/plate121_rolledB.ply"), "--energy", "shells",
                                    "--bending-weight", "1e-2", "-o", out)
    assert code == 0, stderr
    assert "iterations" in stdout and "(shells)" in stdout and str(out) in stdout
    V, F = load_mesh(out)
    assert V.shape == (121, 3) and np.all(np.isfinite(V))


def test_errors_exit_with_code_2(finger, tmp_path, capsys):
    ref = shared_mesh("finger/finger0.ply")
    out = tmp_path / "o.ply"
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", shared_mesh("octa/octa_src_small.ply"),
                                    "--target", shared_mesh("octa/octa_trg_small.ply"), "-o", out)
    assert code == 2 and "has 601 vertices but the reference has 600" in stderr and "Traceback" not in stderr
    assert not out.exists() and stdout == ""
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", ref, "--target", tmp_path / "missing.ply", "-o", out)
    assert code == 2 and "missing.ply" in stderr and "no such" in stderr
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", tmp_path / "nope.ply", "--target", ref, "-o", out)
    assert code == 2 and "nope.ply" in stderr
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", ref, "--target", ref, "--weights", "1", "2",
                               "-o", out)
    assert code == 2 and "got 2 weights for 1 targets" in stderr
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", ref, "--target", ref, "-o", tmp_path / "o.xyz")
    assert code == 2 and "unsupported output format '.xyz'" in stderr
    # same vertex count, other faces
    topo, X0, X1, z0, z1 = finger
    flipped = tmp_path / "flipped.ply"
    save_mesh(flipped, X1, topo.faces[:, [0, 2, 1]])
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", ref, "--target", flipped, "-o", out)
    assert code == 2 and "faces differ from the reference's (first at face 0" in stderr
    # an encoded mesh of another connectivity
    npz = tmp_path / "plate.npz"
    assert run_main(capsys, "encode", shared_mesh("plate/plate121.ply"), "-o", npz)[0] == 0
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", ref, "--target", npz, "-o", out)
    assert code == 2 and "plate.npz has 200 faces but the reference has 4088" in stderr
    bad = tmp_path / "bad.npz"
    np.savez(bad, faces=topo.faces)
    code, _, stderr = run_main(capsys, "reconstruct", "--ref", ref, "--target", bad, "-o", out)
    assert code == 2 and "not a 'lacore encode' file (missing keys edges, lengths, angles)" in stderr


def test_console_entry_point_in_a_subprocess(tmp_path):
    out = tmp_path / "o.ply"
    cmd = [sys.executable, "-m", "lacore.cli", "reconstruct", "--ref", str(shared_mesh("octa/octa_src_small.ply")),
           "--target", str(shared_mesh("octa/octa_trg_small.ply")), "-o", str(out), "--json"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "has 601 vertices" in proc.stderr and proc.stdout == ""
    cmd = [sys.executable, "-m", "lacore.cli", "reconstruct", "--ref", str(shared_mesh("simple/square4.ply")),
           "--target", str(shared_mesh("simple/square4_bent.ply")), "-o", str(out), "--json"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["success"] and summary["max_length_error"] < 1e-12 and summary["max_angle_error"] < 1e-10


def test_cone_frustum_target_is_the_closest_mesh(tmp_path, capsys):
    """A cone frustum strip's lengths with all angles 0 (no mesh's): Gauss-Newton's success is reported as the
    closest mesh, with the reason; a tree walk fails and names the hole its frames do not close around."""
    from lacore.samples.surfaces import cone_strip
    faces, z = cone_strip()
    topo = MeshTopology.from_faces(faces)
    phi = 2 * np.pi * np.arange(24) / 24
    X = np.concatenate([np.stack([r * np.cos(phi + 0.5 * t), r * np.sin(phi + 0.5 * t), np.full(24, t)], 1)
                        for t, r in ((0.0, 1.0), (1.0, 2.0))])
    save_mesh(tmp_path / "cone.ply", X, faces)
    E = topo.n_edges
    np.savez(tmp_path / "flat.npz", faces=faces, edges=topo.edges, lengths=z[:E], angles=z[E:])
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", tmp_path / "cone.ply", "--target",
                                    tmp_path / "flat.npz", "-o", tmp_path / "out.ply", "--json")
    s = json.loads(stdout)
    assert code == 0 and s["success"] and s["checks"]["outcome"] == "closest", stderr
    assert s["checks"]["target_integrable"] is False and "around a hole" in s["checks"]["target"]
    assert "the closest mesh: the target is not integrable around a hole" in s["message"]
    code, stdout, _ = run_main(capsys, "reconstruct", "--ref", tmp_path / "cone.ply", "--target",
                               tmp_path / "flat.npz", "-o", tmp_path / "out.ply")
    assert code == 0 and "the closest mesh" in stdout
    code, stdout, stderr = run_main(capsys, "reconstruct", "--ref", tmp_path / "cone.ply", "--target",
                                    tmp_path / "flat.npz", "--method", "bfs", "-o", tmp_path / "bfs.ply")
    assert code == 3 and "hole 0 (boundary loop 1, 24 edges): the frames turn by 1.89 rad" in stderr
