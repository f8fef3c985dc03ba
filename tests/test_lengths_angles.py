"""The map X -> z = (lengths, dihedral angles): conventions, accuracy, derivatives, invariance."""

import numpy as np
import pytest
import trimesh
from conftest import load_topology
from fd import directional_fd, relative_error
from scipy.spatial.transform import Rotation

from lacore.geometry.lengths_angles import (dihedral_angles, edge_lengths, lengths_and_angles,
                                            lengths_and_angles_jacobian, split_z)
from lacore.geometry.topology import MeshTopology
from lacore.geometry.trigonometry import (interior_angle_jacobian, interior_angles, triangle_area_gradient,
                                          triangle_areas, triangle_inequality_margin)

MESHES = ["finger/finger1.ply", "plate/plate4SD_rolledA.ply", "sphere/defSphere3.ply",
          "hyperbolic/monkey_saddle_2.ply", "simple/SteffensPolyhedron.ply", "plate/paperCrissCross.ply"]


def test_cube_sign_convention():
    cube = trimesh.creation.box()
    topo = MeshTopology.from_faces(cube.faces)
    theta = dihedral_angles(cube.vertices, topo)
    cube_edges = np.isclose(np.abs(theta), np.pi / 2)
    assert cube_edges.sum() == 12 and np.allclose(theta[~cube_edges], 0, atol=1e-15)
    assert np.all(theta[cube_edges] > 0)  # convex with outward normals: positive
    inverted = MeshTopology.from_faces(cube.faces[:, ::-1])
    assert np.allclose(np.sort(dihedral_angles(cube.vertices, inverted)), np.sort(-theta), atol=1e-15)


@pytest.mark.parametrize("alpha", [1e-9, 1e-5, 0.3, 2.5, -1e-9, -2.0])
def test_dihedral_angle_accuracy_near_flat(alpha):
    # left face (x0, x1, x2) lies in the plane z=0, right face (x1, x0, x3) rotated by alpha about the edge
    X = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -np.cos(alpha), -np.sin(alpha)]])
    topo = MeshTopology.from_faces([[0, 1, 2], [1, 0, 3]])
    theta = dihedral_angles(X, topo)
    (e,) = topo.interior_edges
    exact = np.arctan2(np.sin(alpha), np.cos(alpha))  # the angle actually represented by the coordinates
    assert abs(theta[e] - exact) <= 1e-15 * max(1.0, abs(exact)) + 1e-24
    assert np.all(theta[topo.boundary_edges] == 0)


def test_lengths_match_coordinates():
    X, topo = load_topology("finger/finger0.ply")
    l, theta = split_z(lengths_and_angles(X, topo), topo)
    a, b = topo.edges.T
    np.testing.assert_allclose(l, np.linalg.norm(X[b] - X[a], axis=1), rtol=1e-15)
    np.testing.assert_array_equal(l, edge_lengths(X, topo))
    np.testing.assert_array_equal(theta, dihedral_angles(X, topo))
    # finger is a closed convex-ish shape: total mean curvature positive
    assert np.sum(l * theta) > 0


@pytest.mark.parametrize("rel", MESHES)
def test_rigid_motion_invariance(rel):
    X, topo = load_topology(rel)
    z = lengths_and_angles(X, topo)
    R = Rotation.from_rotvec([0.3, -1.1, 2.0]).as_matrix()
    z2 = lengths_and_angles(X @ R.T + np.array([10.0, -3.0, 7.0]), topo)
    scale = np.abs(X).max()
    E = topo.n_edges
    assert np.abs(z2[:E] - z[:E]).max() < 1e-13 * scale
    assert np.abs(z2[E:] - z[E:]).max() < 1e-11


