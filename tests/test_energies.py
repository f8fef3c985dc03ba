"""Deformation energies on lengths and angles (thesis 3.3): values, weights, derivatives, composition with Z[X]."""

import numpy as np
import pytest
from conftest import load_topology
from fd import directional_fd, relative_error
from scipy.spatial.transform import Rotation

from lacore.energies import (EnergyInVertices, QuadraticEnergy, ThinShellsEnergy, edge_areas, membrane_density,
                             quadratic_weights)
from lacore.errors import LengthsAnglesError, MeshError
from lacore.geometry.lengths_angles import dihedral_angles, face_areas, lengths_and_angles, lengths_and_angles_jacobian
from lacore.geometry.topology import MeshTopology

PAIRS = [("plate/plate121.ply", "plate/plate121_rolledA.ply"),
         ("finger/finger0.ply", "finger/finger1.ply"),
         ("sphere/defSphere0.ply", "sphere/defSphere3.ply")]
ACOS02 = np.arccos(0.2)  # dihedral angle of the spokes of square4_bent (a pyramid of height 1)


_CACHE = {}


def pair(rels):
    """Vertices and lengths-and-angles of a shared pair in dense correspondence (cached per module)."""
    if rels not in _CACHE:
        Xa, topo = load_topology(rels[0])
        Xb, _ = load_topology(rels[1])
        _CACHE[rels] = (topo, Xa, Xb, lengths_and_angles(Xa, topo), lengths_and_angles(Xb, topo))
    return _CACHE[rels]


def z_direction(z, topo, seed):
    """Random direction in z: relative 10% on lengths, 0.1 rad on interior angles, 0 on boundary angles."""
    rng = np.random.default_rng(seed)
    E = topo.n_edges
    v = np.concatenate([0.1 * z[:E] * rng.standard_normal(E), 0.1 * rng.standard_normal(E)])
    v[E + topo.boundary_edges] = 0.0
    return v


def energies(topo, Xa):
    return [QuadraticEnergy(topo, reference_vertices=Xa, weights="frohlich_botsch", bending_weight=0.1),
            QuadraticEnergy(topo, reference_vertices=Xa, weights="heeren", bending_weight=0.1),
            ThinShellsEnergy(topo, bending_weight=0.1, mu=1.0, lam=1.0),
            ThinShellsEnergy(topo, bending_weight=0.01, mu=2.0, lam=0.5)]


def shifted(z_a, z_b, argument, t, v):
    return (z_a + t * v, z_b) if argument == 0 else (z_a, z_b + t * v)


# --------------------------------------------------------------------------- weights and hand-computed values
def test_quadratic_weights_square4_by_hand():
    # four right isosceles triangles of area 1/4 around the centre vertex 0: spokes of length sqrt(1/2)
    # (interior, dbar = (1/4 + 1/4) / 3 = 1/6), rim edges of length 1 (boundary, dbar = (1/4) / 3 = 1/12)
    X, topo = load_topology("simple/square4.ply")
    spoke = (topo.edges == 0).any(1)
    assert spoke.sum() == 4 and np.array_equal(spoke, ~topo.is_boundary_edge)
    lbar = lengths_and_angles(X, topo)[:topo.n_edges]
    np.testing.assert_allclose(edge_areas(lbar, topo), np.where(spoke, 1 / 6, 1 / 12), rtol=1e-15)
    w_s, w_b = quadratic_weights(lbar, topo, "frohlich_botsch")  # (3.20)
    np.testing.assert_allclose(w_s, np.where(spoke, 2.0, 1.0), rtol=1e-14)
    np.testing.assert_allclose(w_b, np.where(spoke, 0.5 / (1 / 6), 0.0), rtol=1e-14)
    w_s, w_b = quadratic_weights(lbar, topo, "heeren")  # (3.21)
    np.testing.assert_allclose(w_s, np.where(spoke, (1 / 6) / 0.5, 1 / 12), rtol=1e-14)
    np.testing.assert_allclose(w_b, np.where(spoke, 3.0, 0.0), rtol=1e-14)
    w_s, w_b = quadratic_weights(lbar, topo, "uniform")
    assert np.all(w_s == 1) and np.array_equal(w_b, spoke.astype(float))
    # the energy takes the same weights from reference_z
    q = QuadraticEnergy(topo, reference_z=lengths_and_angles(X, topo), weights="heeren", bending_weight=0.5)
    np.testing.assert_allclose(q.residual_weights, np.r_[np.where(spoke, 1 / 3, 1 / 12), np.where(spoke, 1.5, 0)],
                               rtol=1e-14)


