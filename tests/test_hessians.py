"""Second derivatives of lengths and dihedral angles (lacore.geometry.hessians) and the Newton steps built on them."""

import numpy as np
import pytest
import scipy.sparse as sp
from fd import directional_fd, relative_error

from lacore.geometry.hessians import (ANGLE_PAIRS, LENGTH_PAIRS, dihedral_angle_hessians, length_hessians,
                                      residual_curvature_values)
from lacore.geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian
from lacore.reconstruction import GaussNewtonOptions, get_context, reconstruct
from lacore.samples.simple_deform import box_bar, simple_deform_bend
from lacore.geometry.topology import MeshTopology


@pytest.fixture(scope="module")
def bent_bar():
    """A small closed box bar, bent and randomly perturbed (no symmetric special case)."""
    B, F = box_bar(6, 3)
    topo = MeshTopology.from_faces(F, n_vertices=len(B))
    X = simple_deform_bend(B, 1.0) + 0.02 * np.random.default_rng(1).standard_normal(B.shape)
    return topo, X


def _stencils(topo):
    ie = topo.interior_edges
    opp = topo.edge_opposite_vertices[ie]
    quad = np.stack([topo.edges[ie, 0], topo.edges[ie, 1], opp[:, 0], opp[:, 1]], 1)
    cols_len = 3 * np.repeat(topo.edges, 3, axis=1) + np.tile(np.arange(3), 2)
    cols_ang = 3 * np.repeat(quad, 3, axis=1) + np.tile(np.arange(3), 4)
    return ie, cols_len, cols_ang


def test_hessians_match_finite_differences_of_the_jacobian(bent_bar):
    """Every column of every element Hessian = derivative of the analytic Jacobian row (Richardson FD)."""
    topo, X = bent_bar
    E = topo.n_edges
    ie, cols_len, cols_ang = _stencils(topo)
    Hl, Ha = length_hessians(X, topo), dihedral_angle_hessians(X, topo)
    assert Hl.shape == (E, 6, 6) and Ha.shape == (len(ie), 12, 12)
    x = X.ravel()

    def jac(v):
        return lengths_and_angles_jacobian(v.reshape(-1, 3), topo).toarray()

    fd_len, fd_ang = np.zeros_like(Hl), np.zeros_like(Ha)
    for k in range(len(x)):
        d = np.zeros_like(x)
        d[k] = 1.0
        dJ = directional_fd(jac, x, d, 1e-4)           # d(J)/dx_k
        for j in range(6):
            m = cols_len[:, j] == k
            fd_len[m, :, j] = dJ[np.flatnonzero(m)[:, None], cols_len[m]]
        for j in range(12):
            m = cols_ang[:, j] == k
            fd_ang[m, :, j] = dJ[E + ie[m][:, None], cols_ang[m]]
    assert relative_error(Hl, fd_len) < 1e-11           # measured 3.7e-12
    assert relative_error(Ha, fd_ang) < 1e-11           # measured 3.3e-12
    assert np.abs(Ha - Ha.transpose(0, 2, 1)).max() == 0.0


def test_hessians_kill_translations_and_rotate_with_rotations(bent_bar):
    """Lengths and angles are rigid invariants: H t = 0 for a translation t of the stencil, and for an
    infinitesimal rotation w x x the Hessian gives the rotated gradient: H (w x x) = w x g blockwise
    (differentiate g(R x) = R g(x))."""
    topo, X = bent_bar
    ie, cols_len, cols_ang = _stencils(topo)
    J = lengths_and_angles_jacobian(X, topo).tocsr()
    E = topo.n_edges
    rng = np.random.default_rng(2)
    for H, cols, rows, k in ((length_hessians(X, topo), cols_len, np.arange(E), 2),
                             (dihedral_angle_hessians(X, topo), cols_ang, E + ie, 4)):
        t = np.tile(rng.standard_normal(3), k)
        assert np.abs(H @ t).max() < 1e-12 * np.abs(H).max()
        w = rng.standard_normal(3)
        pts = X.ravel()[cols].reshape(len(cols), k, 3)
        rot = np.cross(w, pts).reshape(len(cols), 3 * k)
        g = J[rows].toarray()[np.arange(len(rows))[:, None], cols].reshape(len(cols), k, 3)
        lhs = np.einsum("nij,nj->ni", H, rot).reshape(len(cols), k, 3)
        assert np.abs(lhs - np.cross(w, g)).max() < 1e-12 * np.abs(H).max() * np.abs(pts).max()


