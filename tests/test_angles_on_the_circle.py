"""Dihedral angles live on the circle: an edge folded to 3.1 rad and one folded to -3.1 rad differ by 0.08 rad.

``W_q``'s residuals, the checks, and the blends of keys (interpolation, the shape mixer, the shape model) take
angle differences through :func:`lacore.geometry.lengths_angles.wrap_angle`; without it a fold that crosses the
branch cut at +-pi costs ``(2 pi)^2`` and an in-between opens the fold through 0.
"""

import numpy as np
import pytest

from lacore import MeshTopology, QuadraticEnergy, lengths_and_angles, reconstruct
from lacore.geometry.lengths_angles import wrap_angle
from lacore.shapes.interpolation import interpolate, lift_angles, piecewise_linear_z, spline_z


def hinge(theta):
    """A strip of four triangles whose middle edge is folded to the signed angle ``theta``; the other two interior
    edges flat.  Vertices 0-1 on the hinge; the flap (vertices 3, 5) turns about the x axis."""
    faces = np.array([[0, 1, 2], [1, 0, 3], [2, 1, 4], [3, 0, 5]])
    c, s = np.cos(np.pi + theta), np.sin(np.pi + theta)
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, c, s], [1.5, 1, 0], [-0.5, c, s]])
    topo = MeshTopology.from_faces(faces)
    return X, topo


def middle(topo):
    return int(np.flatnonzero((topo.edges == [0, 1]).all(1) | (topo.edges == [1, 0]).all(1))[0])


def test_wrap_angle_keeps_angles_inside_bit_for_bit():
    a = np.array([0.1, -np.pi, np.pi, 3.0])
    assert wrap_angle(a) is a
    b = np.array([0.1, 6.2, -6.2, 3 * np.pi])
    w = wrap_angle(b)
    assert w[0] == 0.1 and np.allclose(w[1:], [6.2 - 2 * np.pi, 2 * np.pi - 6.2, np.pi], rtol=0, atol=1e-15)


@pytest.mark.parametrize("theta", [3.05, -3.05])
def test_a_fold_across_the_branch_cut_is_reached_the_short_way(theta):
    """The hinge at ``theta`` (near +-pi) as the start, the hinge folded 0.1 rad further (across the cut: its
    signed angle has the other sign) as the target: reproduced, with ``W_q`` of the start about ``w 0.1^2``."""
    X0, topo = hinge(theta)
    E, e = topo.n_edges, middle(topo)
    target_theta = wrap_angle(np.array([theta + np.sign(theta) * 0.1]))[0]
    assert np.sign(target_theta) != np.sign(theta)                       # the target crossed the cut
    X1, _ = hinge(target_theta)
    z1 = lengths_and_angles(X1, topo)
    assert z1[E + e] == pytest.approx(target_theta, abs=1e-12)
    W = QuadraticEnergy(topo, reference_vertices=X0)
    w = W.residual_weights[E + e]
    assert W.value(lengths_and_angles(X0, topo), z1) == pytest.approx(w * 0.1 ** 2, rel=1e-6)
    res = reconstruct(z1, topo, X0)
    assert res.success and res.checks["reproduced"], res.message
    assert abs(wrap_angle(lengths_and_angles(res.vertices, topo)[E + e] - target_theta)) < 1e-8


def test_in_betweens_of_a_fold_across_the_cut_stay_folded():
    """Keys folded to 3.0 and -3.0 rad (0.28 rad apart on the circle): the in-between at 1/2 is folded to pi, not
    opened flat (the plain average 0), and reconstructs to it; splines too."""
    X0, topo = hinge(3.0)
    X1, _ = hinge(-3.0)
    E, e = topo.n_edges, middle(topo)
    Z = np.stack([lengths_and_angles(X0, topo), lengths_and_angles(X1, topo)])
    lifted = lift_angles(Z)
    assert lifted[1, E + e] == pytest.approx(2 * np.pi - 3.0) and lifted[0, E + e] == Z[0, E + e]
    mid = piecewise_linear_z(Z, [0.0, 1.0], [0.5])[0]
    assert abs(abs(mid[E + e]) - np.pi) < 1e-12
    three = spline_z(np.stack([Z[0], Z[1], Z[0]]), [0.0, 1.0, 2.0], [0.5, 1.5])
    assert np.all(np.abs(np.abs(three[:, E + e]) - np.pi) < 0.2)         # between 3.0 and -3.0 the short way
    res = interpolate([X0, X1], topo, [0.5])
    assert res.success, res.message
    theta = lengths_and_angles(res.vertices[0], topo)[E + e]
    assert abs(abs(theta) - np.pi) < 1e-6, theta


