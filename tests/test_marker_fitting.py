"""Marker fitting (thesis 4.3.1): bindings, derivatives, the bordered joint step, occlusion, errors, safeguard."""

import numpy as np
import pytest
from fd import directional_fd, relative_error
from scipy.spatial.transform import Rotation

from lacore.geometry.lengths_angles import face_areas
from lacore.markers.binding import (MarkerBinding, MarkerBindingError, bind_markers, surface_point_jacobians,
                                    surface_points)
from lacore.errors import InputError
from lacore.markers.fitting import (FIT_DEFAULTS, LENGTH_RANGE_MARGIN, FitOptions, FrameSolver, MarkerDataError,
                                    extrapolation_skill, fit_markers, observed_mask)
from lacore.samples.bar import bar_mesh, bar_pose
from lacore.models.shape_model import ShapeModel
from lacore.progress import Cancelled

ROT = Rotation.from_rotvec([0.3, 0.2, 0.1]).as_matrix()
SHIFT = np.array([1.0, 2.0, 3.0])


@pytest.fixture(scope="module")
def bar():
    X0, F = bar_mesh()
    train = np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 4) for tw in np.linspace(-1, 1, 3)])
    model = ShapeModel.fit(train, F, n_modes=4)
    rng = np.random.default_rng(0)
    vertices = rng.choice(len(X0), 20, replace=False)
    binding = MarkerBinding.from_vertices(vertices, F, offsets=0.05)
    return X0, F, model, binding


def _surface_binding(F, m, seed=1, offset=0.08):
    rng = np.random.default_rng(seed)
    b = rng.random((m, 3)) + 0.1
    return MarkerBinding.from_surface(rng.choice(len(F), m, replace=False), b / b.sum(1, keepdims=True),
                                      offset * rng.uniform(0.5, 1.5, m))


def test_surface_point_jacobian_matches_finite_differences(bar):
    X0, F, _, _ = bar
    X = bar_pose(X0, 0.6, 0.4)
    binding = _surface_binding(F, 12)
    G, dofs = surface_point_jacobians(X, F, binding)
    rng = np.random.default_rng(2)
    d = rng.standard_normal(X.shape)
    fd = directional_fd(lambda Y: surface_points(Y, F, binding), X, d, 1e-3)
    analytic = np.einsum("mij,mj->mi", G, d.ravel()[dofs])
    err = relative_error(analytic, fd)
    assert err < 2e-8, err  # measured 4e-9
    # the normal's derivative matters: without it the error is of the order of the offsets
    G0, _ = surface_point_jacobians(X, F, MarkerBinding.from_surface(binding.faces, binding.barycentric))
    assert relative_error(np.einsum("mij,mj->mi", G0, d.ravel()[dofs]), fd) > 1e-3


def test_gradient_and_bordered_step_match_fd_and_dense_solve(bar):
    X0, F, model, _ = bar
    binding = _surface_binding(F, 15)
    X = bar_pose(X0, 0.5, -0.3) @ ROT.T + SHIFT
    x = surface_points(bar_pose(X0, 0.7, -0.2) @ ROT.T + SHIFT, F, binding)
    x[3] = np.nan
    vis = np.flatnonzero(np.isfinite(x[:, 0]))
    # compression ratio 0.98: faces are penalized here (checks that Jacobian too); temporal term on
    solver = FrameSolver(model, binding, FitOptions(prior_weight=0.7, compression_ratio=0.98), temporal=0.3)
    solver.X_hat = X + 0.01
    assert 0 < len(solver._compression(X)[1]) < len(F)
    rng = np.random.default_rng(3)
    a = 0.1 * rng.standard_normal(model.n_modes)
    gX, ga, vals, Jz = solver.gradient(X, a, x, vis, matrix=True)
    B = solver.border(Jz)
    dX = rng.standard_normal(X.shape)
    fd = directional_fd(lambda Y: solver.energy(Y, a, x, vis)[0], X, dX, 1e-4)
    assert abs(gX @ dX.ravel() - fd) < 1e-7 * abs(fd), (gX @ dX.ravel(), fd)
    da = rng.standard_normal(model.n_modes)
    fd_a = directional_fd(lambda b: solver.energy(X, b, x, vis)[0], a, da, 1e-4)
    assert abs(ga @ da - fd_a) < 1e-7 * abs(fd_a)
    # bordered Schur step == dense solve of the full (3V + J) Gauss-Newton system
    solver.factorize(X, a, x, vis)
    step_X, step_a = solver.step(gX, ga)
    pat = solver.pattern
    import scipy.sparse as sp
    L = sp.csc_matrix((vals, pat["indices"], pat["indptr"]), shape=(pat["n"], pat["n"])).toarray()
    A = L + L.T - np.diag(np.diag(L))
    full = np.block([[A, B], [B.T, solver.coefficient_block(a)]])
    ref = np.linalg.solve(full, -np.concatenate([gX, ga]))
    assert relative_error(np.concatenate([step_X, step_a]), ref) < 1e-8
    assert gX @ step_X + ga @ step_a < 0