def test_residual_curvature_values_layout(bent_bar):
    """The assembly layout (upper triangles, lengths then angles) scales each element's Hessian."""
    topo, X = bent_bar
    rng = np.random.default_rng(3)
    cl, ca = rng.standard_normal(topo.n_edges), rng.standard_normal(len(topo.interior_edges))
    vl, va = residual_curvature_values(X, topo, cl, ca)
    assert vl.shape == (21, topo.n_edges) and va.shape == (78, len(topo.interior_edges))
    Hl, Ha = length_hessians(X, topo), dihedral_angle_hessians(X, topo)
    assert np.abs(vl - (Hl[:, LENGTH_PAIRS[0], LENGTH_PAIRS[1]] * cl[:, None]).T).max() < 1e-13
    assert np.abs(va - (Ha[:, ANGLE_PAIRS[0], ANGLE_PAIRS[1]] * ca[:, None]).T).max() < 1e-12


def test_newton_matrix_is_the_hessian_of_the_energy(bent_bar):
    """matrix(second_order=True) and dot(v, second_order=True) = finite differences of the gradient of W_q."""
    topo, X = bent_bar
    ctx = get_context(topo, X)
    z = lengths_and_angles(simple_deform_bend(box_bar(6, 3)[0], -0.5), topo)   # far target: large residuals
    obj = ctx.objective(z)
    _, grad, M = obj.linearize(X)
    pat = ctx.pattern
    L = sp.csc_matrix((M(second_order=True), pat["indices"], pat["indptr"]), shape=(pat["n"], pat["n"]))
    H = (L + L.T - sp.diags(L.diagonal())).toarray()
    rng = np.random.default_rng(4)
    for _ in range(3):
        v = rng.standard_normal(X.size)
        fd = directional_fd(lambda x: obj.linearize(x.reshape(-1, 3))[1], X.ravel(), v, 1e-4)
        assert relative_error(H @ v, fd) < 1e-10                         # measured 3.8e-12
        assert relative_error(M.dot(v, second_order=True), H @ v) < 1e-12
    gn = M.dot(v)
    assert relative_error(gn, H @ v) > 0.1      # the Gauss-Newton matrix is not the Hessian here: 0.23


@pytest.mark.numerics
def test_newton_steps_make_the_hard_bar_blend_converge():
    """Bend 90 -> twist 90 of a 1.8k bar at t = 0.5: with the Hessian after the first cut or slowly converging
    steps (default newton="auto") Gauss-Newton needs fewer iterations to the same minimum."""
    from lacore.samples.simple_deform import box_bar as bar

    B, F = bar(40, 10)
    topo = MeshTopology.from_faces(F, n_vertices=len(B))
    h = B[:, 0]
    s = (h - h.min()) / np.ptp(h)
    tw = B.copy()
    tw[:, 1] = np.cos(np.pi / 2 * s) * B[:, 1] - np.sin(np.pi / 2 * s) * B[:, 2]
    tw[:, 2] = np.sin(np.pi / 2 * s) * B[:, 1] + np.cos(np.pi / 2 * s) * B[:, 2]
    K0 = simple_deform_bend(B, np.pi / 2)
    z = 0.5 * (lengths_and_angles(K0, topo) + lengths_and_angles(tw, topo))
    gn = reconstruct(z, topo, K0, options=GaussNewtonOptions(newton="never"))
    auto = reconstruct(z, topo, K0)
    always = reconstruct(z, topo, K0, newton="always")
    for r in (gn, auto, always):
        assert r.success and r.energy == pytest.approx(gn.energy, rel=1e-8)
    assert gn.newton_steps == 0 and always.newton_steps > 0
    # measured 5 (always), 8 (auto) vs 9 (Gauss-Newton only)
    assert always.iterations <= 0.8 * gn.iterations and auto.iterations <= gn.iterations


def test_newton_option_and_unregularized_factorization_errors(bent_bar):
    """An unknown mode is named; a Newton matrix that is not positive definite fails at once (no shift)."""
    from lacore.errors import InputError
    from lacore.linalg.sparse_cholesky import NotPositiveDefiniteError, SparseCholesky

    with pytest.raises(InputError, match="unknown newton mode 'sometimes'; use one of never, auto, always"):
        GaussNewtonOptions(newton="sometimes")
    A = sp.csc_matrix(np.array([[1.0, 2.0], [2.0, 1.0]]))     # eigenvalues 3 and -1
    chol = SparseCholesky(A, backend="scipy")
    with pytest.raises(NotPositiveDefiniteError, match="the 2x2 matrix is not positive definite$"):
        chol.factorize(A, regularize=False)
    assert chol.factorize(A).shift > 0                        # the default retries with a diagonal shift