def test_square4_to_pyramid_by_hand():
    # square4 -> square4_bent lifts the centre to height 1: spokes sqrt(1/2) -> sqrt(3/2), rims unchanged,
    # spoke dihedral angles 0 -> arccos(1/5) (normals (0, 1, 1/2) and (-1, 0, 1/2) of neighbouring faces)
    Xa, topo = load_topology("simple/square4.ply")
    Xb, _ = load_topology("simple/square4_bent.ply")
    za, zb = lengths_and_angles(Xa, topo), lengths_and_angles(Xb, topo)
    eta = 0.3
    dl2 = (np.sqrt(1.5) - np.sqrt(0.5)) ** 2
    fb = QuadraticEnergy(topo, reference_vertices=Xa, weights="frohlich_botsch", bending_weight=eta)
    assert fb.value(za, zb) == pytest.approx(4 * 2 * dl2 + eta * 4 * 3 * ACOS02**2, rel=1e-14)
    he = QuadraticEnergy(topo, reference_vertices=Xa, weights="heeren", bending_weight=eta)
    assert he.value(za, zb) == pytest.approx(4 * dl2 / 3 + eta * 4 * 3 * ACOS02**2, rel=1e-14)
    # membrane: in the frame (X1 - X0, X2 - X0) g_a = I/2, g_b = [[3/2, 1], [1, 3/2]], so G = [[3, 2], [2, 3]]:
    # tr G = 6, det G = 5 on each face of area 1/4
    mu, lam = 1.3, 0.7
    ts = ThinShellsEnergy(topo, bending_weight=eta, mu=mu, lam=lam)
    tr, det = ts.distortion_invariants(za, zb)
    np.testing.assert_allclose(tr, 6.0, rtol=1e-14)
    np.testing.assert_allclose(det, 5.0, rtol=1e-14)
    mem = 4 * 0.25 * (3 * mu + 1.25 * lam - (mu / 2 + lam / 4) * np.log(5.0) - mu - lam / 4)
    assert ts.membrane_value(za, zb) == pytest.approx(mem, rel=1e-14)
    # bending (3.24): four spokes, (0 - arccos(1/5))^2 * (1/2) / (1/6)
    assert ts.bending_value(za, zb) == pytest.approx(4 * 3 * ACOS02**2, rel=1e-14)
    assert ts.value(za, zb) == pytest.approx(mem + eta * 12 * ACOS02**2, rel=1e-14)


def test_custom_weights_override_and_boundary_bending_weight_is_zero():
    topo, Xa, Xb, za, zb = pair(PAIRS[0])
    E = topo.n_edges
    rng = np.random.default_rng(3)
    ws, wb = rng.uniform(0.5, 2.0, E), rng.uniform(0.5, 2.0, E)
    q = QuadraticEnergy(topo, membrane_weights=ws, bending_weights=wb, bending_weight=0.2)
    np.testing.assert_array_equal(q.membrane_weights, ws)
    np.testing.assert_array_equal(q.bending_weights, np.where(topo.is_boundary_edge, 0.0, wb))
    d = za - zb
    expected = np.sum(ws * d[:E] ** 2) + 0.2 * np.sum((wb * d[E:] ** 2)[topo.interior_edges])
    assert q.value(za, zb) == pytest.approx(expected, rel=1e-13)
    # the scheme's weights for the other part
    ref = QuadraticEnergy(topo, reference_vertices=Xa, weights="heeren")
    mixed = QuadraticEnergy(topo, reference_vertices=Xa, weights="heeren", membrane_weights=ws)
    np.testing.assert_array_equal(mixed.bending_weights, ref.bending_weights)
    assert np.all(ref.bending_weights[topo.boundary_edges] == 0)
    assert np.all(ref.bending_weights[topo.interior_edges] > 0)


