"""Discrete geodesics in the space of lengths and angles (thesis 2.2, 4.1, eq. 4.6; figures 4.1/4.2).

Covers the path-energy identities (2.6), (2.7), (4.9), finite-difference checks
of every derivative the solvers use, the Schur-complement KKT solve, the
cross-check SQP in ``z`` vs Gauss-Newton in vertex positions, and the thesis'
qualitative claim on the 121-vertex rolled plates: the constrained geodesic is
(nearly) equidistant, the projected linear path is not.
"""

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import load_mesh
from fd import directional_fd, relative_error

from lacore.progress import Cancelled
from lacore.energies import QuadraticEnergy, ThinShellsEnergy
from lacore.errors import LengthsAnglesError, MeshError
from lacore.reconstruction import ReconstructionSettings
from lacore.shapes.geodesic_solvers import _SchurKKT, _vertex_path_linearization
from lacore.shapes.geodesics import GeodesicOptions, discrete_geodesic, projected_linear_path
from lacore.shapes.path_energy import (QuadraticPathModel, _time_laplacian_inverse, default_energy, linear_path,
                                       path_energy, path_energy_profile)
from lacore.integrability.local import euler_integrability_jacobian, euler_integrability_map
from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.geometry.topology import MeshTopology

N_STEPS = 8


@pytest.fixture(scope="module")
def plates():
    XA, F = load_mesh("plate/plate121_rolledA.ply")
    XB, _ = load_mesh("plate/plate121_rolledB.ply")
    topo = MeshTopology.from_faces(F, n_vertices=len(XA))
    return topo, XA, XB


@pytest.fixture(scope="module")
def plate_geodesics(plates):
    """Both geodesic solvers and the projected linear path on rolledA -> rolledB, K = 8."""
    topo, XA, XB = plates
    sqp = discrete_geodesic(XA, XB, topo, N_STEPS, method="sqp")
    vert = discrete_geodesic(XA, XB, topo, N_STEPS, method="vertices")
    z_lin, X_lin = projected_linear_path(XA, XB, topo, N_STEPS)
    np.testing.assert_allclose(z_lin, [lengths_and_angles(X, topo) for X in X_lin], rtol=1e-14, atol=1e-14)
    return sqp, vert, z_lin


def _random_path(topo, X0, X1, K, seed):
    rng = np.random.default_rng(seed)
    zs = linear_path(lengths_and_angles(X0, topo), lengths_and_angles(X1, topo), K)
    zs[1:-1] += 1e-3 * rng.standard_normal(zs[1:-1].shape)
    return zs


# --------------------------------------------------------------------------- path energy identities
def test_time_laplacian_inverse_closed_form():
    for m in range(1, 7):
        T = np.diag(2.0 * np.ones(m)) - np.diag(np.ones(m - 1), 1) - np.diag(np.ones(m - 1), -1)
        np.testing.assert_allclose(T @ _time_laplacian_inverse(m), np.eye(m), atol=1e-13)


def test_linear_path_is_the_unconstrained_geodesic_of_wq(plates):
    """(4.9): the equidistant linear path minimizes the path energy of W_q in R^2E.

    Its gradient vanishes, its steps have equal energy W[z_0, z_K] / K^2 and its
    path energy (2.7) is W[z_0, z_K] for every K.
    """
    topo, XA, XB = plates
    energy = default_energy(topo, XA)
    z0, zK = lengths_and_angles(XA, topo), lengths_and_angles(XB, topo)
    W = energy.value(z0, zK)
    assert W > 0.1
    for K in (1, 2, 3, 5, 8):
        zs = linear_path(z0, zK, K)
        np.testing.assert_allclose(path_energy_profile(zs, energy), W / K**2, rtol=1e-12)
        assert path_energy(zs, energy) == pytest.approx(W, rel=1e-12)
        if K >= 2:
            g = QuadraticPathModel(energy.residual_weights, K).gradient(zs)
            assert np.abs(g).max() < 1e-12 * np.abs(energy.gradient(z0, zK, 0)).max()
    # any perturbation of the interior increases the path energy (strictly convex quadratic)
    zs = _random_path(topo, XA, XB, 4, seed=1)
    assert path_energy(zs, energy) > W


