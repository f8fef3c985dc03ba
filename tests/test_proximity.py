"""Distances between triangles (lacore.geometry.proximity) and faces touching in the rest mesh."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lacore.geometry.proximity import point_triangle_distances, segment_distances, touching_faces, triangle_distances
from lacore.geometry.self_intersection import self_intersections
from lacore.markers import MarkerBinding
from lacore.markers.interpenetration import REST_CONTACT_GAP, new_self_intersections


def sampled_distance(T1, T2, n=100):
    """Reference: least distance between dense samples of two triangles."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = u + v <= 1
    u, v = u[keep, None], v[keep, None]
    P = T1[0] + u * (T1[1] - T1[0]) + v * (T1[2] - T1[0])
    Q = T2[0] + u * (T2[1] - T2[0]) + v * (T2[2] - T2[0])
    return float(cKDTree(P).query(Q)[0].min())


def test_triangle_distances_match_dense_sampling():
    rng = np.random.default_rng(3)
    V = rng.normal(size=(60, 6, 3))
    V[:, 3:] += 2.0 * rng.normal(size=(60, 1, 3))
    crossing = np.array([len(self_intersections(v, [[0, 1, 2], [3, 4, 5]])) > 0 for v in V])
    d = np.array([triangle_distances(v, [[0, 1, 2], [3, 4, 5]], [0], [1])[0] for v in V])
    ref = np.array([sampled_distance(v[:3], v[3:]) for v in V])
    gap = ref[~crossing] - d[~crossing]
    assert (~crossing).sum() > 50
    # sampling overestimates the distance by at most a grid step's worth (measured 0.0031)
    assert gap.min() > -1e-9 and gap.max() < 0.01


def test_point_and_segment_distances_on_known_cases():
    A, B, C = np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    P = np.array([[0.25, 0.25, -2.0], [2.0, 0, 0], [-1.0, -1, 0], [1.0, 1, 0]])
    expected = [2.0, 1.0, np.sqrt(2.0), np.sqrt(2.0) / 2]
    d = point_triangle_distances(P, np.repeat(A, 4, 0), np.repeat(B, 4, 0), np.repeat(C, 4, 0))
    assert np.allclose(d, expected)
    # a degenerate triangle (all corners on a line) gives the distance to the segment
    d = point_triangle_distances(np.array([[0.5, 1.0, 0]]), A, B, 2 * B)
    assert np.allclose(d, [1.0])
    # parallel, skew, touching and degenerate segments
    P0 = np.array([[0.0, 0, 0], [0.0, 0, 0], [0.0, 0, 0], [0.0, 0, 0]])
    P1 = np.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0]])
    Q0 = np.array([[0.5, 1, 0], [2.0, -1, 3], [1.0, 0, 0], [0.0, 3, 4]])
    Q1 = np.array([[3.0, 1, 0], [2.0, 1, 3], [1.0, 5, 0], [0.0, 3, 4]])
    assert np.allclose(segment_distances(P0, P1, Q0, Q1), [1.0, np.sqrt(10.0), 0.0, 5.0])


def two_sheets(gap, n=6):
    """Two flat ``n x n`` grids of unit spacing, one ``gap`` above the other (no shared vertex)."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    grid = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    q = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    F = np.concatenate([np.stack([q, q + 1, q + n + 1], 1), np.stack([q, q + n + 1, q + n], 1)])
    V = np.concatenate([grid, grid + [0.0, 0.0, gap]])
    return V, np.concatenate([F, F[:, ::-1] + n * n])


def test_touching_faces_is_scale_free_and_skips_neighbours():
    V, F = two_sheets(0.3)
    pairs = touching_faces(V, F, 0.5)
    n_sheet = len(F) // 2
    assert len(pairs) > 0 and (pairs[:, 0] < n_sheet).all() and (pairs[:, 1] >= n_sheet).all()
    assert len(touching_faces(V, F, 0.2)) == 0                     # within one sheet: neighbours, never pairs
    assert np.array_equal(touching_faces(V * 1000.0, F, 500.0), pairs)
    with pytest.raises(ValueError, match="distance"):
        touching_faces(V, F, -1.0)


@pytest.mark.parametrize("gap, reported", [(0.2 * REST_CONTACT_GAP, False), (20 * REST_CONTACT_GAP, True)])
def test_faces_touching_at_rest_may_cross(gap, reported):
    """Faces closer at rest than REST_CONTACT_GAP mean edge lengths are a contact; farther ones are not."""
    V, F = two_sheets(gap)
    moved = V.copy()
    n = len(V) // 2
    moved[n + 14, 2] = -0.2                                      # one vertex of the upper sheet dips through
    assert len(self_intersections(moved, F)) > 0
    binding = MarkerBinding.from_vertices([0, n - 1], F)
    markers = moved[[0, n - 1]][None] + [0.0, 0.0, 5.0]
    res = new_self_intersections(moved[None], F, binding, markers, V)
    assert (res.counts[0] > 0) == reported
    assert (len(res.rest_pairs) > 0) != reported


def test_the_body_coarsened_with_its_training_poses_touches_only_at_the_eyes():
    """Build Model's coarsening of the CC0 body (rest pose and 30 training poses, 2,500 vertices) brings eyelid chords
    within 0.0024 mean edge lengths of the eyeballs; the full body keeps a gap. Those pairs are rest contacts."""
    from conftest import shared_data_dir
    from lacore.multiresolution import coarsen
    from lacore.samples.human import load_human, training_angles
    from lacore.markers.interpenetration import IntersectionCheck

    body = load_human(shared_data_dir())
    poses = body.pose(training_angles(30, path=shared_data_dir()))

    def mean_edge(X, F):
        return float(np.linalg.norm(X[F[:, 0]] - X[F[:, 1]], axis=1).mean())

    assert len(touching_faces(body.vertices, body.faces, REST_CONTACT_GAP * mean_edge(body.vertices, body.faces))) == 0
    c = coarsen(np.concatenate([body.vertices[None], poses]), body.faces, 2500)
    R, F = body.vertices[c.vertex_indices], c.faces
    pairs = touching_faces(R, F, REST_CONTACT_GAP * mean_edge(R, F))
    # measured 12 (both eyes); a greedy coarsening on another CPU may pick other collapses, so none is allowed too
    assert len(pairs) < 50
    head = body.bone_index("Head")
    assert (body.vertex_bone[c.vertex_indices][F[pairs]] == head).all()
    rest = IntersectionCheck(F, MarkerBinding.from_vertices([0, 1], F), R).rest_pairs
    assert len(set(map(tuple, pairs.tolist())) - set(map(tuple, rest.tolist()))) == 0
