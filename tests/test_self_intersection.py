"""Self-intersections of a triangle mesh (lacore.geometry.self_intersection) and of a fitted take
(lacore.markers.interpenetration): constructed cases and a brute-force reference."""

import numpy as np
import pytest
import trimesh

from lacore import MeshTopology
from lacore.geometry.self_intersection import _Faces, _Stars, intersecting_faces, self_intersections
from lacore.markers import MarkerBinding
from lacore.markers.interpenetration import new_self_intersections


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def crosses(p, q, tri):
    """Reference: whether segment ``p q`` crosses the interior of ``tri`` (Moller-Trumbore, scalar)."""
    a, b, c = tri
    d = _sub(q, p)
    e1, e2 = _sub(b, a), _sub(c, a)
    h = _cross(d, e2)
    det = _dot(e1, h)
    if abs(det) < 1e-14:
        return False
    s = _sub(p, a)
    u = _dot(s, h) / det
    k = _cross(s, e1)
    v = _dot(d, k) / det
    t = _dot(e2, k) / det
    return 0 < u and 0 < v and u + v < 1 and 0 < t < 1


def brute_force(V, F):
    """Reference: every pair of faces with overlapping boxes; an edge of one crossing the other (opposite edges only
    if a vertex is shared)."""
    T = V[F]
    lo, hi = T.min(axis=1), T.max(axis=1)
    boxes = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    out = []
    P, Fl = [tuple(x) for x in np.asarray(V, float).tolist()], np.asarray(F).tolist()
    for i, j in np.argwhere(np.triu(boxes, 1)).tolist():
        common = set(Fl[i]) & set(Fl[j])
        if len(common) >= 2:
            continue
        A, B = [P[k] for k in Fl[i]], [P[k] for k in Fl[j]]
        if common:
            v = common.pop()
            ea = [tuple(x for x in Fl[i] if x != v)]
            eb = [tuple(x for x in Fl[j] if x != v)]
        else:
            ea = [(Fl[i][k], Fl[i][(k + 1) % 3]) for k in range(3)]
            eb = [(Fl[j][k], Fl[j][(k + 1) % 3]) for k in range(3)]
        if any(crosses(P[a], P[b], B) for a, b in ea) or any(crosses(P[a], P[b], A) for a, b in eb):
            out.append((i, j))
    return np.array(out, np.int64).reshape(-1, 2)


def sphere(subdivisions=3):
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.array(s.vertices, float), np.array(s.faces, np.int64)


# ----------------------------------------------------------------------------- constructed cases


def test_two_crossing_triangles():
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [3, 0.5, 0]])
    assert self_intersections(V, [[0, 1, 2], [3, 4, 5]]).tolist() == [[0, 1]]
    # one edge through the other face's interior (the "chain link"): also reported
    V2 = V.copy()
    V2[5] = [0.5, 3, 0.5]
    assert self_intersections(V2, [[0, 1, 2], [3, 4, 5]]).tolist() == [[0, 1]]
    assert intersecting_faces(V, [[0, 1, 2], [3, 4, 5]]).tolist() == [True, True]


@pytest.mark.parametrize("other", [
    [[0.5, 0.5, 0], [0.5, 0.5, 1], [1, 0.2, 1]],          # a vertex on the face, the rest above
    [[0.5, 0.0, 0], [1.0, 0.0, 0], [0.7, 0.3, 1]],        # an edge lying on the face's edge, the rest above
    [[0.2, 0.2, 0], [0.8, 0.2, 0], [0.2, 0.8, 0]],        # coplanar, inside: lying flat on it
    [[1.0, 1.0, -1], [1.0, 1.0, 1], [3, 3, 0]],           # touches the face's edge x + y = 2 from outside
    [[0.5, 0.5, 1e-3], [1, 0.5, 1], [0.5, 1, 1]],         # close above, not touching
])
def test_touching_is_not_crossing(other):
    V = np.vstack([[[0.0, 0, 0], [2, 0, 0], [0, 2, 0]], other])
    assert self_intersections(V, [[0, 1, 2], [3, 4, 5]]).shape == (0, 2)


