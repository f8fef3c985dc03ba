"""Discrete integrability conditions (thesis 3.2): identities at admissible z, derivatives, locality, rank."""

import glob
import os

import numpy as np
import pytest
from scipy.sparse import csc_matrix, identity
from scipy.sparse.linalg import LinearOperator, eigsh, splu
from conftest import load_topology, shared_meshes_dir
from fd import directional_fd, relative_error

from lacore.errors import LengthsAnglesError
from lacore.integrability.local import (euler_integrability_jacobian, euler_integrability_map, integrability_map,
                                       integrability_violation)
from lacore.integrability.transitions import (standard_frames, transition_rotations, triangle_inequality_jacobian,
                                             triangle_inequality_map)
from lacore.geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian


def all_shared_meshes():
    return sorted(os.path.relpath(p, shared_meshes_dir()) for p in glob.glob(str(shared_meshes_dir() / "*/*.ply")))


@pytest.mark.parametrize("rel", all_shared_meshes())
def test_admissible_z_satisfies_integrability(rel):
    X, topo = load_topology(rel)
    z = lengths_and_angles(X, topo)
    eu = euler_integrability_map(z, topo)
    assert eu.shape == (3 * len(topo.interior_vertices),)
    assert np.abs(eu).max(initial=0) < 1e-10
    I = integrability_map(z, topo)
    assert np.abs(I - np.eye(3)).max(initial=0) < 1e-10
    assert integrability_violation(z, topo).max() < 1e-12
    assert np.all(triangle_inequality_map(z, topo) > 0)


@pytest.mark.parametrize("rel", ["finger/finger0.ply", "plate/plate121_rolledB.ply", "simple/SteffensPolyhedron.ply"])
def test_transition_rotations_relate_standard_frames(rel):
    X, topo = load_topology(rel)
    R = transition_rotations(lengths_and_angles(X, topo), topo)
    F = standard_frames(X, topo.faces)
    left, right = topo.dual_edges.T
    assert np.abs(F[left] @ R - F[right]).max() < 1e-12
    assert np.abs(R @ np.transpose(R, (0, 2, 1)) - np.eye(3)).max() < 1e-14
    assert np.allclose(np.linalg.det(R), 1.0)


def test_perturbing_one_angle_is_local():
    X, topo = load_topology("sphere/defSphere0.ply")
    z = lengths_and_angles(X, topo)
    E = topo.n_edges
    e = topo.interior_edges[17]
    z[E + e] += 1e-3
    eu = np.abs(euler_integrability_map(z, topo).reshape(-1, 3)).max(1)
    violated = set(topo.interior_vertices[eu > 1e-9].tolist())
    assert violated == set(topo.edges[e].tolist())
    assert np.all(eu[eu <= 1e-9] < 1e-13)
    viol = integrability_violation(z, topo)
    assert set(np.flatnonzero(viol > 1e-12).tolist()) == set(topo.edges[e].tolist())


def test_perturbing_one_length_touches_its_two_faces_vertices():
    X, topo = load_topology("sphere/defSphere0.ply")
    z = lengths_and_angles(X, topo)
    e = topo.interior_edges[5]
    z[e] *= 1.001
    eu = np.abs(euler_integrability_map(z, topo).reshape(-1, 3)).max(1)
    violated = set(topo.interior_vertices[eu > 1e-9].tolist())
    assert violated == set(topo.faces[topo.edge_faces[e]].ravel().tolist())


@pytest.mark.parametrize("rel", ["finger/finger0.ply", "plate/plate4SD_rolledA.ply", "sphere/defSphere7.ply",
                                 "hyperbolic/monkey_saddle_1.ply"])
def test_euler_jacobian_finite_differences(rel):
    X, topo = load_topology(rel)
    X = X / np.abs(X).max()
    z = lengths_and_angles(X, topo)
    E = topo.n_edges
    rng = np.random.default_rng(2)
    # a non-admissible point: relative length noise and angle noise
    z = z + np.r_[0.003 * z[:E] * rng.standard_normal(E), 0.003 * rng.standard_normal(E)]
    J, val = euler_integrability_jacobian(z, topo, return_value=True)
    np.testing.assert_array_equal(val, euler_integrability_map(z, topo))
    for block in (slice(0, E), slice(E, 2 * E)):
        d = np.zeros(2 * E)
        d[block] = rng.standard_normal(E)
        h = 1e-4 * z[:E].min()
        fd = directional_fd(lambda w: euler_integrability_map(w, topo), z, d, h)
        assert relative_error(J @ d, fd) < 1e-8


@pytest.mark.parametrize("rel", ["sphere/defSphere5.ply", "plate/plate121_rolledA.ply"])
def test_euler_jacobian_annihilates_tangent_of_image(rel):
    """Ĩ(Z(X)) = 0 for all X, so DĨ(Z(X)) dZ/dX = 0 (tangent space 4.4 contains the image of dZ/dX)."""
    X, topo = load_topology(rel)
    Jz, z = lengths_and_angles_jacobian(X, topo, return_z=True)
    A = euler_integrability_jacobian(z, topo)
    P = A @ Jz
    assert np.abs(P.toarray()).max() < 1e-9 * np.abs(A.data).max() * np.abs(Jz.data).max()