def test_training_ellipsoid_derivatives_match_finite_differences(bar):
    """Coefficients outside the training poses' ellipsoid (FitOptions.coefficient_weight, the modes masked by the
    default observed_radius, at full strength: 4 modes of the 11 the training poses span): the term's energy is
    positive, the coefficient gradient matches finite differences, and the Schur step with the term's matrix equals
    the dense solve of the full system."""
    X0, F, model, _ = bar
    binding = _surface_binding(F, 15)
    X = bar_pose(X0, 0.5, -0.3)
    x = surface_points(bar_pose(X0, 0.7, -0.2), F, binding)
    vis = np.arange(len(x))
    solver = FrameSolver(model, binding, FitOptions(prior_weight=0.7, coefficient_weight=0.5))
    assert np.isfinite(solver.a_radius) and solver.extrapolation == 0.0
    D = observed_mask(model.topology, model.reference_vertices, binding.faces, *FIT_DEFAULTS.observed_radius)
    assert np.array_equal(solver.observed, D) and D.min() < 0.5
    rng = np.random.default_rng(4)
    a = rng.standard_normal(model.n_modes)
    a *= 2.0 * solver.a_radius / np.sqrt(a @ (solver.a_scale * a))          # twice the largest training radius
    E_ell, g_ell, H_ell = solver._ellipsoid(a)
    assert E_ell > 0 and np.all(np.linalg.eigvalsh(H_ell) > 0)
    gX, ga, vals, Jz = solver.gradient(X, a, x, vis, matrix=True)
    da = rng.standard_normal(model.n_modes)
    fd_a = directional_fd(lambda b: solver.energy(X, b, x, vis)[0], a, da, 1e-5)
    assert abs(ga @ da - fd_a) < 1e-6 * abs(fd_a), (ga @ da, fd_a)            # measured 1e-9
    fd_e = directional_fd(lambda b: solver._ellipsoid(b)[0], a, da, 1e-5)
    assert abs(g_ell @ da - fd_e) < 1e-6 * abs(fd_e), (g_ell @ da, fd_e)
    B = solver.border(Jz)
    solver.factorize(X, a, x, vis)
    step_X, step_a = solver.step(gX, ga)
    pat = solver.pattern
    import scipy.sparse as sp
    L = sp.csc_matrix((vals, pat["indices"], pat["indptr"]), shape=(pat["n"], pat["n"])).toarray()
    A = L + L.T - np.diag(np.diag(L))
    full = np.block([[A, B], [B.T, solver.coefficient_block(a) + H_ell]])
    ref = np.linalg.solve(full, -np.concatenate([gX, ga]))
    assert relative_error(np.concatenate([step_X, step_a]), ref) < 1e-8


def test_fit_options_reject_bad_mask_and_ellipsoid_settings(bar):
    X0, F, model, binding = bar
    x = surface_points(bar_pose(X0, 0.3, 0.0), F, binding)
    with pytest.raises(InputError, match="observed_radius must be None or two numbers 0 <= r1 < r2"):
        fit_markers(model, x, binding, observed_radius=(0.3, 0.1))
    with pytest.raises(InputError, match=r"coefficient_weight must be a number in \[0, 1e\+06\]"):
        fit_markers(model, x, binding, coefficient_weight=-1.0)
    assert FitOptions(observed_radius=0).check() and FitOptions(observed_radius=None).check()


def test_triangular_solves_and_stale_schur_step(bar):
    """forward / diagonal_solve / backward compose to A^-1 (the Schur complement from forward substitutions only);
    a step with an earlier step's border and Schur complement stays a descent direction."""
    from lacore.linalg.sparse_cholesky import SparseCholesky
    X0, F, model, _ = bar
    binding = _surface_binding(F, 15)
    X = bar_pose(X0, 0.5, -0.3)
    x = surface_points(bar_pose(X0, 0.7, -0.2), F, binding)
    vis = np.arange(len(x))
    solver = FrameSolver(model, binding, FitOptions(prior_weight=0.7))
    a = np.zeros(model.n_modes)
    gX, ga, vals, Jz = solver.gradient(X, a, x, vis, matrix=True)
    B = solver.border(Jz)
    chol = SparseCholesky(solver.pattern["matrix"]).factorize(vals)
    if not chol.has_triangular_solves:  # pragma: no cover - without cvxopt
        pytest.skip("CHOLMOD backend not available")
    u = chol.backward(chol.diagonal_solve(chol.forward(B)))
    assert relative_error(u, chol.solve(B)) < 1e-12
    W = chol.forward(B)
    assert relative_error(W.T @ chol.diagonal_solve(W), B.T @ chol.solve(B)) < 1e-12
    solver.factorize(X, a, x, vis)
    X1 = X + 0.01 * np.random.default_rng(4).standard_normal(X.shape)
    g1X, g1a = solver.factorize(X1, a, x, vis, schur=False)       # new factor, old border and Schur complement
    assert solver.W is None
    dX, da = solver.step(g1X, g1a)
    assert g1X @ dX + g1a @ da < 0


