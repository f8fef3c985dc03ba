"""Settings dataclasses (one place for every default) and the common result base type."""

import json
from dataclasses import FrozenInstanceError

import numpy as np
import pytest
import trimesh
from conftest import shared_mesh

from lacore.errors import InputError, MeshError
from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.reconstruction import (GaussNewtonOptions, HybridOptions, ReconstructionResult, ReconstructionSettings,
                                   get_context, reconstruct, tree_kind)
from lacore.reconstruction.gauss_newton import run_gauss_newton
from lacore.reconstruction.result import GaussNewtonResult
from lacore.reconstruction.settings import ReconstructionSetup, split_options
from lacore.result import SolverResult
from lacore.geometry.topology import MeshTopology


@pytest.fixture(scope="module")
def plates():
    meshes = [trimesh.load(shared_mesh(f"plate/plate121_rolled{s}.ply"), process=False) for s in "AB"]
    topo = MeshTopology.from_faces(np.asarray(meshes[0].faces), n_vertices=len(meshes[0].vertices))
    XA, XB = (np.asarray(m.vertices, float) for m in meshes)
    return topo, XA, XB


def test_settings_are_frozen_validated_and_hashable():
    s = ReconstructionSettings(fixed_face=[3, 7], bending_weight=1)
    assert s.fixed_face == (3, 7) and s.bending_weight == 1.0 and isinstance(s.bending_weight, float)
    assert hash(s) == hash(ReconstructionSettings(fixed_face=(3, 7), bending_weight=1e0))
    with pytest.raises(FrozenInstanceError):
        s.energy = "shells"
    for bad, match in [({"energy": "elastic"}, "unknown energy 'elastic'"), ({"weights": "x"}, "unknown weights"),
                       ({"bending_weight": -1.0}, "bending_weight"), ({"solver": "umfpack"}, "unknown solver")]:
        with pytest.raises(InputError, match=match):
            ReconstructionSettings(**bad)
    with pytest.raises(MeshError, match="fixed_face must be a face index"):
        ReconstructionSettings(fixed_face=[0.5])
    with pytest.raises(InputError, match="pcg_rtol"):
        GaussNewtonOptions(pcg_rtol=1.0)
    with pytest.raises(InputError, match="hybrid_start"):
        HybridOptions(start="bfs")
    with pytest.raises(InputError, match="smoothing_iterations"):
        HybridOptions(smoothing_iterations=-1)


def test_split_options_maps_the_keywords_to_one_named_bundle():
    setup = split_options({"energy": "shells", "max_iterations": 7, "hybrid_start": "tree", "hybrid_kind": "spt",
                           "smoothing_iterations": 3})
    assert isinstance(setup, ReconstructionSetup)
    assert setup.settings == ReconstructionSettings(energy="shells")
    assert setup.options == GaussNewtonOptions(max_iterations=7)
    assert setup.hybrid == HybridOptions(start="tree", kind="spt", smoothing_iterations=3)
    settings, options, hybrid = setup  # unpacks in field order
    assert (settings, options, hybrid) == (setup.settings, setup.options, setup.hybrid)
    assert ReconstructionSetup() == (ReconstructionSettings(), GaussNewtonOptions(), HybridOptions())
    # keywords override the objects' fields
    setup = split_options({"ftol": 1e-3}, ReconstructionSettings(bending_weight=0.1),
                          GaussNewtonOptions(max_iterations=5))
    assert setup.options == GaussNewtonOptions(max_iterations=5, ftol=1e-3) and setup.settings.bending_weight == 0.1
    with pytest.raises(TypeError, match=r"unknown options \['tolerance'\]"):
        split_options({"tolerance": 1})