def test_cauchy_schwarz_lower_bound(plates):
    """(2.6)/(2.7): ``L^K[Y]^2 <= E^K[Y]`` with equality iff all steps have equal energy."""
    topo, XA, XB = plates
    energy = default_energy(topo, XA)
    zs = _random_path(topo, XA, XB, 5, seed=2)
    prof = path_energy_profile(zs, energy)
    length = np.sum(np.sqrt(prof))
    assert length**2 < path_energy(zs, energy) * (1 - 1e-6)
    zl = linear_path(zs[0], zs[-1], 5)
    assert np.sum(np.sqrt(path_energy_profile(zl, energy))) ** 2 == pytest.approx(path_energy(zl, energy), rel=1e-12)


def test_path_energy_profile_checks_its_input(plates):
    topo, XA, _ = plates
    energy = default_energy(topo, XA)
    z = lengths_and_angles(XA, topo)
    with pytest.raises(LengthsAnglesError, match="K >= 1"):
        path_energy_profile(z[None], energy)
    bad = np.array([z, z])
    bad[1, 3] = np.nan
    with pytest.raises(LengthsAnglesError, match="NaN"):
        path_energy(bad, energy)


# --------------------------------------------------------------------------- derivatives (finite differences)
def test_path_model_gradient_and_hessian_match_finite_differences(plates):
    topo, XA, XB = plates
    energy = default_energy(topo, XA)
    K = 4
    model = QuadraticPathModel(energy.residual_weights, K)
    zs = _random_path(topo, XA, XB, K, seed=3)
    rng = np.random.default_rng(4)
    D = rng.standard_normal((K - 1, zs.shape[1]))

    def value(y):
        full = zs.copy()
        full[1:-1] = y.reshape(K - 1, -1)
        return model.value(full)

    def grad(y):
        full = zs.copy()
        full[1:-1] = y.reshape(K - 1, -1)
        return model.gradient(full).ravel()

    y0 = zs[1:-1].ravel()
    fd = directional_fd(value, y0, D.ravel(), 1e-4)
    an = float(np.sum(model.gradient(zs) * D))
    assert abs(fd - an) <= 1e-8 * abs(an)
    d = model.hessian_diagonal()
    fd_h = directional_fd(grad, y0, D.ravel(), 1e-4)
    assert relative_error(model.apply_hessian(D, d).ravel(), fd_h) < 1e-8
    # the value agrees with the energy object: K sum W[z_i, z_i+1]
    assert model.value(zs) == pytest.approx(path_energy(zs, energy), rel=1e-13)
    # H^-1 is the inverse of H on the variables with positive weight (lengths and interior angles)
    E = topo.n_edges
    free = np.r_[np.arange(E), E + topo.interior_edges]
    df = model.hessian_diagonal(free)
    np.testing.assert_allclose(model.solve_hessian(model.apply_hessian(D[:, free], df), df), D[:, free],
                               rtol=1e-9, atol=1e-12)


def test_vertex_path_gradient_and_gauss_newton_matrix(plates):
    """Gradient ``J^T g`` vs finite differences of the path energy in vertex coordinates; at a path with
    zero residuals (all points equal) the Gauss-Newton matrix ``J^T H J`` is the exact Hessian."""
    topo, XA, XB = plates
    energy = default_energy(topo, XA)
    K = 3
    model = QuadraticPathModel(energy.residual_weights, K)
    cols = np.arange(3 * topo.n_vertices)
    rng = np.random.default_rng(5)
    Xi = np.array([XA + 0.01 * rng.standard_normal(XA.shape), XB + 0.01 * rng.standard_normal(XB.shape)])
    zs = linear_path(lengths_and_angles(XA, topo), lengths_and_angles(XB, topo), K)
    f, grad, N, _ = _vertex_path_linearization(Xi, zs.copy(), topo, model, cols)
    D = rng.standard_normal(Xi.shape)

    def value(x):
        return _vertex_path_linearization(x.reshape(Xi.shape), zs.copy(), topo, model, cols)[0]

    fd = directional_fd(value, Xi.ravel(), D.ravel(), 1e-5)
    assert abs(fd - grad @ D.ravel()) <= 1e-7 * abs(fd)
    assert f == pytest.approx(path_energy(np.r_[zs[:1], [lengths_and_angles(x, topo) for x in Xi], zs[-1:]],
                                          energy), rel=1e-13)
    # zero residuals: z_0 = z_K = Z(XA) and X_1 = X_2 = XA
    z0 = lengths_and_angles(XA, topo)
    zs0 = np.array([z0] * (K + 1))
    X0 = np.array([XA, XA])
    _, g0, N0, _ = _vertex_path_linearization(X0, zs0.copy(), topo, model, cols)
    assert np.abs(g0).max() < 1e-12

    def grad_at(x):
        return _vertex_path_linearization(x.reshape(X0.shape), zs0.copy(), topo, model, cols)[1]

    fd_h = directional_fd(grad_at, X0.ravel(), D.ravel(), 1e-5)
    assert relative_error(N0 @ D.ravel(), fd_h) < 1e-7