def test_fit_recovers_held_out_poses_under_rigid_motion_and_occlusion(bar):
    X0, F, model, binding = bar
    s = np.linspace(0, 2, 8)
    true = np.array([bar_pose(X0, 0.7 * np.sin(v), 0.5 * np.cos(v)) for v in s]) @ ROT.T + SHIFT
    x = surface_points(true, F, binding)
    x[3, :5] = np.nan
    res = fit_markers(model, x, binding, prior_weight=1.0, temporal_weight=0.0)  # 8 far-apart frames: no smoothing
    err = np.linalg.norm(res.vertices - true, axis=2).mean(1)
    assert res.success and res.status == 0, res.message
    assert err.max() < 0.015, err  # bar length 6; measured 0.0042
    assert res.marker_rms < 0.01, res.marker_rms  # measured 0.0034
    assert np.isnan(res.marker_residuals[3, :5]).all() and np.isfinite(res.marker_residuals[3, 5:]).all()
    assert res.vertices.shape == (8, len(X0), 3) and res.coefficients.shape == (8, 4)
    assert set(res.timings) >= {"frames", "prolongation", "total"}
    assert res.frame_iterations.max() <= 8  # measured 3
    # the model's own lengths and angles are reproduced: Z[X] vs z of the result
    assert res.z.shape == (8, 2 * model.topology.n_edges)
    s = res.summary()
    assert s["frames"] == 8 and s["marker_rms"] == pytest.approx(res.marker_rms)


def test_mean_only_prior_is_worse_than_the_model(bar):
    X0, F, model, binding = bar
    true = bar_pose(X0, 0.9, 0.6)
    x = surface_points(true, F, binding)
    # the modes everywhere, converged tightly: the training ellipsoid slows the last steps (ftol stops at 0.0059
    # on the defaults)
    e_model = np.linalg.norm(fit_markers(model, x, binding, observed_radius=None, ftol=1e-12, marker_tolerance=0.0,
                                         max_iterations=100).vertices[0] - true, axis=1).mean()
    res0 = fit_markers(model, x, binding, n_modes=0)
    e_mean = np.linalg.norm(res0.vertices[0] - true, axis=1).mean()
    assert res0.coefficients.shape == (1, 0)
    assert e_model < 0.1 * e_mean, (e_model, e_mean)  # measured 0.0015 vs 0.045 (modes everywhere)
    # the default mask with this 4-mode model (fewer modes than the 12 training poses span): at full strength, 20
    # random markers leave parts of the bar to the mean's straight shape
    e_masked = np.linalg.norm(fit_markers(model, x, binding).vertices[0] - true, axis=1).mean()
    assert e_masked < 0.5 * e_mean, (e_masked, e_mean)  # measured 0.014
    # with every mode the training poses (bending the bar as a whole) show that the markers' region predicts the
    # rest (extrapolation_skill 1): the modes act everywhere, as without the mask (0.0060 and 0.0059)
    train = np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 4) for tw in np.linspace(-1, 1, 3)])
    full = ShapeModel.fit(train, F)                     # the fixture's poses, all 11 modes
    assert FrameSolver(full, binding).extrapolation == pytest.approx(1.0, abs=1e-4)
    assert FrameSolver(model, binding).extrapolation == 0.0
    e_full = np.linalg.norm(fit_markers(full, x, binding).vertices[0] - true, axis=1).mean()
    e_none = np.linalg.norm(fit_markers(full, x, binding, observed_radius=None).vertices[0] - true, axis=1).mean()
    assert e_full < 0.6 * e_masked and e_full < 1.1 * e_none, (e_full, e_none, e_masked)


def test_temporal_target_moves_the_unmarked_region_rigidly(bar):
    """``FrameSolver.predict(masked=True)``: vertices whose modes the mask silences (``vertex_observed`` 0) follow
    the marked region's rigid motion instead of extrapolating their own velocity; marked ones keep theirs."""
    X0, F, model, _ = bar
    end = np.argsort(X0[F].mean(1)[:, np.argmax(np.ptp(X0, axis=0))])[:8]          # faces at one end of the bar
    binding = MarkerBinding.from_surface(end, np.full((8, 3), 1.0 / 3.0), np.zeros(8))
    solver = FrameSolver(model, binding)
    Dv = solver.vertex_observed
    free, marked = Dv == 0.0, Dv == 1.0
    assert free.sum() > 0.3 * len(X0) and marked.sum() >= 8, (free.sum(), marked.sum())
    X_prev, X = bar_pose(X0, 0.4, 0.2), bar_pose(X0, 0.6, 0.3)
    a = np.zeros(solver.J)
    y = surface_points(2.0 * X - X_prev, F, binding)
    vis = np.arange(8)
    plain = solver.predict(X, a, X_prev, a, y, vis)[0]
    masked = solver.predict(X, a, X_prev, a, y, vis, masked=True)[0]
    assert np.allclose(masked[marked], plain[marked], atol=1e-9)

    def distances(Q):
        return np.linalg.norm(Q[free][:, None] - Q[free][None], axis=2)

    def shape_change(P):
        """Largest change of the distances between the unmarked vertices from ``X``'s."""
        return np.abs(distances(P) - distances(X)).max()

    assert shape_change(masked) < 1e-9 * np.ptp(X0).max() < 0.01 * shape_change(plain)
    # without the mask every vertex keeps its velocity
    none = FrameSolver(model, binding, FitOptions(observed_radius=None))
    assert none.vertex_observed is None
    assert np.array_equal(none.predict(X, a, X_prev, a, y, vis, masked=True)[0], none.predict(X, a, X_prev, a, y,
                                                                                               vis)[0])


def _pca(z):
    """Modes ``(N - 1, d)`` spanning the centred samples ``z (N, d)`` and the samples' coefficients."""
    zc = z - z.mean(0)
    U = np.linalg.svd(zc, full_matrices=False)[2][:len(z) - 1]
    return U, zc @ U.T