def test_every_default_comes_from_one_place():
    import inspect

    from lacore.energies import DEFAULT_BENDING_WEIGHT, DEFAULT_WEIGHTS, QuadraticEnergy, ThinShellsEnergy, \
        quadratic_weights

    s = ReconstructionSettings()
    assert (s.weights, s.bending_weight) == (DEFAULT_WEIGHTS, DEFAULT_BENDING_WEIGHT)
    for func, name, value in [(QuadraticEnergy, "weights", DEFAULT_WEIGHTS),
                              (QuadraticEnergy, "bending_weight", DEFAULT_BENDING_WEIGHT),
                              (ThinShellsEnergy, "bending_weight", DEFAULT_BENDING_WEIGHT),
                              (quadratic_weights, "scheme", DEFAULT_WEIGHTS)]:
        assert inspect.signature(func).parameters[name].default is value
    # the consumers above the reconstruction take the settings objects, not their fields
    from lacore.models.shape_model import ShapeModel
    from lacore.multiresolution import MultiresolutionReconstruction
    from lacore.shapes.geodesics import discrete_geodesic, projected_linear_path
    from lacore.shapes.path_energy import default_energy

    for func in (discrete_geodesic, default_energy, projected_linear_path, MultiresolutionReconstruction,
                 ShapeModel.fit_z):
        params = inspect.signature(func).parameters
        assert "settings" in params and not {"bending_weight", "weights", "solver"} & set(params), func
    params = inspect.signature(ShapeModel.synthesize).parameters  # the model's own settings, options objects
    assert "options" in params and all(p.kind != p.VAR_KEYWORD for p in params.values())


def test_an_explicitly_given_default_counts_as_given(plates):
    topo, XA, XB = plates
    z = lengths_and_angles(XB, topo)
    ctx = get_context(topo, XA, ReconstructionSettings(bending_weight=1e-2))
    # a settings object gives all its fields, also those at their default
    with pytest.raises(InputError, match="bending_weight=0.001 differs from the context's 0.01"):
        reconstruct(z, topo, XA, context=ctx, settings=ReconstructionSettings())
    with pytest.raises(InputError, match="bending_weight=0.001 differs from the context's 0.01"):
        reconstruct(z, topo, XA, context=ctx, bending_weight=1e-3)
    shells = get_context(topo, XA, ReconstructionSettings(energy="shells", bending_weight=1e-2))
    with pytest.raises(InputError, match="energy='quadratic' differs from the context's 'shells'"):
        reconstruct(z, topo, XA, context=shells, settings=ReconstructionSettings(bending_weight=1e-2))
    # settings that match, with automatic fixed face and solver, are accepted; none given: the context's
    same = ReconstructionSettings(bending_weight=1e-2)
    a = reconstruct(z, topo, XA, context=ctx, settings=same, max_iterations=2)
    b = reconstruct(z, topo, XA, context=ctx, max_iterations=2)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    with pytest.raises(TypeError, match=r"get_context\(\) got unknown options \['ftol'\]; settings are"):
        get_context(topo, XA, ftol=1e-3)


def test_tree_kind_builds_no_tree_for_the_least_squares_hybrid():
    assert tree_kind("gn") is None and tree_kind("lsq") is None
    assert tree_kind("hybrid") is None                      # default start: the least-squares relaxation
    assert tree_kind("hybrid", HybridOptions(start="tree", kind="bfs")) == "bfs"
    assert [tree_kind(k) for k in ("bfs", "mst", "spt")] == ["bfs", "mst", "spt"]


def test_settings_objects_and_keywords_give_the_same_reconstruction(plates):
    topo, XA, XB = plates
    z = 0.5 * (lengths_and_angles(XA, topo) + lengths_and_angles(XB, topo))
    a = reconstruct(z, topo, XA, settings=ReconstructionSettings(bending_weight=1e-2),
                    options=GaussNewtonOptions(max_iterations=4))
    b = reconstruct(z, topo, XA, bending_weight=1e-2, max_iterations=4)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    assert a.iterations == b.iterations == 4 and a.status == 0 and not a.success
    # a context carries its settings; explicit settings that differ are refused
    ctx = get_context(topo, XA, ReconstructionSettings(bending_weight=1e-2))
    assert ctx is get_context(topo, XA, bending_weight=1e-2) and ctx.bending_weight == 1e-2
    with pytest.raises(InputError, match="bending_weight=0.1 differs from the context's 0.01"):
        reconstruct(z, topo, XA, context=ctx, bending_weight=0.1)