def test_schur_complement_solves_the_kkt_system(plates):
    topo, XA, XB = plates
    energy = default_energy(topo, XA)
    K = 3
    model = QuadraticPathModel(energy.residual_weights, K)
    E = topo.n_edges
    free = np.r_[np.arange(E), E + topo.interior_edges]
    zs = _random_path(topo, XA, XB, K, seed=6)
    blocks = [euler_integrability_jacobian(z, topo)[:, free].tocsr() for z in zs[1:-1]]
    d = model.hessian_diagonal(free)
    kkt = _SchurKKT(model, d, 1e-12)
    kkt.factorize(blocks)
    rng = np.random.default_rng(7)
    r1 = rng.standard_normal((K - 1, len(free)))
    r2 = rng.standard_normal(sum(b.shape[0] for b in blocks))
    p, y = kkt.solve(r1, r2)
    H = sp.kron(model.T, sp.diags(d))
    A = sp.block_diag(blocks)
    M = sp.bmat([[H, A.T], [A, -kkt.delta * sp.identity(A.shape[0])]]).toarray()
    rhs = np.r_[r1.ravel(), r2]
    res = M @ np.r_[p.ravel(), y] - rhs
    assert np.abs(res).max() < 1e-9 * np.abs(rhs).max()
    assert 0 < kkt.delta < 1e-8


# --------------------------------------------------------------------------- geodesic on the rolled plates
def test_plate_geodesic_sqp_and_vertices_agree(plates, plate_geodesics):
    """The same geodesic (4.6) from constrained SQP in z and from Gauss-Newton in vertex positions."""
    topo, XA, XB = plates
    sqp, vert, _ = plate_geodesics
    print(f"\nplate geodesic K={N_STEPS}: SQP E={sqp.path_energy:.15g} ({sqp.iterations} it, {sqp.seconds:.2f} s), "
          f"vertices E={vert.path_energy:.15g} ({vert.iterations} it, {vert.seconds:.2f} s)")
    assert sqp.success and vert.success, (sqp.message, vert.message)
    assert sqp.path_energy == pytest.approx(vert.path_energy, rel=1e-6)
    assert abs(sqp.path_energy - vert.path_energy) <= 1e-9 * sqp.path_energy  # achieved: ~1e-15
    np.testing.assert_allclose(sqp.step_energies, vert.step_energies, rtol=1e-5)
    # the same path, not just the same energy
    assert np.abs(sqp.z - vert.z).max() < 1e-5
    # end points are fixed
    np.testing.assert_array_equal(sqp.z[0], lengths_and_angles(XA, topo))
    np.testing.assert_array_equal(sqp.z[-1], lengths_and_angles(XB, topo))
    # admissible: integrability at every interior point, triangle inequalities on the whole path
    assert sqp.constraint_violation < 1e-8
    assert max(np.abs(euler_integrability_map(z, topo)).max() for z in sqp.z[1:-1]) < 1e-8
    assert sqp.min_triangle_margin > 0 and vert.min_triangle_margin > 0
    # vertex method: its immersions realize its z path
    for X, z in zip(vert.vertices, vert.z, strict=True):
        assert np.abs(lengths_and_angles(X, topo) - z).max() < 1e-12