# --------------------------------------------------------------------------- thin shells vs. vertex positions
@pytest.mark.parametrize("rels", PAIRS[:2])
@pytest.mark.parametrize("mu,lam", [(1.0, 1.0), (2.0, 0.25)])
def test_membrane_matches_first_fundamental_forms(rels, mu, lam):
    # (1.13)/(1.33)/(1.34) from vertex positions: G_f = (DPsi_a^T DPsi_a)^{-1} DPsi_b^T DPsi_b
    topo, Xa, Xb, za, zb = pair(rels)
    f = topo.faces

    def first_fundamental_form(X):
        D = np.stack([X[f[:, 1]] - X[f[:, 0]], X[f[:, 2]] - X[f[:, 0]]], axis=2)  # (F, 3, 2)
        return np.swapaxes(D, 1, 2) @ D

    G = np.linalg.solve(first_fundamental_form(Xa), first_fundamental_form(Xb))
    tr, det = np.trace(G, axis1=1, axis2=2), np.linalg.det(G)
    ts = ThinShellsEnergy(topo, mu=mu, lam=lam)
    tr_z, det_z = ts.distortion_invariants(za, zb)
    np.testing.assert_allclose(tr_z, tr, rtol=1e-10)
    np.testing.assert_allclose(det_z, det, rtol=1e-10)
    # density via the eigenvalues s_i of G: mu/2 sum(s_i - log s_i - 1) + lam/4 (det - log det - 1)
    s = np.linalg.eigvals(G).real
    dens = 0.5 * mu * np.sum(s - np.log(s) - 1, axis=1) + 0.25 * lam * (det - np.log(det) - 1)
    np.testing.assert_allclose(membrane_density(tr, det, mu, lam), dens, rtol=1e-8, atol=1e-13)
    per_face = face_areas(Xa, f) * dens
    np.testing.assert_allclose(ts.membrane_energies(za, zb), per_face, rtol=1e-8, atol=1e-14)
    assert ts.membrane_value(za, zb) == pytest.approx(per_face.sum(), rel=1e-10)
    assert per_face.sum() > 1e-4  # a real deformation (the rolled plate is nearly isometric: 4e-4)


def test_bending_matches_vertex_quantities():
    topo, Xa, Xb, za, zb = pair(PAIRS[1])
    ie = topo.interior_edges
    A = face_areas(Xa, topo.faces)
    d = (A[topo.edge_faces[ie, 0]] + A[topo.edge_faces[ie, 1]]) / 3
    l2 = np.sum((Xa[topo.edges[ie, 1]] - Xa[topo.edges[ie, 0]]) ** 2, axis=1)
    dtheta = dihedral_angles(Xa, topo)[ie] - dihedral_angles(Xb, topo)[ie]
    expected = np.sum(dtheta**2 * l2 / d)
    ts = ThinShellsEnergy(topo, bending_weight=0.04)
    assert ts.bending_value(za, zb) == pytest.approx(expected, rel=1e-12)
    assert ts.value(za, zb) == pytest.approx(ts.membrane_value(za, zb) + 0.04 * expected, rel=1e-13)


# --------------------------------------------------------------------------- identities
@pytest.mark.parametrize("rels", PAIRS)
def test_zero_at_identity(rels):
    topo, Xa, Xb, za, zb = pair(rels)
    for en in energies(topo, Xa):
        for z in (za, zb):
            assert en.value(z, z) == 0.0
            for arg in (0, 1):
                g = en.gradient(z, z, arg)
                assert g.shape == (2 * topo.n_edges,)
                assert np.abs(g).max() < 1e-12 * np.abs(en.gradient(za, zb, arg)).max()


