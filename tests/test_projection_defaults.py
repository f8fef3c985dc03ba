"""Issue 18, defaults: one projection preset (lacore.reconstruction.settings.DEFAULT_PROJECTION, Fast) is the
default of ``lacore interpolate``, of the interpolation functions and of the add-on's Fast
(tests/blender/check_interpolate.py checks the add-on's table); its smoothing budget is extended where a step
does not agree with its quadratic model (a blend far from admissible), so the default stays near Gauss-Newton."""

import inspect
import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import load_topology, shared_mesh

from lacore.cli import main
from lacore.io.meshes import load_mesh
from lacore.reconstruction.settings import DEFAULT_PROJECTION, FAST, PROJECTION_PRESETS, projection_preset
from lacore.shapes.interpolation import interpolate, keyframe_inbetweens, project_targets


def test_the_default_projection_is_the_fast_preset():
    assert DEFAULT_PROJECTION is FAST and PROJECTION_PRESETS["fast"] is FAST
    assert FAST.method == "hybrid" and FAST.hybrid.start == "given" and FAST.hybrid.smoothing_iterations == 1
    assert FAST.hybrid.extend_smoothing and FAST.options.ftol == 1e-4
    assert projection_preset(None) == projection_preset("fast") == (FAST.method, FAST.options, FAST.hybrid)
    assert projection_preset("gn") == ("gn", None, None)
    for fn in (interpolate, keyframe_inbetweens, project_targets):
        assert inspect.signature(fn).parameters["method"].default is None, fn.__name__


def test_cli_default_is_the_library_default(tmp_path, capsys):
    """``lacore interpolate`` without --method gives the frames of ``interpolate()`` without a method."""
    a, b = shared_mesh("finger/finger0.ply"), shared_mesh("finger/finger1.ply")
    X0, topo = load_topology("finger/finger0.ply")
    X1, _ = load_topology("finger/finger1.ply")
    ts = [0.25, 0.5, 1.5]
    code = main(["interpolate", str(a), str(b), "--t", *map(str, ts), "-o", str(tmp_path / "f"), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["success"] and summary["method"] == DEFAULT_PROJECTION.name
    lib = interpolate([X0, X1], topo, ts)
    assert lib.method == FAST.method
    for i, o in enumerate(summary["outputs"]):
        assert o["iterations"] == lib.iterations[i] and o["energy"] == pytest.approx(lib.energy[i], rel=1e-12)
        assert np.abs(load_mesh(o["file"])[0] - lib.vertices[i]).max() < 1e-12
    code = main(["interpolate", str(a), str(b), "--t", "0.5", "--method", "gn", "--max-iterations", "50",
                 "-o", str(tmp_path / "g"), "--json"])
    summary = json.loads(capsys.readouterr().out)
    gn = interpolate([X0, X1], topo, [0.5], method="gn")
    assert code == 0 and summary["method"] == "gn" and summary["outputs"][0]["iterations"] == gn.iterations[0]


def test_the_default_extends_its_budget_on_a_blend_far_from_admissible():
    """plate121 rolled one way -> rolled the other way, ten in-betweens: the steps recover ~40 % of what their
    Gauss-Newton model predicts, so the budget of one step is extended; without the extension (the add-on's Fast
    before) frames ended at up to 49x Gauss-Newton's energy, reported as success."""
    XA, topo = load_topology("plate/plate121_rolledA.ply")
    XB, _ = load_topology("plate/plate121_rolledB.ply")
    ts = np.arange(1, 11) / 11
    gn = interpolate([XA, XB], topo, ts, method="gn")
    fast = interpolate([XA, XB], topo, ts)
    before = interpolate([XA, XB], topo, ts, hybrid=replace(FAST.hybrid, extend_smoothing=False))
    assert gn.success and fast.success
    assert np.max(fast.energy / gn.energy - 1) < 2e-3  # measured 1.1e-4
    assert np.max(before.energy / gn.energy - 1) > 10  # measured 48.7
    assert fast.total_iterations > before.total_iterations  # measured 35 against 26 (gn: 61)


def test_the_extension_keeps_one_step_on_smooth_motions():
    """The finger pair: every budgeted step agrees with its model, so the default takes exactly the steps of the
    budget (the first frame after the key: 2 of 3, then 1) -- the same frames as without the extension."""
    X0, topo = load_topology("finger/finger0.ply")
    X1, _ = load_topology("finger/finger1.ply")
    ts = np.arange(1, 11) / 11
    fast = interpolate([X0, X1], topo, ts)
    before = interpolate([X0, X1], topo, ts, hybrid=replace(FAST.hybrid, extend_smoothing=False))
    assert fast.iterations.tolist() == before.iterations.tolist() == [2] + [1] * 9
    assert np.array_equal(fast.vertices, before.vertices)
