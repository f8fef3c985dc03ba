"""In-betweens by a reduced model of the path between two keys (lacore.shapes.mixing.path)."""

import numpy as np
import pytest

from lacore import MeshTopology, interpolate, keyframe_inbetweens, lengths_and_angles, reconstruct
from lacore.errors import InputError
from lacore.geometry.rigid import rigid_rms
from lacore.reconstruction import get_context
from lacore.samples.bar import bar_mesh, bar_pose
from lacore.shapes.mixing import blend_targets
from lacore.shapes.mixing.path import SAFETY, PathOptions, path_inbetweens
from lacore.shapes.mixing.subspace import FullProblem

FACTORS = np.arange(1, 11) / 11


@pytest.fixture(scope="module")
def bar():
    X, F = bar_mesh(n_along=24, n_side=3)
    return X, F, MeshTopology.from_faces(F)


def _diag(X):
    return float(np.linalg.norm(np.ptp(X, axis=0)))


def _gauss_newton(A, B, topo, factors):
    """Converged full Gauss-Newton projections of the blend (A's weights and frame)."""
    zk = np.stack([lengths_and_angles(A, topo), lengths_and_angles(B, topo)])
    out = []
    for t in factors:
        res = reconstruct(blend_targets(zk, [t], topo.n_edges), topo, A, method="gn", max_iterations=300,
                          initial_vertices=(1 - t) * A + t * B)
        assert res.success
        out.append(res.vertices)
    return np.array(out)


@pytest.mark.parametrize("pose", [(1.5, 0.0), (0.0, 1.5), (1.0, 1.0)], ids=["bend", "twist", "both"])
def test_path_matches_converged_gauss_newton(bar, pose):
    X, F, topo = bar
    B = bar_pose(X, *pose)
    res = path_inbetweens(X, B, topo, FACTORS)
    assert res.success and not res.polished and res.message == ""
    assert res.factorizations == 2                        # the tangent at A and one Newton vector
    gn = _gauss_newton(X, B, topo, FACTORS)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    # measured: largest RMS 0.0004 % (bend), 0.01 % (twist), 0.008 % (both); indicator 0.1-0.2 %
    assert rms.max() < 3e-4
    assert np.all(rms <= res.indicator)                   # the indicator is an upper estimate here
    assert res.indicator.max() <= PathOptions().tolerance
    # the full energy of every in-between is close to converged Gauss-Newton's
    zk = np.stack([lengths_and_angles(X, topo), lengths_and_angles(B, topo)])

    ctx = get_context(topo, X)
    e_gn = np.array([ctx.energy(blend_targets(zk, [t], topo.n_edges), V) for t, V in zip(FACTORS, gn, strict=True)])
    assert np.all(res.energy >= e_gn * (1 - 1e-6))
    assert np.all(res.energy - e_gn <= 0.5 * e_gn + 1e-12 * _diag(X) ** 2)


def test_keys_are_reproduced(bar):
    X, F, topo = bar
    B = bar_pose(X, 1.0, 0.5)
    res = path_inbetweens(X, B, topo, [0.0, 0.5, 1.0])
    d = _diag(X)
    assert np.abs(res.vertices[0] - X).max() < 1e-9 * d      # the frame of A
    assert rigid_rms(res.vertices[2], B) < 1e-6 * d
    assert res.indicator[0] == 0.0 and res.indicator[2] == 0.0 and res.indicator[1] > 0