def test_extrapolation_skill_of_parts_moving_together_and_apart():
    """Q^2 of predicting the unmarked half of 60 entries from the marked half over 12 training samples of 2 latent
    variables: near 1 where the halves move together, noise lowering it; at most about 0 where they move apart;
    scale-free."""
    rng = np.random.default_rng(0)
    D, w = np.repeat([1.0, 0.0], 30), np.ones(60)
    A = rng.normal(size=(2, 30))
    lat, other, noise = rng.normal(size=(12, 2)), rng.normal(size=(12, 2)), rng.normal(size=(12, 60))
    together = lat @ np.hstack([A, 2.0 * A])
    apart = np.hstack([lat @ A, other @ A])
    assert extrapolation_skill(*_pca(together)[:1], w, _pca(together)[1], D) == pytest.approx(1.0, abs=1e-4)
    q = [extrapolation_skill(*_pca(together + s * noise)[:1], w, _pca(together + s * noise)[1], D)
         for s in (0.1, 1.0)]
    assert 0.98 < q[0] < 1.0 and 0.3 < q[1] < 0.9, q           # measured 0.997, 0.67
    U, T = _pca(apart + 0.1 * noise)
    q_apart = extrapolation_skill(U, w, T, D)
    assert q_apart < 0.05, q_apart                               # measured -0.23: the fit predicts the noise
    # the metric's and the coefficients' units do not matter; leave-one-out is folds >= N
    assert extrapolation_skill(U, 1e3 * w, 7.0 * T, D) == pytest.approx(q_apart, rel=1e-6)
    assert extrapolation_skill(U, w, T, D, folds=12) == pytest.approx(extrapolation_skill(U, w, T, D, folds=99))
    # nothing unmarked: 1; fewer than 2 training poses: 0
    assert extrapolation_skill(U, w, T, np.ones(60)) == 1.0 and extrapolation_skill(U, w, T[:1], D) == 0.0


def test_frames_with_fewer_than_three_markers_and_temporal_term(bar):
    X0, F, model, binding = bar
    s = np.linspace(0, 1, 6)
    true = np.array([bar_pose(X0, 0.6 * v, 0.3 * v) for v in s])
    x = surface_points(true, F, binding)
    x[3, 2:] = np.nan  # 2 markers left
    x[4, :] = np.nan   # none
    res = fit_markers(model, x, binding, temporal_weight=0.0)
    assert list(res.frame_status) == [0, 0, 0, 2, 2, 0], res.frame_status
    assert res.success and res.status == 2 and "fewer than 3" in res.message
    assert np.isfinite(res.vertices).all()
    assert res.regularized_frames == [3, 4]
    # without markers the pose follows the constant-velocity prediction and the shape the prior
    gap_error = np.linalg.norm(res.vertices[3:5] - true[3:5], axis=2).max()
    assert gap_error < 0.2, gap_error  # measured 0.056 (bar length 6)
    # temporal term (vertex space): noisy markers on a smooth motion give a smoother fit with it
    s = np.linspace(0, 1, 12)
    true = np.array([bar_pose(X0, 0.6 * v, 0.3 * v) for v in s])
    noisy = surface_points(true, F, binding) + 0.01 * np.random.default_rng(4).standard_normal((12, 20, 3))
    acc = [np.linalg.norm(np.diff(fit_markers(model, noisy, binding, temporal_weight=w, rate=60).vertices, 2,
                                  axis=0), axis=2).mean() for w in (0.0, 10.0)]
    assert acc[1] < 0.85 * acc[0], acc  # measured 0.0169 vs 0.0237
    # without a frame rate the frames are not known to be a recording: no temporal term
    plain = fit_markers(model, noisy, binding)
    assert plain.temporal_weight == 0.0
    assert np.abs(plain.vertices - fit_markers(model, noisy, binding, temporal_weight=0.0).vertices).max() < 1e-9


def test_bind_markers_recovers_a_binding_after_a_rigid_motion(bar):
    X0, F, _, _ = bar
    X = bar_pose(X0, 0.4, 0.2)
    b = _surface_binding(F, 25, seed=5)
    binding = MarkerBinding.from_surface(b.faces, b.barycentric, np.full(25, 0.05))  # one offset, as in mocap
    R = Rotation.from_rotvec([0.05, 0.0, 0.02]).as_matrix()
    x = surface_points(X, F, binding) @ R.T + [0.02, 0.01, 0.0]   # markers slightly off the mesh's frame
    found, info = bind_markers(X, F, x, iterations=200)
    assert np.abs(info["rotation"] @ R - np.eye(3)).max() < 1e-5     # measured 8e-7
    assert np.abs(surface_points(X, F, found) - surface_points(X, F, binding)).max() < 1e-4  # measured 8e-6
    assert np.array_equal(found.faces, binding.faces)
    assert np.abs(found.offsets - 0.05).max() < 1e-4
    # without the alignment the binding is off by the misplacement
    off, off_info = bind_markers(X, F, x, align=False)
    assert off_info["iterations"] == 0
    assert np.abs(surface_points(X, F, off) - surface_points(X, F, binding)).max() > 0.05
    # progress after every ICP iteration (the add-on's progress bar); True cancels
    seen = []
    again, again_info = bind_markers(X, F, x, iterations=200,
                                     progress=lambda done, total, message: seen.append((done, total)))
    assert seen[0] == (0, 200) and seen[-1] == (200, 200) and len(seen) > 3
    assert [d for d, _ in seen[1:-1]] == list(range(1, len(seen) - 1))  # one per iteration until convergence
    assert again_info["iterations"] == seen[-2][0]  # the last one reported
    assert np.array_equal(again.faces, found.faces)
    with pytest.raises(Cancelled):
        bind_markers(X, F, x, progress=lambda done, total, message: done >= 2)