def test_hybrid_result_is_complete_and_consistent(plates):
    """The smoothing budget is not a failure: status 6 (not 0 'iteration limit') with success=True."""
    topo, XA, XB = plates
    z = 0.5 * (lengths_and_angles(XA, topo) + lengths_and_angles(XB, topo))
    res = reconstruct(z, topo, XA, method="hybrid", hybrid=HybridOptions(smoothing_iterations=2))
    assert isinstance(res, ReconstructionResult) and isinstance(res, SolverResult)
    assert res.iterations == 2 and res.status == 6 and res.success
    # an average of two shapes is no mesh's lengths and angles: the result approximates the closest mesh
    assert res.message.startswith("2 smoothing iterations done; an approximation of the closest mesh (2 budgeted "
                                  "iterations): the target is not integrable at a vertex")
    assert res.checks["outcome"] == "closest" and res.checks["target_integrable"] is False
    assert res.method == "hybrid-lsq" and {"least_squares", "total", "initialization"} <= set(res.timings)
    assert res.timings["total"] >= res.timings["least_squares"] + res.timings["factorization"]
    summary = res.summary()
    json.dumps(summary, allow_nan=False)
    assert "vertices" not in summary and summary["status"] == 6 and summary["iterations"] == 2
    assert res["energy"] == res.energy and "energy_history" in res.keys() and res.get("nope", 7) == 7
    with pytest.raises(KeyError, match="nope"):
        res["nope"]


def test_run_gauss_newton_returns_a_result_object(plates):
    topo, XA, XB = plates
    ctx = get_context(topo, XA)
    out = run_gauss_newton(ctx.objective(lengths_and_angles(XB, topo)), ctx.to_canonical(XA), ctx,
                           GaussNewtonOptions(max_iterations=3))
    assert isinstance(out, GaussNewtonResult) and out.x.shape == XA.shape
    assert out.iterations == len(out.step_sizes) == len(out.energy_history) - 1 <= 3
    assert out.energy < out.initial_energy and out.success == (out.status > 0)
    assert "x" not in out.summary()


def test_hybrid_nearest_start_iterations():
    from lacore.errors import InputError
    from lacore.reconstruction import HybridOptions

    assert HybridOptions().nearest_start_iterations is None
    h = HybridOptions(start="given", smoothing_iterations=1, nearest_start_iterations=3.0)
    assert h.nearest_start_iterations == 3 and isinstance(h.nearest_start_iterations, int)
    with pytest.raises(InputError, match="nearest_start_iterations must be a non-negative integer"):
        HybridOptions(nearest_start_iterations=-1)
    with pytest.raises(InputError, match="unknown hybrid_start 'warm'; use one of lsq, tree, given"):
        HybridOptions(start="warm")


def test_fit_weights_beyond_a_million_are_refused_by_the_library():
    """Absurd but finite fit weights (prior_weight=1e308 made the fit's system unsolvable) are refused by the options
    in one line naming the range; the CLI takes its limit (lacore.errors.MAX_WEIGHT) from there."""
    from lacore.markers.fitting import fit_options

    for n in ("prior_weight", "temporal_weight", "penetration_weight", "compression_weight", "coefficient_weight"):
        fit_options(**{n: 1e6})                                              # the largest weight taken
        for bad in (1e308, 2e6, -1.0, float("nan"), float("inf")):
            with pytest.raises(InputError, match=rf"{n} must be a number in [\[(]0, 1e\+06\], got "):
                fit_options(**{n: bad})
    with pytest.raises(InputError, match=r"prior_weight must be a number in \(0, 1e\+06\], got 0"):
        fit_options(prior_weight=0.0)