@pytest.mark.parametrize("rels", PAIRS[:1] + [("simple/square4.ply", "simple/square4_bent.ply")])
def test_thin_shells_hessian_psd_at_identity_and_energy_nonnegative(rels):
    # W_TS >= 0 with equality at z_a = z_b, so both Hessians are PSD there (membrane density >= 0 for SPD G)
    topo, Xa, Xb, za, zb = pair(rels)
    ts = ThinShellsEnergy(topo, bending_weight=0.1)
    for arg in (0, 1):
        H = ts.hessian(za, za, arg).toarray()
        assert np.abs(H - H.T).max() <= 1e-12 * np.abs(H).max()
        eig = np.linalg.eigvalsh(H)
        assert eig.min() > -1e-11 * eig.max()
        assert eig.max() > 0
    for seed in range(5):
        v = z_direction(za, topo, seed)
        for z_a, z_b in ((za, za + 0.5 * v), (za + 0.5 * v, za), (za, zb)):
            w = ts.value(z_a, z_b)
            assert np.isfinite(w) and w > 0


@pytest.mark.parametrize("rels", PAIRS)
def test_rigid_motion_invariance(rels):
    topo, Xa, Xb, za, zb = pair(rels)
    R = Rotation.from_rotvec([0.4, -1.3, 2.2]).as_matrix()
    t = np.array([5.0, -2.0, 11.0])
    for en in energies(topo, Xa)[::2]:
        for arg, z_fixed, X in ((1, za, Xb), (0, zb, Xa)):
            f = EnergyInVertices(en, z_fixed, argument=arg)
            w0, w1 = f.value(X), f.value(X @ R.T + t)
            assert w0 > 0 and abs(w1 - w0) <= 1e-12 * w0
            g0, g1 = f.gradient(X).reshape(-1, 3), f.gradient(X @ R.T + t).reshape(-1, 3)
            assert np.abs(g1 - g0 @ R.T).max() <= 1e-9 * np.abs(g0).max()


# --------------------------------------------------------------------------- derivatives in z
def check_z_derivatives(en, za, zb, argument, v):
    """FD checks (Richardson, h = 1e-3 along v) of the gradient, Hessian and mixed Hessian in ``argument``."""
    other = 1 - argument
    g = en.gradient(za, zb, argument)
    fd = directional_fd(lambda t: en.value(*shifted(za, zb, argument, t, v)), 0.0, 1.0, 1e-3)
    assert abs(fd - g @ v) <= 1e-8 * np.abs(g).max() * np.abs(v).sum(), (type(en).__name__, fd, g @ v)
    H = en.hessian(za, zb, argument)
    assert H.shape == (len(za), len(za))
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    fd = directional_fd(lambda t: en.gradient(*shifted(za, zb, argument, t, v), argument), 0.0, 1.0, 1e-3)
    assert relative_error(H @ v, fd) < 1e-7, type(en).__name__
    # mixed block: d/dz_argument of the gradient in the other slot
    Hm = en.hessian(za, zb, (argument, other))
    fd = directional_fd(lambda t: en.gradient(*shifted(za, zb, argument, t, v), other), 0.0, 1.0, 1e-3)
    assert relative_error(Hm.T @ v, fd) < 1e-7, type(en).__name__
    assert abs(Hm.T - en.hessian(za, zb, (other, argument))).max() == 0.0


@pytest.mark.parametrize("rels", PAIRS)
@pytest.mark.parametrize("argument", [0, 1])
def test_gradient_and_hessian_finite_differences(rels, argument):
    topo, Xa, Xb, za, zb = pair(rels)
    for k, en in enumerate(energies(topo, Xa)):
        check_z_derivatives(en, za, zb, argument, z_direction(za, topo, seed=10 * k + argument))


