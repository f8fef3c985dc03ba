"""Absurd but finite option values (1e308...) exit 2 with one line naming the option and its range, and write
nothing; values at the edge of the range still run."""

import re

import numpy as np
import pytest

from lacore.cli import main
from lacore.cli.common import MAX_WEIGHT
from lacore.cli.mixer import MAX_MIX_RANGE
from lacore.io.meshes import save_mesh
from lacore.markers.binding import MarkerBinding, surface_points
from lacore.models.shape_model import ShapeModel
from lacore.samples.bar import bar_mesh, bar_pose


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("ranges")
    X0, F = bar_mesh(n_along=12)
    train = np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 3) for tw in np.linspace(-1, 1, 3)])
    ShapeModel.fit(train, F, n_modes=3).save(d / "model.npz")
    verts = np.random.default_rng(0).choice(len(X0), 16, replace=False)
    true = np.array([bar_pose(X0, 0.5 * s, 0.3 * s) for s in np.linspace(0, 1, 4)])
    x = surface_points(true, F, MarkerBinding.from_vertices(verts, F, offsets=0.05))
    np.savez(d / "markers.npz", positions=x, vertices=verts, offsets=np.full(16, 0.05))
    save_mesh(d / "a.ply", train[0], F)
    save_mesh(d / "b.ply", train[8], F)
    return d


def _argv(d, command, out):
    return {"fit": ["fit", d / "model.npz", "--markers", d / "markers.npz", "-o", out],
            "mixer": ["mixer", d / "a.ply", d / "b.ply", "-o", out],
            "interpolate": ["interpolate", d / "a.ply", d / "b.ply", "--t", "0.5", "-o", out],
            "reconstruct": ["reconstruct", "--ref", d / "a.ply", "--target", d / "b.ply", "-o", out],
            "model": ["model", d / "a.ply", d / "b.ply", "-o", out]}[command]


@pytest.mark.parametrize("command, option, values, message", [
    # before: exit 3 (the linear system could not be solved), the failed result written
    ("fit", "--prior-weight", ["1e308"], r"--prior-weight must be a number in \(0, 1e\+06\], got 1e\+308"),
    ("fit", "--prior-weight", ["2e6"], r"--prior-weight must be a number in \(0, 1e\+06\], got 2e\+06"),
    # before: exit 2 blaming the rate ("rate 120 frames per second overflows the temporal weight")
    ("fit", "--temporal-weight", ["1e308", "--rate", "120"],
     r"--temporal-weight must be a number in \[0, 1e\+06\], got 1e\+308"),
    # before: exit 0
    ("fit", "--penetration-weight", ["1e308"], r"--penetration-weight must be a number in \[0, 1e\+06\], got 1e\+308"),
    # before: exit 2 with "vertices has NaN or infinite coordinates", no option named
    ("mixer", "--range", ["0", "1e308"], r"--range must be a number in \[-1000, 1000\], got 1e\+308"),
    ("mixer", "--range", ["-1e308", "1"], r"--range must be a number in \[-1000, 1000\], got -1e\+308"),
    # before: a traceback (ValueError: the matrix has NaN or infinite entries)
    ("interpolate", "--bending-weight", ["1e300"], r"argument --bending-weight: must be a number in \[0, 1e\+06\], "
                                                   r"got 1e\+300"),
    ("model", "--bending-weight", ["1e300"], r"argument --bending-weight: must be a number in \[0, 1e\+06\]"),
    # before: exit 0, a result written
    ("reconstruct", "--bending-weight", ["1e300"], r"argument --bending-weight: must be a number in \[0, 1e\+06\]"),
])
def test_absurd_option_values_exit_2_naming_the_option(files, tmp_path, capsys, command, option, values, message):
    out = tmp_path / {"interpolate": "out", "reconstruct": "out.ply"}.get(command, "out.npz")
    code = _run([str(a) for a in _argv(files, command, out)] + [option] + values)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert re.search(message, err), err
    assert list(tmp_path.iterdir()) == []


def _run(argv):
    """main's exit code, also where argparse rejects the value (SystemExit)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def test_weights_at_the_limit_still_run(files, tmp_path, capsys):
    out = tmp_path / "out.npz"
    argv = [str(a) for a in _argv(files, "fit", out)]
    code = main(argv + ["--prior-weight", f"{MAX_WEIGHT:g}", "--penetration-weight", f"{MAX_WEIGHT:g}"])
    assert code == 0, capsys.readouterr().err
    with np.load(out) as r:
        assert np.isfinite(r["vertices"]).all()
    code = main([str(a) for a in _argv(files, "mixer", tmp_path / "m.npz")] + ["--range", f"{-MAX_MIX_RANGE:g}",
                                                                             f"{MAX_MIX_RANGE:g}"])
    assert code == 0, capsys.readouterr().err