def test_plate_geodesic_kkt_conditions(plates, plate_geodesics):
    """First-order optimality of (4.6): ``dE/dz_i + A_i^T lambda_i = 0`` with the returned multipliers."""
    topo, XA, _ = plates
    sqp, _, _ = plate_geodesics
    energy = default_energy(topo, XA)
    model = QuadraticPathModel(energy.residual_weights, N_STEPS)
    E = topo.n_edges
    free = np.r_[np.arange(E), E + topo.interior_edges]
    g = model.gradient(sqp.z)[:, free]
    r = np.stack([euler_integrability_jacobian(z, topo)[:, free].T @ lam
                  for z, lam in zip(sqp.z[1:-1], sqp.multipliers, strict=True)])
    assert np.abs(g).max() > 1e-3  # the constraints are active: the unconstrained gradient is not zero
    assert np.abs(g + r).max() < 1e-7 * np.abs(g).max()


def test_plate_geodesic_is_equidistant_unlike_the_projected_linear_path(plates, plate_geodesics):
    """Figures 4.1 / 4.2: the projected linear path has uneven step energies, the geodesic nearly equal ones."""
    topo, XA, _ = plates
    sqp, _, z_lin = plate_geodesics
    energy = default_energy(topo, XA)
    prof_lin = path_energy_profile(z_lin, energy)
    prof_geo = sqp.step_energies
    ratio_lin = prof_lin.max() / prof_lin.min()
    ratio_geo = prof_geo.max() / prof_geo.min()
    e_lin = path_energy(z_lin, energy)
    print(f"\nprojected linear path: E={e_lin:.6g}, steps {np.array2string(prof_lin, precision=5)}, "
          f"max/min {ratio_lin:.3f}")
    print(f"discrete geodesic:     E={sqp.path_energy:.6g}, steps {np.array2string(prof_geo, precision=5)}, "
          f"max/min {ratio_geo:.4f}")
    # the thesis' claim, with the numbers obtained (K = 8): geodesic ratio ~1.028, linear ~9.0
    assert ratio_geo < 1.05
    assert ratio_lin > 3.0 * ratio_geo
    assert np.std(prof_geo) / np.mean(prof_geo) < 0.1 * np.std(prof_lin) / np.mean(prof_lin)
    assert sqp.path_energy <= e_lin
    assert sqp.path_energy < 0.9 * e_lin
    # the solver started from the projected linear path and decreased its energy
    assert sqp.initial_path_energy == pytest.approx(e_lin, rel=1e-6)
    assert sqp.path_energy < sqp.initial_path_energy
    # linear convergence down to round-off (the SQP iterates are not feasible, so not monotone)
    assert abs(sqp.history["path_energy"][-1] - sqp.path_energy) < 1e-13


def test_sqp_from_the_unprojected_linear_path(plates):
    """An infeasible start (the linear path in z) reaches the same geodesic (K = 4)."""
    topo, XA, XB = plates
    a = discrete_geodesic(XA, XB, topo, 4, method="sqp", initial="linear")
    b = discrete_geodesic(XA, XB, topo, 4, method="vertices")
    assert a.history["constraint_violation"][0] > 1e-2
    assert a.success and b.success
    assert a.path_energy == pytest.approx(b.path_energy, rel=1e-9)
    assert a.constraint_violation < 1e-8


def test_sqp_stops_at_round_off_from_the_linear_path():
    """From the linear path in z the SQP of a bent-to-twisted bar reaches the geodesic, then accepts steps of
    2^-31 that change nothing: it stops there as converged, not after 200 such steps at the iteration limit."""
    from lacore.samples.bar import bar_mesh, bar_pose

    X, F = bar_mesh(n_along=6, n_side=1)
    topo = MeshTopology.from_faces(F)
    A, B = bar_pose(X, 0.5, 0.0), bar_pose(X, 0.0, 0.5)
    ref = discrete_geodesic(A, B, topo, 3)
    res = discrete_geodesic(A, B, topo, 3, initial="linear")
    assert ref.success and res.success, res.message
    assert res.status == 0 and res.iterations <= 20 and "round-off" in res.message
    assert np.abs(res.z - ref.z).max() < 1e-7
    assert res.path_energy == pytest.approx(ref.path_energy, rel=1e-9)


def test_sqp_reconstructs_vertices(plates):
    topo, XA, XB = plates
    res = discrete_geodesic(XA, XB, topo, 3, options=GeodesicOptions(reconstruct_vertices=True))
    assert res.vertices.shape == (4, topo.n_vertices, 3)
    for X, z in zip(res.vertices, res.z, strict=True):
        assert np.abs(lengths_and_angles(X, topo) - z).max() < 1e-7


