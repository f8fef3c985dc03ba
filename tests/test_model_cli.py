"""`lacore model` and `lacore model-sweep`: JSON summary, model file, sweep PLYs, bad input (exit code 2, no output)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, shared_mesh

from lacore.cli import SUBCOMMANDS, main
from lacore.io.meshes import load_mesh, save_mesh
from lacore.geometry.rigid import rigid_rms
from lacore.samples.bar import bar_family
from lacore.models.shape_model import DEFAULT_BENDING_WEIGHT, DEFAULT_TANGENT, ShapeModel
from lacore.reconstruction import ReconstructionSettings

STAGES = {"mean", "tangent_decomposition", "tangent_solves", "gram", "eigen"}


def run_main(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def bar_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bars")
    poses, faces, _ = bar_family(np.linspace(0, 0.3, 3), np.linspace(0, 0.1, 3))
    paths = []
    for i, X in enumerate(poses):
        paths.append(folder / f"bar{i}.ply")
        save_mesh(paths[-1], X, faces)
    return paths, poses, faces


def test_registered():
    assert {"model", "model-sweep"} <= set(SUBCOMMANDS)


@pytest.mark.parametrize("tangent", ["ambient", "projected"])
def test_model_json_and_file(capsys, tmp_path, bar_files, tangent):
    paths, poses, faces = bar_files
    out = tmp_path / "m.npz"
    code, stdout, err = run_main(capsys, "model", *paths, "-o", out, "--modes", 3, "--tangent", tangent,
                                 "--bending-weight", 0.01, "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["vertices"] == poses.shape[1] and summary["samples"] == 9 and summary["modes"] == 3
    assert summary["tangent"] == tangent and summary["bending_weight"] == 0.01
    ev = summary["explained_variance"]
    assert len(ev) == 3 and ev[0] >= ev[1] >= ev[2] > 0 and sum(ev[:2]) > 0.999
    assert STAGES <= set(summary["stages"]) and summary["seconds"] > 0
    assert (summary["stages"]["tangent_solves"] > 0) == (tangent == "projected")
    model = ShapeModel.load(out, faces=faces)
    direct = ShapeModel.fit(poses, faces, n_modes=3, tangent=tangent,
                            settings=ReconstructionSettings(bending_weight=0.01))
    assert np.abs(model.modes - direct.modes).max() < 1e-9
    np.testing.assert_allclose(model.explained_variance_ratio, ev, rtol=1e-12)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_sweep_writes_plys(capsys, tmp_path, bar_files):
    paths, poses, faces = bar_files
    model_path = tmp_path / "m.npz"
    assert run_main(capsys, "model", *paths, "-o", model_path, "--modes", 2)[0] == 0
    prefix = tmp_path / "sweep"
    code, stdout, err = run_main(capsys, "model-sweep", model_path, "--mode", 1, "--range", -2, 2, "--frames", 5,
                                 "-o", prefix, "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    files = [o["file"] for o in summary["outputs"]]
    assert files == [f"{prefix}_{i:03d}.ply" for i in range(5)]
    model = ShapeModel.load(model_path)
    np.testing.assert_allclose([o["t"] for o in summary["outputs"]], [-2, -1, 0, 1, 2])
    sd = model.standard_deviations[1]
    X = np.stack([load_mesh(f)[0] for f in files])
    assert rigid_rms(X[2], model.mean_vertices) < 1e-9
    c = model.coefficients(X, tangent="ambient")
    np.testing.assert_allclose(c[:, 1], np.array([-2, -1, 0, 1, 2]) * sd, atol=0.05 * sd)
    assert np.abs(c[:, 0]).max() < 0.05 * model.standard_deviations[0]
    # -o with a mesh extension sets the format (not sweep.obj_000.ply)
    code, _, err = run_main(capsys, "model-sweep", model_path, "--mode", 0, "--frames", 2, "-o", tmp_path / "s.obj")
    assert code == 0 and (tmp_path / "s_000.obj").exists() and (tmp_path / "s_001.obj").exists(), err
    # every mesh format lacore reads, STL included (the formats of lacore interpolate)
    code, _, err = run_main(capsys, "model-sweep", model_path, "--mode", 0, "--frames", 2, "-o", tmp_path / "t",
                            "--format", "stl")
    assert code == 0 and load_mesh(tmp_path / "t_001.stl")[0].shape == X[0].shape, err


def test_bad_input_exit_2_without_output(capsys, tmp_path, bar_files):
    paths, _, _ = bar_files
    out = tmp_path / "m.npz"
    cases = [
        (["model", paths[0], "-o", out], "at least 2 training meshes, got 1"),
        (["model", paths[0], shared_mesh("sphere/defSphere0.ply"), "-o", out], "is not in dense correspondence with"),
        (["model", *paths[:3], "-o", out, "--modes", 3], "--modes 3 is larger than N - 1 = 2 for 3 training meshes"),
        (["model", *paths[:3], "-o", tmp_path / "no" / "m.npz"], "m.npz: its folder does not exist"),
        (["model", paths[0], tmp_path / "missing.ply", "-o", out], "missing.ply"),
    ]
    for argv, message in cases:
        code, stdout, err = run_main(capsys, *argv)
        assert code == 2, (argv, err)
        assert message in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 truncated zip")
    code, _, err = run_main(capsys, "model-sweep", corrupt, "--mode", 0, "-o", tmp_path / "s")
    assert code == 2 and "not a readable .npz shape model" in err and len(err.strip().splitlines()) == 1
    assert run_main(capsys, "model", *paths[:4], "-o", out, "--modes", 2)[0] == 0
    code, _, err = run_main(capsys, "model-sweep", out, "--mode", 2, "-o", tmp_path / "s")
    assert code == 2 and "--mode 2 is not a mode of the model (0 to 1)" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corrupt.npz", "m.npz"]


def test_console_script_subprocess(tmp_path, bar_files):
    paths, _, _ = bar_files
    proc = subprocess.run([sys.executable, "-m", "lacore.cli", "model", *map(str, paths[:4]), "-o",
                           str(tmp_path / "m.npz"), "--json"], capture_output=True, text=True, cwd=REPO,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["modes"] == 3
    assert (summary["tangent"], summary["bending_weight"]) == (DEFAULT_TANGENT, DEFAULT_BENDING_WEIGHT) == (
        "ambient", 0.005)


def test_model_localize_option(capsys, tmp_path, bar_files):
    paths, poses, faces = bar_files
    out = tmp_path / "loc.npz"
    code, stdout, err = run_main(capsys, "model", *paths, "-o", out, "--modes", 2, "--localize", "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["localized"] is True and summary["stages"]["localize"] > 0
    loaded = ShapeModel.load(out)
    expected = ShapeModel.fit(poses, faces, n_modes=2).localized()  # the CLI's defaults are the library's
    assert np.abs(loaded.modes - expected.modes).max() < 1e-8