@pytest.mark.parametrize("rel", ["simple/SteffensPolyhedron.ply", "sphere/unitSphere1.ply", "sphere/defSphere0.ply"])
def test_rank_conjecture_on_closed_meshes(rel):
    """Conjecture 1 as a measured fact: rank D Ĩ = 3|V| - 6 at admissible z of a closed mesh."""
    X, topo = load_topology(rel)
    assert topo.is_closed
    A = euler_integrability_jacobian(lengths_and_angles(X, topo), topo).toarray()
    s = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(s > 1e-9 * s[0]))
    assert rank == 3 * topo.n_vertices - 6
    assert s[rank - 1] > 1e-6 * s[0]  # a clear gap, not a borderline count


def kernel_dimension(G, zero=1e-14, block=8, max_rounds=6):
    """Dimension of the kernel of the symmetric positive semidefinite sparse G and its smallest nonzero
    eigenvalue, both relative to the largest eigenvalue.

    Shift-invert Lanczos can miss members of a repeated eigenvalue (here the 6-fold zero), so every null
    vector found is deflated (moved to the top of the spectrum by a rank-k Woodbury update) and the search
    repeats until the smallest remaining eigenvalue is clearly nonzero.
    """
    n = G.shape[0]
    rng = np.random.default_rng(0)
    largest = eigsh(G, k=1, which="LA", return_eigenvectors=False, v0=rng.standard_normal(n))[0]
    shift = 1e-6 * largest
    solve = splu((G + shift * identity(n, format="csc")).tocsc()).solve
    N = np.zeros((n, 0))
    for _ in range(max_rounds):
        MN = solve(N) if N.shape[1] else N
        S = np.linalg.inv(np.eye(N.shape[1]) / largest + N.T @ MN)

        def inverse(b, MN=MN, S=S, N=N):
            y = solve(np.asarray(b, dtype=float).ravel())
            return y - MN @ (S @ (N.T @ y))

        mu, V = eigsh(LinearOperator((n, n), matvec=inverse, dtype=float), k=block, which="LA",
                      v0=rng.standard_normal(n))
        lam = (1.0 / mu - shift) / largest
        found = np.abs(lam) < zero
        if not found.any():
            return N.shape[1], lam.min()
        N = np.linalg.qr(np.hstack([N, V[:, found]]))[0]
    raise AssertionError("kernel search did not settle")


@pytest.mark.parametrize("rel", ["finger/finger0.ply", "finger/finger1.ply", "octa/octa_src_small.ply",
                                 "octa/octa_trg_small.ply", "sphere/defSphere4.ply", "sphere/defSphere9.ply"])
def test_rank_conjecture_sparse(rel):
    """Conjecture 1 on the larger closed meshes: A A^T (A = D Ĩ, 3|V| x 3|V|) has exactly 6 zero
    eigenvalues (rigid motions), found by deflated shift-invert Lanczos, so rank A = 3|V| - 6."""
    X, topo = load_topology(rel)
    assert topo.is_closed and len(topo.interior_vertices) == topo.n_vertices
    A = euler_integrability_jacobian(lengths_and_angles(X, topo), topo)
    dimension, smallest_nonzero = kernel_dimension((A @ A.T).tocsc())
    assert dimension == 6
    assert smallest_nonzero > 1e-10  # measured >= 4e-9 (finger) -- ten orders of magnitude above the zeros


def test_kernel_dimension_counts_a_repeated_zero():
    """The deflated search counts all members of a 7-fold zero eigenvalue next to a 1e-8 one."""
    n = 300
    Q = np.linalg.qr(np.random.default_rng(1).standard_normal((n, n)))[0]
    spectrum = np.r_[np.zeros(7), np.linspace(1e-8, 1.0, n - 7)]
    dimension, smallest_nonzero = kernel_dimension(csc_matrix((Q * spectrum) @ Q.T))
    assert dimension == 7
    assert abs(smallest_nonzero - 1e-8) < 1e-12


def test_rank_on_disk_is_full():
    X, topo = load_topology("plate/plate121_rolledB.ply")
    A = euler_integrability_jacobian(lengths_and_angles(X, topo), topo).toarray()
    s = np.linalg.svd(A, compute_uv=False)
    assert np.sum(s > 1e-9 * s[0]) == 3 * len(topo.interior_vertices)


def test_triangle_inequality_map_and_violation():
    X, topo = load_topology("plate/plate121.ply")
    z = lengths_and_angles(X, topo)
    T = triangle_inequality_map(z, topo)
    Jt = triangle_inequality_jacobian(topo)
    d = np.random.default_rng(4).standard_normal(z.shape)
    np.testing.assert_allclose((triangle_inequality_map(z + d, topo) - T).ravel(), Jt @ d, atol=1e-12)
    e = topo.interior_edges[0]
    z[e] = 10.0  # far longer than the other two edges of both its faces
    T = triangle_inequality_map(z, topo)
    bad_faces = np.flatnonzero((T <= 0).any(1))
    assert set(bad_faces.tolist()) == set(topo.edge_faces[e].tolist())
    viol = integrability_violation(z, topo)
    inner_bad = set(topo.faces[bad_faces].ravel().tolist()) - set(topo.boundary_vertices.tolist())
    assert set(np.flatnonzero(np.isinf(viol)).tolist()) == inner_bad
    assert np.all(np.isfinite(euler_integrability_map(z, topo)))


def test_bad_z_raises():
    X, topo = load_topology("simple/square4.ply")
    z = lengths_and_angles(X, topo)
    with pytest.raises(LengthsAnglesError, match=r"shape \(16,\)"):
        euler_integrability_map(z[:-1], topo)