def test_bind_markers_stops_when_noisy_markers_keep_switching_faces(bar):
    """Noise and markers' own offsets leave ICP in a limit cycle: it stops at its best placement, not the limit."""
    X0, F, _, _ = bar
    X = bar_pose(X0, 0.4, 0.2)
    binding = _surface_binding(F, 25, seed=5, offset=0.05)                  # offsets 0.025-0.075
    R = Rotation.from_rotvec([0.05, 0.0, 0.02]).as_matrix()
    x = surface_points(X, F, binding) @ R.T + [0.02, 0.01, 0.0]
    x = x + 0.005 * np.random.default_rng(1).standard_normal(x.shape)
    seen = []
    found, info = bind_markers(X, F, x, iterations=200, progress=lambda done, total, message: seen.append(done))
    assert seen[-2] <= 40, seen[-2]                                          # measured 25 (200 before: the limit)
    assert info["iterations"] == seen[-2]        # stopped before the next rigid fit: the last one reported
    assert np.abs(info["rotation"] @ R - np.eye(3)).max() < 0.01           # measured 0.0034 (0.0057 after 200)
    assert np.array_equal(found.faces, binding.faces)
    assert np.abs(surface_points(X, F, found) - surface_points(X, F, binding)).max() < 0.04   # measured 0.023


def test_bad_input_errors(bar):
    X0, F, model, binding = bar
    x = surface_points(X0, F, binding)
    with pytest.raises(MarkerBindingError, match="out of range"):
        MarkerBinding.from_vertices([0, len(X0)], F)
    with pytest.raises(MarkerBindingError, match="bound to nothing"):
        MarkerBinding.from_vertices([0, -1], F)
    with pytest.raises(MarkerBindingError, match="out of range"):
        fit_markers(model, x[:2], MarkerBinding.from_surface([0, len(F)], np.full((2, 3), 1 / 3)))
    with pytest.raises(MarkerBindingError, match="21 markers, the binding 20"):
        fit_markers(model, np.vstack([x, x[:1]]), binding)
    with pytest.raises(MarkerBindingError, match="do not sum to 1"):
        MarkerBinding.from_surface([0], [[0.5, 0.5, 0.5]])
    bad = x.copy()
    bad[4, 1] = np.inf
    with pytest.raises(MarkerDataError, match=r"\(0, 4\)"):
        fit_markers(model, bad, binding)
    with pytest.raises(ValueError, match="prior_weight"):
        fit_markers(model, x, binding, prior_weight=0.0)
    for rate, words in ((0.0, "positive number"), (np.nan, "positive number"), (1e300, "overflows")):
        with pytest.raises(InputError, match=words):
            fit_markers(model, x[None], binding, rate=rate)


def test_safeguard_keeps_triangles_from_collapsing(bar):
    """Outlier markers and a weak prior: without the compression penalty Gauss-Newton squashes triangles to ~zero
    area (where the dihedral-angle gradients explode); with it no face falls below 25 % of its reference-mesh area, at
    the same energy to 0.1 %."""
    X0, F, model, binding = bar
    b = MarkerBinding.from_vertices(binding.vertices, F)
    x = surface_points(bar_pose(X0, 0.5, 0.2), F, b)
    x[0] += [0.0, 0.0, -1.5]
    x[1] += [0.0, 1.5, 0.0]
    a0 = face_areas(model.reference_vertices, F)
    # the training ellipsoid off: with these outliers it adds its own energy to both fits
    opts = {"prior_weight": 1e-3, "max_iterations": 50, "ftol": 1e-9, "marker_tolerance": 0.0, "reuse_schur": False,
            "coefficient_weight": 0.0}
    off = fit_markers(model, x, b, compression_ratio=None, **opts)
    on = fit_markers(model, x, b, **opts)
    ratio_off = (face_areas(off.vertices[0], F) / a0).min()
    ratio_on = (face_areas(on.vertices[0], F) / a0).min()
    assert ratio_off < 0.15, ratio_off    # measured 0.047 (7e-10 before angle residuals were wrapped)
    assert ratio_on > 0.2, ratio_on       # measured 0.24999 (a penalty, not a hard bound)
    assert on.frame_energy[0] < 1.05 * off.frame_energy[0]  # measured 0.02289 vs 0.02248


# ----------------------------------------------------------------------------- non-penetration term