@pytest.mark.parametrize("rel", MESHES)
def test_jacobian_finite_differences(rel):
    X, topo = load_topology(rel)
    X = X / np.abs(X).max()
    J, z = lengths_and_angles_jacobian(X, topo, return_z=True)
    assert J.shape == (2 * topo.n_edges, 3 * topo.n_vertices)
    np.testing.assert_allclose(z, lengths_and_angles(X, topo), rtol=1e-12, atol=1e-15)
    rng = np.random.default_rng(0)
    h = 1e-3 * edge_lengths(X, topo).min()
    for _ in range(3):
        d = rng.standard_normal(X.shape)
        fd = directional_fd(lambda Y: lengths_and_angles(Y, topo), X, d, h)
        assert relative_error(J @ d.ravel(), fd) < 1e-8
    # boundary rows of the angle block are empty
    assert J[topo.n_edges + topo.boundary_edges].nnz == 0


def test_jacobian_kernel_contains_rigid_motions():
    X, topo = load_topology("sphere/defSphere3.ply")
    J = lengths_and_angles_jacobian(X, topo)
    V = topo.n_vertices
    translations = [np.tile(np.eye(3)[c], V) for c in range(3)]
    rotations = [np.cross(np.eye(3)[c], X).ravel() for c in range(3)]
    for v in translations + rotations:
        assert np.abs(J @ v).max() < 1e-12 * np.abs(v).max() * max(1, np.abs(J.data).max())


# ---------------------------------------------------------------------------- trigonometry (appendix A.1)
def test_kahan_needle_triangle():
    # isosceles needle: sides 1, 1, c with tiny c; the apex angle is 2 asin(c/2) exactly
    c = 1e-8
    L = np.array([[c, 1.0, 1.0]])
    gamma = interior_angles(L)
    apex = 2 * np.arcsin(c / 2)
    assert abs(gamma[0, 0] - apex) < 1e-15 * apex
    assert abs(gamma.sum() - np.pi) < 4e-16
    area = triangle_areas(L)[0]
    exact = 0.5 * c * np.sqrt(1 - c * c / 4)
    assert abs(area - exact) < 1e-15 * exact
    naive = np.arccos((1 + 1 - c * c) / 2.0)  # the law of cosines loses every digit here
    assert abs(naive - apex) > 1e-9


def test_angles_and_areas_match_coordinates():
    X, topo = load_topology("finger/finger1.ply")
    L = edge_lengths(X, topo)[topo.face_edges]
    F = topo.faces
    gamma = interior_angles(L)
    for i in range(3):
        u = X[F[:, (i + 1) % 3]] - X[F[:, i]]
        v = X[F[:, (i + 2) % 3]] - X[F[:, i]]
        ref = np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ij,ij->i", u, v))
        np.testing.assert_allclose(gamma[:, i], ref, rtol=1e-11)
    np.testing.assert_allclose(gamma.sum(1), np.pi, rtol=1e-14)
    area = 0.5 * np.linalg.norm(np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]), axis=1)
    np.testing.assert_allclose(triangle_areas(L), area, rtol=1e-11)


def test_trigonometry_derivatives_finite_differences():
    rng = np.random.default_rng(1)
    L = np.sort(rng.uniform(0.5, 1.5, (200, 3)), axis=1)
    L[:, 2] = np.minimum(L[:, 2], 0.95 * (L[:, 0] + L[:, 1]))  # valid triangles, some slim
    h = 1e-6
    dA = triangle_area_gradient(L)
    dG = interior_angle_jacobian(L)
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        fdA = (triangle_areas(L + e) - triangle_areas(L - e)) / (2 * h)
        fdG = (interior_angles(L + e) - interior_angles(L - e)) / (2 * h)
        np.testing.assert_allclose(dA[:, j], fdA, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(dG[:, :, j], fdG, rtol=1e-7, atol=1e-9)


def test_triangle_inequality_violation_conventions():
    L = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 2.0], [1.0, 1.0, 3.0]])
    np.testing.assert_allclose(triangle_inequality_margin(L), [1.0, 0.0, -1.0])
    gamma = interior_angles(L)
    np.testing.assert_allclose(gamma[0], np.pi / 3, rtol=1e-15)
    assert np.all(gamma[1:] == 0)  # T_f <= 0: interior angles 0 (remark after Algorithm 2)
    assert np.all(triangle_areas(L)[1:] == 0)
    assert np.all(interior_angle_jacobian(L)[1:] == 0) and np.all(triangle_area_gradient(L)[1:] == 0)