def test_finite_difference_convergence_is_second_order():
    # plain central differences of the thin shells gradient: error ratio 4 when h halves
    topo, Xa, Xb, za, zb = pair(PAIRS[0])
    ts = ThinShellsEnergy(topo, bending_weight=0.1)
    for argument in (0, 1):
        v = z_direction(za, topo, seed=7)
        exact = ts.gradient(za, zb, argument) @ v
        errors = []
        for h in (4e-3, 2e-3, 1e-3):
            c = (ts.value(*shifted(za, zb, argument, h, v)) - ts.value(*shifted(za, zb, argument, -h, v))) / (2 * h)
            errors.append(abs(c - exact))
        ratios = np.array(errors[:-1]) / np.array(errors[1:])
        assert np.all((ratios > 3.6) & (ratios < 4.4)), ratios


def test_hessian_pattern_is_reused():
    topo, Xa, Xb, za, zb = pair(PAIRS[0])
    ts = ThinShellsEnergy(topo)
    v = z_direction(za, topo, seed=1)
    for arg in (0, 1, (0, 1)):
        H1, H2 = ts.hessian(za, zb, arg), ts.hessian(za, zb + 0.3 * v, arg)
        np.testing.assert_array_equal(H1.indptr, H2.indptr)
        np.testing.assert_array_equal(H1.indices, H2.indices)
        assert not np.allclose(H1.data, H2.data)


# --------------------------------------------------------------------------- composition with Z[X]
@pytest.mark.parametrize("rels", PAIRS)
def test_composed_gradient_finite_differences(rels):
    topo, Xa, Xb, za, zb = pair(rels)
    rng = np.random.default_rng(5)
    scale = za[:topo.n_edges].min()  # perturb vertices by ~1e-3 of the shortest edge
    for en in energies(topo, Xa)[1:3]:
        for arg, z_fixed, X in ((1, za, Xb), (0, zb, Xa)):
            f = EnergyInVertices(en, z_fixed, topology=topo, argument=arg)
            V = scale * rng.standard_normal(X.shape)
            w, g = f.value_and_gradient(X)
            assert w == f.value(X) and g.shape == (3 * topo.n_vertices,)
            np.testing.assert_array_equal(g, f.gradient(X))
            fd = directional_fd(lambda t, f=f, X=X, V=V: f.value(X + t * V), 0.0, 1.0, 1e-3)
            assert abs(fd - g @ V.ravel()) <= 1e-9 * scale * np.abs(g).sum(), (type(en).__name__, arg)


@pytest.mark.parametrize("rels", PAIRS[:2])
def test_gauss_newton_hessian(rels):
    topo, Xa, Xb, za, zb = pair(rels)
    for en in energies(topo, Xa)[1:3]:
        for arg, z_fixed, X in ((1, za, Xb), (0, zb, Xa)):
            f = EnergyInVertices(en, z_fixed, argument=arg)
            J, z = lengths_and_angles_jacobian(X, topo, return_z=True)
            Hz = en.hessian(*((z_fixed, z) if arg == 1 else (z, z_fixed)), arg)
            ref = (J.T @ Hz @ J).tocsr()
            H = f.gauss_newton_hessian(X, project=False)
            assert H.shape == (3 * topo.n_vertices,) * 2
            assert abs(H - ref).max() <= 1e-12 * abs(ref).max()
            Hp = f.gauss_newton_hessian(X)
            assert abs(Hp - Hp.T).max() <= 1e-13 * abs(Hp).max()
            if isinstance(en, QuadraticEnergy):  # already PSD blocks: projection changes nothing
                assert abs(Hp - H).max() <= 1e-13 * abs(H).max()
            if topo.n_vertices < 200:
                eig = np.linalg.eigvalsh(Hp.toarray())
                assert eig.min() > -1e-12 * eig.max()
                if isinstance(en, ThinShellsEnergy) and arg == 0:
                    assert np.linalg.eigvalsh(H.toarray()).min() < -1e-3 * eig.max()  # projection was needed