def _crossing_bars():
    """Bar A along x held by markers; bar B across it, bent so that its middle dips into A's top, held at its
    ends; the prior's mean is B bent (mean-only prior): the fit keeps B's middle inside A unless the
    non-penetration term pushes it out."""
    from lacore.geometry.lengths_angles import lengths_and_angles
    X0, F0 = bar_mesh(n_along=12)
    V0 = len(X0)
    B = bar_pose(X0, 0.8, 0.0)
    e = B[-1] - B[-2]                                      # level the chord between the cap centres
    t = -np.arctan2(e[2], e[0])
    B = B @ np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])
    B = B[:, [1, 0, 2]] + [3.0, 0.0, 0.0]
    B[:, 1] -= 0.5 * (B[:, 1].min() + B[:, 1].max())
    B[:, 2] += 0.5 - 0.1 - B[:, 2].min()                   # 0.1 into A's top face (z = 0.5)
    rest = np.vstack([X0, X0 + [0, 0, 3.0]])
    F = np.vstack([F0, F0 + V0])
    X = np.vstack([X0, B])
    train = np.array([np.vstack([bar_pose(X0, b, 0), bar_pose(X0, b, 0) + [0, 0, 3]]) for b in np.linspace(-1, 1, 5)])
    model = ShapeModel.fit(train, F, n_modes=2, reference_vertices=rest)
    held = np.concatenate([np.arange(V0), V0 + np.flatnonzero(np.abs(X0[:, 0] - 3) > 2.0)])
    return model, X, F, MarkerBinding.from_vertices(held, F), X[held], lengths_and_angles(X, model.topology)


def test_penetration_term_derivatives_match_finite_differences(bar):
    X0, F, model, binding = bar
    solver = FrameSolver(model, binding, FitOptions(prior_weight=0.7, penetration_weight=3.0))
    X = bar_pose(X0, 0.5, -0.3)
    x = surface_points(bar_pose(X0, 0.7, -0.2), F, binding)
    vis = np.arange(len(x))
    rng = np.random.default_rng(5)
    K = 30
    solver.pen_v, solver.pen_f = rng.integers(0, len(X), K), rng.integers(0, len(F), K)
    solver.pen_n = np.linalg.qr(rng.standard_normal((3, 3)))[0][rng.integers(0, 3, K)]
    r, act = solver._penetration(X)
    assert 0 < len(act) < K
    g, dofs = solver._penetration_jacobian(act)
    d = rng.standard_normal(X.shape)
    fd = directional_fd(lambda Y: solver._penetration(Y)[0][act], X, d, 1e-4)
    assert relative_error(np.einsum("kj,kj->k", g, d.ravel()[dofs]), fd) < 1e-9        # measured 1e-11
    a = np.zeros(model.n_modes)
    gX, _ = solver.gradient(X, a, x, vis)
    fde = directional_fd(lambda Y: solver.energy(Y, a, x, vis)[0], X, d, 1e-4)
    assert abs(gX @ d.ravel() - fde) < 1e-7 * abs(fde)                                 # measured 4e-10


def test_penetration_term_pushes_crossing_corners_out():
    model, X, F, binding, y, mean_z = _crossing_bars()
    off = FrameSolver(model, binding, FitOptions(prior_weight=1.0, n_modes=0, penetration_weight=0.0), mean_z=mean_z)
    assert off.solve_frame_apart(X, np.zeros(0), y)[5] == -1                          # 0: off
    solver = FrameSolver(model, binding, FitOptions(prior_weight=1.0, n_modes=0, penetration_weight=10.0),
                         mean_z=mean_z)
    Xf, a, st, it, E = solver.solve_frame(X, np.zeros(0), y)
    pairs, added = solver.add_penetrations(Xf, y)
    assert len(pairs) > 0 and added > 0
    r0 = solver._penetration(Xf)[0]
    assert r0.max() > 0.5                                  # corners 0.2-0.8 edge lengths below the other face
    X2, a, st, it, E = solver.solve_frame(Xf, a, y)
    assert st == 0 and solver._penetration(X2)[0].max() < 0.15                         # measured 0.09
    assert solver.add_penetrations(X2, y)[1] >= 0


@pytest.mark.parametrize("script, weights, kept", [
    ([(3, 2), (3, 1), (0, 0)], [1, 1, 10], 0),            # a round that did not reduce them: once more, stronger
    ([(3, 2), (3, 1), (4, 0)], [1, 1, 10], 3),            # the stronger round did not either: the first fit stays
    ([(5, 2), (3, 1), (2, 1)], [1, 1, 1], 2),             # every round reduces them: PENETRATION_ROUNDS rounds
    ([(3, 2), (2, 0), (0, 0)], [1, 1, 10], 0),            # constraints everywhere but crossings left: stronger
    ([(3, 0)], [1], 3),                                   # crossings but no constraint to make stronger: no round
])
def test_penetration_rounds_escalate_once(monkeypatch, script, weights, kept):
    """solve_frame_apart: rounds while they reduce the crossings; the first that does not (or crossings left with
    every constraint in place) is followed by one round with the weight PENETRATION_ESCALATION times higher, for
    that frame only; the fit with the fewest crossings is kept."""
    from lacore.markers.fitting import PENETRATION_ESCALATION, PENETRATION_ROUNDS

    model, X, F, binding, y, mean_z = _crossing_bars()
    solver = FrameSolver(model, binding, FitOptions(prior_weight=1.0, n_modes=0, penetration_weight=10.0),
                         mean_z=mean_z)
    used, outcomes = [], iter(script)
    monkeypatch.setattr(solver, "solve_frame", lambda X, a, y, *args: used.append(solver.w_p) or (X, a, 0, 1, 1.0))

    def add(X, y):                                        # k new constraints on n crossing pairs
        n, k = next(outcomes)
        solver.pen_v = np.arange(len(solver.pen_v) + k)
        return np.zeros((n, 2), int), k

    monkeypatch.setattr(solver, "add_penetrations", add)
    assert PENETRATION_ROUNDS == 2 and PENETRATION_ESCALATION == 10.0
    n = solver.solve_frame_apart(X, np.zeros(0), y)[5]
    assert [w / 10.0 for w in used] == weights and n == kept and solver.w_p == 10.0