def test_degenerate_faces_never_intersect():
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0],
                  [0.5, 0.5, -1], [0.5, 0.5, 1], [0.5, 0.5, 0.3],        # a segment through the first face
                  [0.4, 0.4, -1], [0.4, 0.4, -1], [0.4, 0.4, -1]])       # a point
    assert self_intersections(V, [[0, 1, 2], [3, 4, 5], [6, 7, 8]]).shape == (0, 2)
    V[5] = [1.5, 0.5, 0]                                                  # no longer degenerate: it crosses
    assert self_intersections(V, [[0, 1, 2], [3, 4, 5], [6, 7, 8]]).tolist() == [[0, 1]]


def test_adjacent_faces():
    v = [0.0, 0, 0]
    a1, a2 = [2.0, 0, 0], [0.0, 2, 0]
    # sharing one vertex: reported only when one face passes through the other beyond it
    through = [[0.5, 0.5, -1], [0.5, 0.5, 1]]       # the opposite edge pierces the first face
    above = [[0.5, 0.5, 0.2], [0.5, 0.8, 1]]        # a fold that stays on one side
    for other, expect in ((through, [[0, 1]]), (above, [])):
        V = np.array([v, a1, a2, *other])
        assert self_intersections(V, [[0, 1, 2], [0, 3, 4]]).tolist() == expect
    # sharing an edge: never (folded flat onto each other is contact)
    V = np.array([v, a1, a2, [0.3, 1.0, 0.0]])
    assert self_intersections(V, [[0, 1, 2], [0, 3, 1]]).shape == (0, 2)


def test_closed_sphere_has_none_and_a_pushed_vertex_is_found():
    V, F = sphere(3)                                                # 642 vertices, 1280 faces
    assert self_intersections(V, F).shape == (0, 2)
    top = int(np.argmax(V[:, 2]))
    W = V.copy()
    W[top] = [0.0, 0.0, -1.3]                                       # through the opposite side
    P = self_intersections(W, F)
    ring = np.flatnonzero((F == top).any(axis=1))
    assert len(P) > 0
    assert np.isin(P, ring).any(axis=1).all()                       # every pair has a face of the pushed vertex
    far = P[~np.isin(P, ring)]                                      # ... and the faces they cross are at the bottom
    assert (V[F[far]].mean(axis=1)[:, 2] < -0.8).all()
    # pushed only inside: no crossing
    W[top] = [0.0, 0.0, 0.5]
    assert self_intersections(W, F).shape == (0, 2)


def test_unit_free_and_order_free():
    V, F = sphere(2)
    rng = np.random.default_rng(3)
    W = V + 0.15 * rng.standard_normal(V.shape)
    P = self_intersections(W, F)
    assert len(P) > 10
    for scale in (1e-3, 1e3):
        assert np.array_equal(self_intersections(W * scale + [5.0, -2.0, 7.0], F), P)
    perm = rng.permutation(len(F))
    Q = np.sort(np.argsort(perm)[P], axis=1)           # P in the new face numbering
    Q = Q[np.lexsort((Q[:, 1], Q[:, 0]))]
    assert np.array_equal(self_intersections(W, F[perm]), Q)
    rolled = np.roll(F, 1, axis=1)                      # same faces, corners rolled
    assert np.array_equal(self_intersections(W, rolled), P)


@pytest.mark.parametrize("seed", range(6))
def test_random_meshes_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    if seed % 2:                                       # a triangle soup sharing vertices: every case at once
        V = rng.random((24, 3))
        F = np.array(sorted({tuple(rng.choice(24, 3, replace=False)) for _ in range(60)}))
        F = F[np.unique(np.sort(F, axis=1), axis=0, return_index=True)[1]]      # each vertex triple once
    elif seed == 0:                                    # a vertex pushed through a sphere
        V, F = sphere(2)
        V[np.argmax(V[:, 2])] = [0.05, -0.02, -1.3]
    else:                                              # a crumpled sphere: mostly adjacent faces
        V, F = sphere(1)
        V = V + 0.3 * rng.standard_normal(V.shape)
    P = self_intersections(V, F)
    ref = brute_force(V, F)
    assert len(ref) > 3
    assert np.array_equal(P, ref)
    assert (P[:, 0] < P[:, 1]).all() and len(np.unique(P, axis=0)) == len(P)
    if seed % 2 == 0:                                  # manifold: the same through a topology and its cache
        topo = MeshTopology.from_faces(F)
        assert np.array_equal(self_intersections(V, topo), ref)
        assert np.array_equal(self_intersections(V, topo, check=False), ref)
        assert np.array_equal(np.flatnonzero(intersecting_faces(V, topo)), np.unique(ref))