def test_no_angle_moves_without_a_crossing():
    X0, topo = hinge(1.0)
    X1, _ = hinge(-1.0)
    Z = np.stack([lengths_and_angles(X0, topo), lengths_and_angles(X1, topo)])
    assert lift_angles(Z) is not None and np.array_equal(lift_angles(Z), Z)
    assert piecewise_linear_z(Z, [0.0, 1.0], [0.5])[0][topo.n_edges + middle(topo)] == pytest.approx(0.0, abs=1e-15)


def test_in_betweens_of_skinned_poses_keep_their_folds():
    """Linear-blend skinning folds the coarse CC0 body's skin nearly flat back (3.10 rad at one edge of its rest
    pose); between two random poses 3-12 edges cross the branch cut (measured, seed 1).  The in-between targets at
    1/4, 1/2 and 3/4 keep every such edge that both keys fold beyond pi/2 folded beyond pi/2, where plain averages
    opened them to 0.1-1.5."""
    from conftest import shared_data_dir
    from lacore.samples.human import load_human
    try:
        body = load_human(shared_data_dir(), coarse=True)
    except (FileNotFoundError, OSError) as exc:
        pytest.skip(f"CC0 human not available: {exc}")
    topo = MeshTopology.from_faces(body.faces, n_vertices=body.n_vertices)
    E = topo.n_edges
    poses, _ = body.random_poses(6, seed=1)
    Z = np.stack([lengths_and_angles(p, topo) for p in poses])
    crossings = 0
    for a, b in zip(Z[:-1], Z[1:], strict=True):
        # folded in both keys (beyond pi/2) on either side of the cut: the short way stays folded
        cross = np.flatnonzero((np.abs(b[E:] - a[E:]) > np.pi) & (np.abs(a[E:]) > np.pi / 2)
                               & (np.abs(b[E:]) > np.pi / 2))
        crossings += cross.size
        mid = piecewise_linear_z(np.stack([a, b]), [0.0, 1.0], [0.25, 0.5, 0.75])
        assert np.all(np.abs(mid[:, E + cross]) > np.pi / 2)
        assert np.all(np.abs(mid[:, E:]) <= np.pi)
    assert crossings >= 10  # measured 25 over the 5 pairs


@pytest.mark.parametrize("method", ["sqp", "vertices"])
def test_a_discrete_geodesic_across_the_cut_turns_the_short_way(method):
    """The hinge from 3.0 to -3.0 rad in 4 steps: the fold turns through pi (steps of 0.071 rad), with the path
    energy of those steps; a mesh without interior vertices has no integrability constraint (no error)."""
    from lacore.shapes.geodesics import discrete_geodesic
    X0, topo = hinge(3.0)
    X1, _ = hinge(-3.0)
    E, e = topo.n_edges, middle(topo)
    res = discrete_geodesic(X0, X1, topo, 4, method=method)
    assert res.success, res.message
    theta = wrap_angle(res.z[:, E + e])
    np.testing.assert_allclose(np.abs(theta), [3.0, 3.0 + 0.0708, np.pi, 3.0 + 0.0708, 3.0], atol=1e-3)
    step = 2 * np.pi - 6.0
    w = QuadraticEnergy(topo, reference_vertices=X0).residual_weights[E + e]
    assert res.path_energy == pytest.approx(4 * 4 * w * (step / 4) ** 2, rel=1e-3)


def test_the_energy_gradient_across_the_cut_matches_finite_differences():
    """``W_q``'s gradient (:class:`~lacore.reconstruction.objectives.QuadraticObjective`) at the hinge folded to
    3.05 rad with a target across the cut (-3.13 rad): central differences agree (the wrapped residual is smooth
    there)."""
    from lacore.reconstruction import get_context
    X0, topo = hinge(3.05)
    X1, _ = hinge(-3.13)
    objective = get_context(topo, X0).objective(lengths_and_angles(X1, topo))
    energy, grad, _ = objective.linearize(X0)
    assert energy == pytest.approx(objective.energy(X0)) and energy < 0.1   # not (2 pi)^2 w
    h = 1e-6
    fd = np.empty(X0.size)
    for i in range(X0.size):
        step = np.zeros(X0.size)
        step[i] = h
        fd[i] = (objective.energy(X0 + step.reshape(-1, 3)) - objective.energy(X0 - step.reshape(-1, 3))) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8 * np.abs(grad).max())