def test_fit_reports_self_intersections_only_with_the_term(bar):
    X0, F, model, binding = bar
    x = surface_points(np.array([bar_pose(X0, 0.3 * k, 0.0) for k in range(3)]), F, binding)
    assert fit_markers(model, x, binding, prior_weight=1.0,
                       penetration_weight=0.0).frame_self_intersections is None                  # 0: off
    res = fit_markers(model, x, binding, prior_weight=1.0)                                       # default: on
    assert res.frame_self_intersections.tolist() == [0, 0, 0]          # a bent bar does not pass through itself
    assert res.summary()["frame_self_intersections"] == [0, 0, 0]


def test_frame_start_is_the_extrapolation_of_least_energy(bar):
    """FrameSolver.start: of the previous pose extrapolated by START_EXTRAPOLATIONS, the least energy; scale-free."""
    from lacore.geometry.rigid import apply_rigid, rigid_fit
    from lacore.markers.fitting import START_EXTRAPOLATIONS

    X0, F, model, binding = bar
    assert START_EXTRAPOLATIONS[0] == 1.0 and 0.0 in START_EXTRAPOLATIONS
    P = [bar_pose(X0, 0.6 * v, 0.3 * v) @ ROT.T + SHIFT for v in (0.2, 0.3, 0.4)]
    noise = 0.05 * np.random.default_rng(3).standard_normal(X0.shape)
    chosen = {}
    for scale in (1.0, 1000.0):            # the same bar in metres and millimetres
        m = ShapeModel.fit(_training_poses(X0, scale), F, n_modes=4)
        b = MarkerBinding.from_surface(binding.faces, binding.barycentric, binding.offsets * scale)
        solver = FrameSolver(m, b, FitOptions(), temporal=10.0)
        y = surface_points(P[2] * scale, F, b)
        a = np.zeros(solver.J)
        for name, (X, Xp) in {"smooth": (P[1], P[0]), "noisy": (P[1], P[1] + noise)}.items():
            X, Xp = X * scale, Xp * scale
            cands = []
            for beta in START_EXTRAPOLATIONS:
                Xb = X + beta * (X - Xp)
                Xb = apply_rigid(Xb, *rigid_fit(surface_points(Xb, F, b), y))
                cands.append(Xb)
            solver.X_hat = cands[0]
            E = np.array([solver.energy(Xb, a, y, np.arange(b.n_markers))[0] for Xb in cands])
            Xs, as_ = solver.start(X, a, Xp, a, y)
            k = int(np.argmin(E))
            assert np.allclose(Xs, cands[k], rtol=0, atol=1e-9 * scale) and np.array_equal(as_, a)
            chosen[name, scale] = (START_EXTRAPOLATIONS[k], E)
    # a smooth motion: the energies of all candidates are small (measured 0.067, 0.064, 0.094 at 1, 0.5, 0)
    assert chosen["smooth", 1.0][1].max() < 0.3, chosen["smooth", 1.0]
    # the previous fit off in directions of its own (noise): the full extrapolation doubles it (measured 25.2),
    # no velocity starts at 0.50
    beta, E = chosen["noisy", 1.0]
    assert beta == 0.0 and E[0] > 20 * E.min(), E
    for name in ("smooth", "noisy"):       # scale-free: the same choice and energies in mm
        assert chosen[name, 1.0][0] == chosen[name, 1000.0][0]
        assert np.allclose(chosen[name, 1.0][1], chosen[name, 1000.0][1], rtol=1e-6)


def _training_poses(X0, scale):
    """The bar fixture's 12 training poses, scaled."""
    return scale * np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 4) for tw in np.linspace(-1, 1, 3)])


def test_a_full_step_reuses_its_factorization_once(bar, monkeypatch):
    """FitOptions.reuse_factor: after a short full step on a new factorization (temporal term on) the next step reuses
    it; on a smooth noisy motion that saves factorizations and the fit stays where the one refactorizing every step
    ends."""
    X0, F, model, binding = bar
    s = np.linspace(0, 1, 12)
    true = np.array([bar_pose(X0, 0.6 * v, 0.3 * v) for v in s]) @ ROT.T + SHIFT
    noisy = surface_points(true, F, binding) + 0.01 * np.random.default_rng(4).standard_normal((12, 20, 3))
    calls = []
    factorize = FrameSolver.factorize

    def counted(self, *args, **kwargs):
        calls.append(1)
        return factorize(self, *args, **kwargs)
    monkeypatch.setattr(FrameSolver, "factorize", counted)
    runs = {}
    for reuse in (False, True):
        calls.clear()
        res = fit_markers(model, noisy, binding, rate=60, reuse_factor=reuse)
        runs[reuse] = res, len(calls), int(res.frame_iterations.sum())
    (off, n_off, it_off), (on, n_on, it_on) = runs[False], runs[True]
    assert off.success and on.success, (off.message, on.message)
    assert n_off == it_off                         # without reuse: one factorization per step
    assert n_on <= 0.75 * n_off, (n_on, n_off)     # measured 17 vs 27 (frames 0 and 1: no temporal term)
    assert it_on <= 1.2 * it_off, (it_on, it_off)  # measured 27 vs 27 steps
    gap = np.linalg.norm(on.vertices - off.vertices, axis=2).max()
    assert gap < 0.005, gap                        # bar length 6; measured 0.00046
    err = [np.linalg.norm(r.vertices - true, axis=2).mean() for r in (off, on)]
    assert err[1] < 1.1 * err[0], err              # measured 0.00967 vs 0.00967 (marker noise 0.01)
    assert abs(on.marker_rms - off.marker_rms) < 0.02 * off.marker_rms, (on.marker_rms, off.marker_rms)