def test_open_fans_match_brute_force():
    """Boundary vertices (open fans) are tested face pair by face pair: a crumpled disk."""
    V, F = sphere(2)
    keep = V[F].mean(axis=1)[:, 2] < 0.3                            # a cap with a boundary
    F = F[keep]
    used = np.unique(F)
    V = V[used] + 0.25 * np.random.default_rng(7).standard_normal((len(used), 3))
    F = np.searchsorted(used, F)
    assert not _Stars(F, len(V)).closed.all()
    ref = brute_force(V, F)
    assert len(ref) > 3
    assert np.array_equal(self_intersections(V, F), ref)


@pytest.fixture(scope="module")
def posed_body():
    from lacore.samples.human import load_human

    body = load_human(coarse=True)                                  # 2,500 vertices, 4,996 faces
    return body.random_poses(1, seed=0)[0][0], np.asarray(body.faces)


def test_posed_body_matches_brute_force(posed_body):
    """Bent elbows and knees: the pairs of the brute force, and most fans skip their pair tests."""
    X, F = posed_body
    ref = brute_force(X, F)
    assert len(ref) > 40                                            # 96 measured
    assert np.array_equal(self_intersections(X, F), ref)
    topo = MeshTopology.from_faces(F)
    assert np.array_equal(self_intersections(X, topo, check=False), ref)
    stars = _Stars(F, len(X))
    graph = _Faces(X, stars.Ft).graph_fans(stars.Ft, stars.closed)
    assert graph.mean() > 0.9                                      # 0.968 measured (79 fans tested pair by pair)


# ----------------------------------------------------------------------------- fitted takes


def test_new_self_intersections_ignore_the_rest_mesh_and_marker_contact():
    V, F = sphere(2)
    top, bottom = int(np.argmax(V[:, 2])), int(np.argmin(V[:, 2]))
    rest = V.copy()
    pushed = V.copy()
    pushed[top] = [0.0, 0.0, -1.3]
    binding = MarkerBinding.from_vertices([top, bottom], F)
    apart = np.array([[[0.0, 0, 5], [0.0, 0, -5]]])            # markers far apart: not a contact
    res = new_self_intersections(pushed[None], F, binding, apart, rest)
    assert res.counts.tolist() == [len(self_intersections(pushed, F))] and res.contact_counts.tolist() == [0]
    assert res.frames.tolist() == [0]
    topo = new_self_intersections(pushed[None], MeshTopology.from_faces(F), binding, apart, rest)
    assert np.array_equal(topo.pairs[0], res.pairs[0])             # faces given as a topology: the same
    # the same markers touching (closer than their offsets) explain the pairs near both
    binding = MarkerBinding.from_vertices([top, bottom], F, offsets=[0.05, 0.05])
    touching = np.array([[[0.0, 0, -1.05], [0.0, 0, -1.1]]])
    res = new_self_intersections(pushed[None], F, binding, touching, rest)
    assert res.contact_counts[0] > 0 and res.counts[0] + res.contact_counts[0] == len(self_intersections(pushed, F))
    # occluded markers explain nothing
    res = new_self_intersections(pushed[None], F, binding, np.full((1, 2, 3), np.nan), rest)
    assert res.contact_counts.tolist() == [0]
    # a rest mesh that already has the pairs: nothing new
    res = new_self_intersections(pushed[None], F, binding, apart, pushed)
    assert res.counts.tolist() == [0] and len(res.rest_pairs) > 0