def test_vertex_path_has_its_ends_also_from_lengths_and_angles(plates):
    """``method="vertices"`` returns every point's vertices: an end given as (admissible) lengths and angles is
    reconstructed, and K = 1 has its two ends."""
    topo, XA, XB = plates
    zB = lengths_and_angles(XB, topo)
    res = discrete_geodesic(XA, zB, topo, 2, method="vertices")
    assert res.vertices.shape == (3, topo.n_vertices, 3)
    for X, z in zip(res.vertices, res.z, strict=True):
        assert np.abs(lengths_and_angles(X, topo) - z).max() < 1e-6
    one = discrete_geodesic(XA, XB, topo, 1, method="vertices")
    assert one.success and one.vertices.shape == (2, topo.n_vertices, 3)
    assert np.abs(one.vertices[0] - XA).max() < 1e-12


def test_closed_mesh_with_rank_deficient_constraints():
    """Closed surface: the Euler Jacobian has rank 3V - 6 (Conjecture 1); the regularized KKT system copes."""
    X0, F = load_mesh("sphere/defSphere0.ply")
    X1, _ = load_mesh("sphere/defSphere1.ply")
    topo = MeshTopology.from_faces(F, n_vertices=len(X0))
    assert topo.is_closed
    sqp = discrete_geodesic(X0, X1, topo, 2, method="sqp")
    vert = discrete_geodesic(X0, X1, topo, 2, method="vertices")
    assert sqp.success and vert.success, (sqp.message, vert.message)
    assert sqp.constraint_violation < 1e-8
    assert sqp.path_energy == pytest.approx(vert.path_energy, rel=1e-8)
    assert sqp.path_energy <= sqp.initial_path_energy


@pytest.mark.parametrize("genus, holes", [(0, 2), (1, 0)])
def test_holes_and_handles_are_constrained_too(genus, holes):
    """An annulus and a torus: the SQP's interior points close around the hole / the handles as well (Theorem 3.2;
    with the vertex conditions only they missed by 6e-3 rad and 1.5e-2 rad), so SQP in z and Gauss-Newton in
    vertex positions (admissible by construction) find the same geodesic."""
    from lacore.integrability import check_integrability
    from lacore.samples.surfaces import pretzel, pretzel_with_holes
    X0, F = pretzel_with_holes(0, 2, cells=3, radius=0.08) if holes else pretzel(1, cells=3)
    topo = MeshTopology.from_faces(F, n_vertices=len(X0))
    X1 = X0.copy()
    X1[:, 2] += 0.5 * X0[:, 0] ** 2
    X1[:, 1] += 0.2 * np.sin(2 * X0[:, 0])
    sqp = discrete_geodesic(X0, X1, topo, 4, method="sqp")
    vert = discrete_geodesic(X0, X1, topo, 4, method="vertices")
    assert sqp.success and vert.success, (sqp.message, vert.message)
    assert sqp.multipliers.shape == (3, 3 * len(topo.interior_vertices) + 6 * (2 * genus + max(holes - 1, 0)))
    for z in sqp.z[1:-1]:
        check = check_integrability(z, topo)
        assert check.integrable and check.max_holonomy < 1e-10 and check.max_translation < 1e-10
    assert sqp.constraint_violation < 1e-10
    assert sqp.path_energy == pytest.approx(vert.path_energy, rel=1e-6)
    # a tree walk reproduces the midpoint exactly: no seam
    from lacore.reconstruction import reconstruct
    walk = reconstruct(sqp.z[2], topo, X0, method="bfs")
    assert walk.success and walk.checks["outcome"] == "reproduced", walk.message


def test_trivial_geodesics(plates):
    topo, XA, XB = plates
    one = discrete_geodesic(XA, XB, topo, 1)
    energy = default_energy(topo, XA)
    assert one.z.shape == (2, 2 * topo.n_edges)
    assert one.path_energy == pytest.approx(energy.value(one.z[0], one.z[1]), rel=1e-14)
    same = discrete_geodesic(XA, XA, topo, 3, method="sqp")
    assert same.success
    assert same.path_energy < 1e-20
    assert np.abs(same.z - same.z[0]).max() < 1e-9