def test_indicator_flags_and_polish_fixes(bar):
    """A tolerance the space cannot meet with one Newton vector: flagged without polish, exact with it."""
    X, F, topo = bar
    B = bar_pose(X, 2.5, 2.0)
    strict = PathOptions(tolerance=1e-7, max_newton_vectors=1, polish=False)
    res = path_inbetweens(X, B, topo, FACTORS, strict)
    assert not res.success and not res.polished
    assert res.indicator.max() > 1e-7 and "above the tolerance" in res.message
    gn = _gauss_newton(X, B, topo, FACTORS)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    assert np.all(rms <= res.indicator)
    fixed = path_inbetweens(X, B, topo, FACTORS, PathOptions(tolerance=1e-7, max_newton_vectors=1,
                                                             polish_method="gn"))
    assert fixed.success and fixed.polished and "polished by full Gauss-Newton" in fixed.message
    assert np.all(fixed.indicator == 0.0)
    rms = np.sqrt(((fixed.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    assert rms.max() < 5e-6        # both converged, from other starts: measured 1.5e-6
    fast = path_inbetweens(X, B, topo, FACTORS, PathOptions(tolerance=1e-7, max_newton_vectors=1,
                                                            polish_method="fast"))
    assert fast.success and "polished by Fast" in fast.message
    rms = np.sqrt(((fast.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    assert rms.max() < 1e-3


def test_extrapolation_probes_further(bar):
    """Factors beyond the keys: the indicator grows there, so the path takes more Newton vectors or polishes."""
    X, F, topo = bar
    B = bar_pose(X, 1.5, 0.0)
    factors = np.array([-0.5, 0.5, 1.5])
    res = path_inbetweens(X, B, topo, factors)
    assert res.success
    gn = _gauss_newton(X, B, topo, factors)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    assert rms.max() < PathOptions().tolerance
    assert res.polished or np.all(rms <= res.indicator)


def test_factorizations_are_counted(monkeypatch, bar):
    X, F, topo = bar
    calls = []
    orig = FullProblem.factorize

    def counting(self, *a, **k):
        calls.append(1)
        return orig(self, *a, **k)

    monkeypatch.setattr(FullProblem, "factorize", counting)
    res = path_inbetweens(X, bar_pose(X, 1.0, 0.0), topo, FACTORS)
    assert len(calls) == res.factorizations == 2
    calls.clear()
    res = path_inbetweens(X, bar_pose(X, 1.0, 0.0), topo, FACTORS, PathOptions(tangents="both"))
    assert len(calls) == res.factorizations == 3


def test_interpolate_method_path(bar):
    X, F, topo = bar
    B, C = bar_pose(X, 1.0, 0.0), bar_pose(X, 1.0, 1.0)
    res = interpolate([X, B], topo, FACTORS, method="path")
    direct = path_inbetweens(X, B, topo, FACTORS)
    assert res.method == "path" and res.success
    np.testing.assert_allclose(res.vertices, direct.vertices, atol=1e-9 * _diag(X))
    np.testing.assert_allclose(res.indicator, direct.indicator)
    # three keys: each segment by its own path, all in the frame of the first key
    kf = keyframe_inbetweens([X, B, C], topo, [0, 4, 8], method="path")
    gn = keyframe_inbetweens([X, B, C], topo, [0, 4, 8], method="gn")
    rms = np.sqrt(((kf.vertices - gn.vertices) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    assert rms.max() < PathOptions().tolerance
    with pytest.raises(InputError, match="spline"):
        keyframe_inbetweens([X, B, C], topo, [0, 4, 8], smooth=True, method="path")
    with pytest.raises(InputError, match="PathOptions"):
        interpolate([X, B], topo, [0.5], method="path", options=object())


@pytest.mark.parametrize("kw", [{"tolerance": 0.0}, {"max_newton_vectors": 0}, {"tangents": "none"},
                                {"iterations": 1.5}])
def test_bad_options(kw):
    with pytest.raises(InputError):
        PathOptions(**kw)


def test_safety_factor_is_documented():
    assert SAFETY >= 1.0


def test_rolled_plates_are_polished():
    """Real shared data where the path's space does not converge (the two rolled plates: estimates 10-20 % of the
    diagonal): the indicator sends every in-between to full Gauss-Newton, never a wrong shape."""
    from conftest import shared_mesh

    from lacore.io.meshes import load_mesh

    A, F = load_mesh(shared_mesh("plate/plate121_rolledA.ply"))
    B, _ = load_mesh(shared_mesh("plate/plate121_rolledB.ply"))
    topo = MeshTopology.from_faces(F, n_vertices=len(A))
    factors = [0.25, 0.5, 0.75]
    res = path_inbetweens(A, B, topo, factors)
    assert res.polished and res.success and res.factorizations == 4      # three probes, estimates 10-20 %
    assert "polished by full Gauss-Newton" in res.message                # far off: not by Fast
    assert min(e for _, e in res.estimates) > 0.03
    gn = _gauss_newton(A, B, topo, factors)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(A)
    # both converged in a flat valley (energies equal to 1e-9): measured 1.8e-6 to 1.0e-5 as stopping rules changed
    assert rms.max() < 5e-5


def test_path_frames_plain_arrays(bar):
    """The worker-process form (plain arrays in and out) gives the frames of keyframe_inbetweens."""
    from lacore.shapes.interpolation import path_frames

    X, F, topo = bar
    B = bar_pose(X, 1.0, 0.0)
    V, ind, ok, msg = path_frames(np.stack([X, B]), F, [0.0, 1.0], [0.3, 0.6])
    res = keyframe_inbetweens([X, B], topo, [0.0, 1.0], [0.3, 0.6], method="path")
    np.testing.assert_allclose(V, res.vertices, atol=1e-9 * _diag(X))
    np.testing.assert_allclose(ind, res.indicator)
    assert ok and isinstance(msg, str)


@pytest.mark.parametrize("factors", [[], [np.nan], [[0.5]]])
def test_bad_factors(bar, factors):
    X, F, topo = bar
    with pytest.raises(InputError, match="factors"):
        path_inbetweens(X, bar_pose(X, 1.0, 0.0), topo, factors)


def test_auto_polish_by_fast_when_close(bar):
    """An indicator just above the tolerance: the in-betweens above it by Fast from the good ones, the rest kept."""
    X, F, topo = bar
    B = bar_pose(X, 1.5, 0.0)
    res = path_inbetweens(X, B, topo, FACTORS, PathOptions(tolerance=1e-3, max_newton_vectors=1))
    assert res.success and res.polished and "polished by Fast" in res.message
    gn = _gauss_newton(X, B, topo, FACTORS)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / _diag(X)
    assert rms.max() < 1e-3
    assert np.all(rms <= res.indicator)          # Fast's in-betweens keep the reduced ones' estimate, an upper one


def _path_projection(A, B, topo, factors, starts):
    """Converged full Gauss-Newton of the path's energy (``A``'s weights at every ``t``, the projection the path's
    indicator estimates the distance to; its polish computes it), from ``starts``, and the in-betweens' own sizes
    (``A``'s diagonal times :meth:`ShapeMixer.relative_size`)."""
    from lacore.reconstruction.settings import GaussNewtonOptions
    from lacore.reconstruction.spanning_trees import default_root_faces
    from lacore.shapes.mixing import MixerOptions, ShapeMixer

    mixer = ShapeMixer(np.stack([A, B]), topo.faces, MixerOptions(), _topology=topo,   # the path's fixed face
                       _fixed_faces=default_root_faces(topo, vertices=A))
    out = []
    for t, X in zip(factors, starts, strict=True):
        res = reconstruct(mixer.target([t]), topo, A, context=mixer._context,
                          options=GaussNewtonOptions(max_iterations=300), initial_vertices=X)
        assert res.success
        out.append(res.vertices)
    return np.array(out), _diag(A) * mixer.relative_size(np.asarray(factors, float)[:, None])


@pytest.fixture(scope="module")
def finger():
    from conftest import shared_mesh

    from lacore.io.meshes import load_mesh

    A, F = load_mesh(shared_mesh("finger/finger0.ply"))
    B, _ = load_mesh(shared_mesh("finger/finger1.ply"))
    return A, B, MeshTopology.from_faces(F, n_vertices=len(A))


@pytest.mark.parametrize("factors", [[0.25, 0.5, 0.75], FACTORS], ids=["quarters", "elevenths"])
def test_keys_of_very_different_sizes(finger, factors):
    """The finger against the bent finger scaled by 0.1: the in-betweens shrink to a fifth and less of A's size.
    Indicator and error are over each in-between's own size; the indicator covers the error, and the in-betweens
    are within the tolerance of the projection."""
    A, B, topo = finger
    B = 0.1 * B
    res = path_inbetweens(A, B, topo, factors)
    assert res.success
    gn, sizes = _path_projection(A, B, topo, factors, res.vertices)
    np.testing.assert_allclose(sizes / _diag(A), 1.0 - 0.9 * np.asarray(factors), atol=2e-3)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / sizes
    # measured, quarters: at t = 0.75 0.061 % of its size (0.020 % of A's diagonal), indicator 0.15 %; elevenths: at
    # t = 0.91 0.074 % (indicator 0.19 %).  With the indicator over A's diagonal and the probes placed by t alone:
    # quarters, 0.037 % of A's diagonal (0.115 % of its size) against an indicator of 0.058 %; elevenths, 0.066 %
    # (0.36 %) against 0.015 %
    assert np.all(rms <= res.indicator)
    assert rms.max() < PathOptions().tolerance
    assert res.indicator.max() <= PathOptions().tolerance or res.polished


@pytest.mark.parametrize("scale", [0.1, 10.0])
def test_fast_polish_projects_the_paths_energy(finger, scale):
    """Fast's polish minimizes the path's energy (A's weights at every t), also where the in-betweens leave the band
    of sizes in which reconstruct keeps the reference's weights."""
    A, B, topo = finger
    B = scale * B
    factors = [0.25, 0.5, 0.75]
    res = path_inbetweens(A, B, topo, factors, PathOptions(tolerance=1e-7, max_newton_vectors=1, polish_method="fast"))
    assert res.success and "polished by Fast" in res.message
    gn, sizes = _path_projection(A, B, topo, factors, res.vertices)
    rms = np.sqrt(((res.vertices - gn) ** 2).sum(axis=2).mean(axis=1)) / sizes
    # measured: largest 0.015 % (0.1) and 0.015 % (10); with reconstruct's target-scaled weights, 0.65 % and 0.28 %
    assert rms.max() < 1e-3
    assert np.all(rms <= res.indicator)


def test_progress_names_the_polish(bar):
    """The last progress message before "done" says how many in-betweens are polished, and by what."""
    X, F, topo = bar
    seen = []
    path_inbetweens(X, bar_pose(X, 2.5, 2.0), topo, FACTORS,
                    PathOptions(tolerance=1e-7, max_newton_vectors=1, polish_method="gn"),
                    progress=lambda done, total, message: seen.append(message))
    assert seen[-1] == "done"
    assert seen[-2] == f"polishing {len(FACTORS)} of {len(FACTORS)} in-betweens by full Gauss-Newton"
