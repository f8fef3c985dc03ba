"""``lacore fit``: shape model + markers file -> poses file; bad input exits 2 and writes nothing."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO

from lacore.cli import main
from lacore.markers import FIT_DEFAULTS
from lacore.markers.binding import MarkerBinding, surface_points
from lacore.samples.bar import bar_mesh, bar_pose
from lacore.models.shape_model import ShapeModel


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fit")
    X0, F = bar_mesh(n_along=12)
    train = np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 3) for tw in np.linspace(-1, 1, 3)])
    model = ShapeModel.fit(train, F, n_modes=3)
    model.save(d / "model.npz")
    rng = np.random.default_rng(0)
    verts = rng.choice(len(X0), 16, replace=False)
    true = np.array([bar_pose(X0, 0.5 * s, 0.3 * s) for s in np.linspace(0, 1, 4)])
    x = surface_points(true, F, MarkerBinding.from_vertices(verts, F, offsets=0.05))
    x[1, :3] = np.nan
    np.savez(d / "markers.npz", positions=x, vertices=verts, offsets=np.full(16, 0.05))
    return d, model, true, verts, x


def _run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_fit_writes_poses_and_json(files, capsys):
    d, model, true, verts, x = files
    out = d / "out.npz"
    code, stdout, err = _run(["fit", str(d / "model.npz"), "--markers", str(d / "markers.npz"), "-o", str(out),
                              "--json", "--temporal-weight", "0.1"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["penetration_weight"] == FIT_DEFAULTS.penetration_weight == 10.0   # the default
    assert summary["temporal_weight"] == 0.1   # the flag
    assert summary["observed_radius"] == [0.1, 0.2]
    assert summary["frames"] == 4 and summary["seconds"] > 0 and summary["seconds_per_frame"] > 0
    assert summary["marker_rms"] < 0.01  # bar length 6; measured 0.0017
    with np.load(out) as r:
        assert r["vertices"].shape == (4, model.topology.n_vertices, 3)
        assert np.array_equal(r["faces"], model.faces)
        assert r["coefficients"].shape == (4, 3) and r["marker_residuals"].shape == (4, 16, 3)
        assert np.isnan(r["marker_residuals"][1, :3]).all()
        assert np.linalg.norm(r["vertices"] - true, axis=2).mean() < 0.02  # measured 0.004
    # surface bindings give the same result
    b = MarkerBinding.from_vertices(verts, model.faces, offsets=0.05)
    np.savez(d / "markers_surface.npz", positions=x, faces=b.faces, barycentric=b.barycentric, offsets=b.offsets)
    out2 = d / "out2.npz"
    code, _, err = _run(["fit", str(d / "model.npz"), "--markers", str(d / "markers_surface.npz"), "-o", str(out2),
                         "--temporal-weight", "0.1"], capsys)
    assert code == 0, err
    with np.load(out) as r1, np.load(out2) as r2:
        assert np.abs(r1["vertices"] - r2["vertices"]).max() < 1e-9


@pytest.mark.parametrize("case, message", [
    ("count", "markers, the binding"),
    ("range", "out of range"),
    ("nothing", "bound to nothing"),
    ("nobinding", "binds the markers to nothing"),
    ("shape", "positions must have shape (T, M, 3)"),
    ("weight", "--prior-weight"),
    ("penetration", "--penetration-weight"),
    ("radius", "--observed-radius"),
    ("model", "not a readable"),
    ("take_options", "--frames, --units are for a take (.c3d or .trc): a markers .npz is fitted whole"),
    ("output_is_input", "is the input"),
    # positions in millimetres for a model in metres: used to be fitted "converged" with a marker RMS 100 times
    # the bar's size
    ("millimetres", "times as far apart as the points they are bound to"),
    ("kilometres", "times as far apart as the points they are bound to"),
])
def test_bad_input_exits_2_without_output(files, capsys, case, message):
    d, model, true, verts, x = files
    markers = d / f"bad_{case}.npz"
    model_file = d / "model.npz"
    extra = []
    if case == "count":
        np.savez(markers, positions=x[:, :15], vertices=verts)
    elif case == "range":
        np.savez(markers, positions=x, vertices=np.r_[verts[:-1], 10 ** 6])
    elif case == "nothing":
        np.savez(markers, positions=x, vertices=np.r_[verts[:-1], -1])
    elif case == "nobinding":
        np.savez(markers, positions=x)
    elif case == "shape":
        np.savez(markers, positions=x[:, :, :2], vertices=verts)
    elif case == "weight":
        np.savez(markers, positions=x, vertices=verts)
        extra = ["--prior-weight", "-1"]
    elif case == "penetration":
        np.savez(markers, positions=x, vertices=verts)
        extra = ["--penetration-weight", "nan"]
    elif case == "radius":
        np.savez(markers, positions=x, vertices=verts)
        extra = ["--observed-radius", "0.3", "0.1"]
    elif case == "model":
        np.savez(markers, positions=x, vertices=verts)
        model_file = d / "not_a_model.npz"
        model_file.write_bytes(b"garbage")
    elif case in ("millimetres", "kilometres"):
        np.savez(markers, positions=x * (1e3 if case == "millimetres" else 1e-3), vertices=verts)
    elif case == "take_options":
        np.savez(markers, positions=x, vertices=verts)
        extra = ["--frames", "0:2", "--units", "mm"]
    out = d / f"out_{case}.npz"
    if case == "output_is_input":
        np.savez(markers, positions=x, vertices=verts)
        out = markers
    code, stdout, err = _run(["fit", str(model_file), "--markers", str(markers), "-o", str(out)] + extra, capsys)
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() or case == "output_is_input"
    assert not [p for p in d.iterdir() if p.name.startswith(".tmp-fit-")]


def test_console_script_runs(files):
    d, *_ = files
    r = subprocess.run([sys.executable, "-m", "lacore.cli", "fit", str(d / "model.npz"), "--markers",
                        str(d / "markers.npz"), "-o", str(d / "cli.npz"), "--json"], capture_output=True, text=True,
                       cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert set(json.loads(r.stdout)) >= {"frames", "seconds", "seconds_per_frame", "marker_rms"}


def test_take_options_reach_the_fit(files, capsys, monkeypatch):
    """--prior-weight, --temporal-weight and --penetration-weight are the options fit_take gets for a take."""
    import lacore.cli.fit as cli_fit
    from lacore.errors import InputError

    d, *_ = files
    seen = {}

    def fake_fit_take(model, take, options=None, **kw):
        seen["options"] = options
        raise InputError("stop here")

    monkeypatch.setattr(cli_fit, "read_take", lambda path, units=None: path)
    monkeypatch.setattr(cli_fit, "fit_take", fake_fit_take)
    code, _, err = _run(["fit", str(d / "model.npz"), "--markers", str(d / "take.c3d"), "-o", str(d / "t.npz"),
                         "--prior-weight", "0.5", "--temporal-weight", "3", "--penetration-weight", "2"], capsys)
    assert code == 2 and "stop here" in err
    o = seen["options"]
    assert (o.prior_weight, o.temporal_weight, o.penetration_weight) == (0.5, 3.0, 2.0)
    assert o.observed_radius == FIT_DEFAULTS.observed_radius == (0.1, 0.2)            # the default
    for flag, radius in ((["0"], None), (["0.2", "0.4"], (0.2, 0.4))):
        code, _, err = _run(["fit", str(d / "model.npz"), "--markers", str(d / "take.c3d"), "-o", str(d / "t.npz"),
                             "--observed-radius", *flag], capsys)
        assert code == 2 and "stop here" in err and seen["options"].observed_radius == radius, err


@pytest.mark.parametrize("extra, message", [
    (["--units", "furlongs"], "--units must be a length unit (mm, cm, dm, m, in, ft), got 'furlongs'"),
    (["--frames", "5:2"], "--frames 5:2 selects no frame of"),
])
def test_bad_take_option_names_the_option(files, capsys, extra, message):
    """A take option with a bad value is one line naming the option and its value (not the library's keyword)."""
    from lacore.markers.io import MarkerTake, write_trc

    d, *_ = files
    positions = np.broadcast_to(np.eye(3)[None], (4, 3, 3)).copy()
    write_trc(d / "small.trc", MarkerTake(labels=("A", "B", "C"), positions=positions, rate=60.0), units="mm")
    out = d / "out_take_option.npz"
    code, _, err = _run(["fit", str(d / "model.npz"), "--markers", str(d / "small.trc"), "-o", str(out), *extra],
                        capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_help_lists_the_units():
    from lacore.cli.fit import KNOWN_UNITS
    from lacore.markers.io import UNIT_SCALES
    assert all(u in UNIT_SCALES for u in KNOWN_UNITS.split(", "))
    r = subprocess.run([sys.executable, "-m", "lacore.cli", "fit", "--help"], capture_output=True, text=True, cwd=REPO)
    assert "mm, cm, dm, m, in, ft" in " ".join(r.stdout.split()), r.stdout