def test_factorization_reused_only_with_the_temporal_term_and_the_safeguard_covered(bar):
    """Without the temporal term (a single frame from the rest pose: long steps) every step refactorizes: the fit is
    the one of reuse_factor=False to the last bit; a factorization does not serve a point where the compression
    safeguard penalizes a face outside the faces its matrix covers."""
    X0, F, model, binding = bar
    true = bar_pose(X0, 0.9, 0.6)
    x = surface_points(true, F, binding)
    on, off = fit_markers(model, x, binding), fit_markers(model, x, binding, reuse_factor=False)
    assert np.array_equal(on.vertices, off.vertices) and np.array_equal(on.frame_iterations, off.frame_iterations)
    solver = FrameSolver(model, binding, FitOptions(), temporal=10.0)
    X = bar_pose(X0, 0.5, 0.2)
    vis = np.arange(binding.n_markers)
    solver.factorize(X, np.zeros(solver.J), x, vis)
    assert solver._covers_compression(X)
    f = int(np.argmax(face_areas(X, F)))
    squashed = X.copy()
    squashed[F[f, 2]] = X[F[f, :2]].mean(0) + 0.2 * (X[F[f, 2]] - X[F[f, :2]].mean(0))   # the face at 20 % area
    ratio = face_areas(squashed, F) / face_areas(model.reference_vertices, F)
    assert ratio[f] < 0.25 and f not in solver._near
    assert not solver._covers_compression(squashed)


def test_frame_start_returns_its_energy(bar):
    """FrameSolver.start(return_energy=True) gives the chosen start's energy (solve_frame starts from it)."""
    X0, F, model, binding = bar
    P = [bar_pose(X0, 0.6 * v, 0.3 * v) for v in (0.2, 0.3, 0.4)]
    solver = FrameSolver(model, binding, FitOptions(), temporal=10.0)
    y = surface_points(P[2], F, binding)
    a = np.zeros(solver.J)
    solver.X_hat = 2 * P[1] - P[0]
    Xs, as_, E = solver.start(P[1], a, P[0], a, y, return_energy=True)
    assert E == pytest.approx(solver.energy(Xs, as_, y, np.arange(binding.n_markers))[0], rel=1e-12)
    assert np.array_equal(Xs, solver.start(P[1], a, P[0], a, y)[0])


def test_log_length_target_reproduces_training_lengths_and_stays_positive(bar):
    """The prior's target lengths (FrameSolver.target): with log lengths (the default) the mean's times the exponential
    of the log-length modes' combination saturated near each edge's training range, reproducing the training poses'
    lengths from their coefficients and within the margin of that range however far the coefficients go; linear
    lengths cross 0 there.  The target's Jacobian matches finite differences."""
    from lacore.geometry.lengths_angles import lengths_and_angles
    X0, F, model, binding = bar
    E = model.topology.n_edges
    log = FrameSolver(model, binding, FitOptions(observed_radius=None))
    lin = FrameSolver(model, binding, FitOptions(observed_radius=None, log_lengths=False))
    T = model.training_coefficients
    train = np.array([bar_pose(X0, b, tw) for b in np.linspace(-1, 1, 4) for tw in np.linspace(-1, 1, 3)])
    true = np.array([lengths_and_angles(X, model.topology)[:E] for X in train])
    err_log = max(np.abs(log.target(a)[:E] / l - 1).max() for a, l in zip(T, true, strict=True))
    err_lin = max(np.abs(lin.target(a)[:E] / l - 1).max() for a, l in zip(T, true, strict=True))
    assert err_log < 0.03 and err_lin < 0.03, (err_log, err_lin)     # measured 0.0090 and 0.0056 (4 modes)
    far = 30.0 * T[np.argmax(np.abs(T[:, 0])), :] / np.abs(T[:, 0]).max()
    assert lin.target(far)[:E].min() < 0 < log.target(far)[:E].min()
    # each edge's log-length target saturates within LENGTH_RANGE_MARGIN of its range over the training poses
    s = np.log(log.target(far)[:E] / model.mean_z[:E])
    lo, hi = log.log_range
    m = LENGTH_RANGE_MARGIN
    assert np.all(s <= hi + m + 1e-12) and np.all(s >= lo - m - 1e-12)
    assert np.sum(s > hi + 0.9 * m) + np.sum(s < lo - 0.9 * m) > E // 4    # measured 240 of 600 edges
    assert np.allclose(log.target(far)[E:], lin.target(far)[E:])     # angles: linear either way
    t, Jt = log.target(0.3 * far, jacobian=True)
    d = np.random.default_rng(5).standard_normal(len(far))
    fd = directional_fd(log.target, 0.3 * far, d, 1e-6)
    assert relative_error(Jt @ d, fd) < 1e-7                         # measured 1e-9