def test_psd_projection_clamps_negative_eigenvalues_of_a_block():
    # one triangle: the membrane Hessian in the undeformed lengths is a single 3x3 block, indefinite here
    topo = MeshTopology.from_faces([[0, 1, 2]])
    X = np.array([[0.0, 0.0, 0.0], [1.3, 0.0, 0.0], [0.55, 1.1, 0.2]])
    z_a, z_b = lengths_and_angles(X, topo), np.r_[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    ts = ThinShellsEnergy(topo)
    H = ts.hessian(z_a, z_b, argument=0).toarray()
    lam, V = np.linalg.eigh(H[:3, :3])
    assert lam[0] < -1e-3 and lam[-1] > 1e-3  # genuinely indefinite
    expected = np.zeros((6, 6))
    expected[:3, :3] = (V * np.maximum(lam, 0)) @ V.T
    Hp = ts.hessian(z_a, z_b, argument=0, project=True).toarray()
    np.testing.assert_allclose(Hp, expected, rtol=0, atol=1e-14 * lam.max())
    f = EnergyInVertices(ts, z_b, argument=0)
    J = lengths_and_angles_jacobian(X, topo).toarray()
    np.testing.assert_allclose(f.gauss_newton_hessian(X).toarray(), J.T @ expected @ J, rtol=0,
                               atol=1e-13 * lam.max())
    np.testing.assert_allclose(f.gauss_newton_hessian(X, project=False).toarray(), J.T @ H @ J, rtol=0,
                               atol=1e-13 * lam.max())


def test_gauss_newton_projection_is_exact_at_identity():
    # at z_b = z_a every element block of W_TS is PSD (each term is >= 0 with minimum there)
    topo, Xa, Xb, za, zb = pair(PAIRS[0])
    for arg in (0, 1):
        f = EnergyInVertices(ThinShellsEnergy(topo, bending_weight=0.1), za, argument=arg)
        H, Hp = f.gauss_newton_hessian(Xa, project=False), f.gauss_newton_hessian(Xa)
        assert abs(Hp - H).max() <= 1e-12 * abs(H).max()


@pytest.mark.parametrize("rels", PAIRS[:2])
def test_quadratic_residual_form(rels):
    topo, Xa, Xb, za, zb = pair(rels)
    q = QuadraticEnergy(topo, reference_vertices=Xa, weights="heeren", bending_weight=0.05)
    sw = np.sqrt(q.residual_weights)
    for arg, z_fixed, X in ((1, za, Xb), (0, zb, Xa)):
        f = EnergyInVertices(q, z_fixed, argument=arg)
        r, Jr = f.residual_and_jacobian(X)
        np.testing.assert_array_equal(r, f.residual(X))
        assert r @ r == pytest.approx(f.value(X), rel=1e-13)
        np.testing.assert_allclose(r, sw * (lengths_and_angles(X, topo) - z_fixed), rtol=1e-15)
        J = lengths_and_angles_jacobian(X, topo)
        assert abs(Jr - J.multiply(sw[:, None])).max() <= 1e-15 * abs(J).max()
        np.testing.assert_allclose(2 * Jr.T @ r, f.gradient(X), rtol=1e-12, atol=1e-12 * np.abs(f.gradient(X)).max())
        GN = f.gauss_newton_hessian(X)
        assert abs(2 * (Jr.T @ Jr) - GN).max() <= 1e-12 * abs(GN).max()
    assert np.array_equal(q.residual(za, zb), sw * (zb - za))


# --------------------------------------------------------------------------- invalid input
def test_errors_for_mismatched_or_bad_input():
    topo, Xa, Xb, za, zb = pair(PAIRS[0])
    E = topo.n_edges
    for en in energies(topo, Xa)[1:3]:
        with pytest.raises(LengthsAnglesError, match=r"z_b must have shape \(640,\)"):
            en.value(za, zb[:-1])
        with pytest.raises(LengthsAnglesError, match="z_a must have shape"):
            en.gradient(np.r_[za, 0.0], zb)
        bad = zb.copy()
        bad[E + 3] = np.nan
        with pytest.raises(LengthsAnglesError, match="angle of edge 3"):
            en.hessian(za, bad)
        with pytest.raises(ValueError, match="argument must be"):
            en.gradient(za, zb, argument=2)
        with pytest.raises(ValueError, match="argument 0 or 1"):
            en.gradient(za, zb, argument=(0, 1))
        with pytest.raises(ValueError, match="symmetric"):
            en.hessian(za, zb, argument=(0, 1), project=True)
        with pytest.raises(LengthsAnglesError, match="z_fixed"):
            EnergyInVertices(en, za[:E])
    with pytest.raises(ValueError, match="need a reference configuration"):
        QuadraticEnergy(topo)
    with pytest.raises(ValueError, match="not both"):
        QuadraticEnergy(topo, reference_vertices=Xa, reference_z=za)
    with pytest.raises(ValueError, match="unknown weight scheme"):
        QuadraticEnergy(topo, reference_vertices=Xa, weights="cotan")
    with pytest.raises(LengthsAnglesError, match=r"membrane_weights must have shape \(320,\)"):
        QuadraticEnergy(topo, membrane_weights=np.ones(E - 1), bending_weights=np.ones(E))
    with pytest.raises(LengthsAnglesError, match="bending_weights must be finite and >= 0; bad at edges 7"):
        QuadraticEnergy(topo, membrane_weights=np.ones(E), bending_weights=np.where(np.arange(E) == 7, -1.0, 1.0))
    with pytest.raises(ValueError, match="mu must be a positive"):
        ThinShellsEnergy(topo, mu=0.0)
    with pytest.raises(TypeError, match="only for QuadraticEnergy"):
        EnergyInVertices(ThinShellsEnergy(topo), za).residual(Xb)


def test_errors_for_meshes_not_in_correspondence():
    # octa_src_small (600 vertices) and octa_trg_small (601 vertices) do not share connectivity
    Xs, ts = load_topology("octa/octa_src_small.ply")
    Xt, tt = load_topology("octa/octa_trg_small.ply")
    zs, zt = lengths_and_angles(Xs, ts), lengths_and_angles(Xt, tt)
    en = ThinShellsEnergy(ts)
    with pytest.raises(LengthsAnglesError, match=f"z_b must have shape \\({2 * ts.n_edges},\\)"):
        en.value(zs, zt)
    f = EnergyInVertices(en, zs, argument=1)
    with pytest.raises(MeshError, match="601 vertices but the mesh has 600"):
        f.value(Xt)
    with pytest.raises(MeshError, match="differs from the energy's topology"):
        EnergyInVertices(en, zs, topology=tt)


def test_triangle_inequality_violation_gives_inf_and_clear_errors():
    topo, Xa, Xb, za, zb = pair(PAIRS[0])
    ts = ThinShellsEnergy(topo)
    face = 17
    e0, e1, e2 = topo.face_edges[face]
    bad = zb.copy()
    bad[e0] = bad[e1] + bad[e2] + 1e-3  # face 17 (and its neighbour across e0) violate (3.6)
    assert ts.value(za, bad) == np.inf and ts.value(bad, za) == np.inf
    assert ts.membrane_energies(za, bad)[face] == np.inf
    assert np.isfinite(ts.membrane_energies(za, bad)[np.setdiff1d(np.arange(topo.n_faces), topo.edge_faces[e0])]).all()
    with pytest.raises(LengthsAnglesError, match=f"z_b has triangles violating the triangle inequality.*{face}"):
        ts.gradient(za, bad)
    with pytest.raises(LengthsAnglesError, match=f"z_a has triangles violating.*{face}"):
        ts.hessian(bad, zb, argument=0)
    # the quadratic energy has no such constraint
    q = QuadraticEnergy(topo, reference_vertices=Xa)
    assert np.isfinite(q.value(za, bad))