def test_custom_energy_and_z_inputs(plates):
    topo, XA, XB = plates
    energy = QuadraticEnergy(topo, reference_vertices=XB, weights="heeren", bending_weight=1e-3)
    zA, zB = lengths_and_angles(XA, topo), lengths_and_angles(XB, topo)
    res = discrete_geodesic(zA, zB, topo, 4, energy=energy, reference_vertices=XA)
    assert res.success, res.message
    assert res.path_energy == pytest.approx(path_energy(res.z, energy), rel=1e-13)
    assert res.path_energy < res.initial_path_energy
    other = discrete_geodesic(XA, XB, topo, 4, energy=energy, method="vertices")
    assert other.path_energy == pytest.approx(res.path_energy, rel=1e-9)


def test_geodesic_errors(plates):
    topo, XA, XB = plates
    zA = lengths_and_angles(XA, topo)
    with pytest.raises(ValueError, match="unknown geodesic method"):
        discrete_geodesic(XA, XB, topo, 3, method="newton")
    with pytest.raises(ValueError, match="n_steps"):
        discrete_geodesic(XA, XB, topo, 0)
    with pytest.raises(ValueError, match="n_steps"):
        discrete_geodesic(XA, XB, topo, 2.5)
    with pytest.raises(ValueError, match="n_steps must be a positive integer, got None"):
        discrete_geodesic(XA, XB, topo, None)
    with pytest.raises(ValueError, match="n_steps must be a positive integer, got None"):
        projected_linear_path(XA, XB, topo, None)
    # an end point that is no mesh (the average of two): the geodesic of (4.6) joins two meshes
    z_mid = 0.5 * (zA + lengths_and_angles(XB, topo))
    for method in ("sqp", "vertices"):
        with pytest.raises(LengthsAnglesError, match="end is no mesh's lengths and angles .*not integrable"):
            discrete_geodesic(XA, z_mid, topo, 3, method=method)
    bad = XB.copy()
    bad[4, 1] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        discrete_geodesic(XA, bad, topo, 3)
    with pytest.raises(MeshError, match="vertices"):
        discrete_geodesic(XA, XB[:-1], topo, 3)
    with pytest.raises(LengthsAnglesError, match="shape"):
        discrete_geodesic(zA, zA[:-2], topo, 3, reference_vertices=XA)
    with pytest.raises(ValueError, match="bending_weight > 0"):
        discrete_geodesic(XA, XB, topo, 3, settings=ReconstructionSettings(bending_weight=0.0))
    with pytest.raises(ValueError, match="need the quadratic energy"):
        discrete_geodesic(XA, XB, topo, 3, settings=ReconstructionSettings(energy="shells"))
    with pytest.raises(ValueError, match="max_iterations must be a non-negative integer"):
        GeodesicOptions(max_iterations=2.5)
    with pytest.raises(ValueError, match="max_iterations must be a non-negative integer, got None"):
        GeodesicOptions(max_iterations=None)
    with pytest.raises(TypeError, match="residual_weights"):
        discrete_geodesic(XA, XB, topo, 3, energy=ThinShellsEnergy(topo))
    with pytest.raises(ValueError, match="vertex positions"):
        discrete_geodesic(zA, lengths_and_angles(XB, topo), topo, 3)
    with pytest.raises(ValueError, match="linear path"):
        discrete_geodesic(XA, XB, topo, 3, method="vertices", initial="linear")
    with pytest.raises(LengthsAnglesError, match="initial path"):
        discrete_geodesic(XA, XB, topo, 3, initial=np.zeros((5, 7)))


def test_progress_is_reported_per_iteration_and_can_cancel(plates):
    topo, XA, XB = plates
    seen = []
    res = discrete_geodesic(XA, XB, topo, 2, method="vertices", options=GeodesicOptions(max_iterations=50),
                            progress=lambda d, t, m: seen.append((d, t, m)))
    assert [d for d, _, _ in seen] == list(range(res.iterations)) and all(t == 50 for _, t, _ in seen)
    assert seen[0][2] == "iteration 1 (at most 50)"
    with pytest.raises(Cancelled, match="cancelled after 1 of 50"):
        discrete_geodesic(XA, XB, topo, 2, method="sqp", options=GeodesicOptions(max_iterations=50),
                          progress=lambda d, t, m: d >= 1)
