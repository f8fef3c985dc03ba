"""Topology: edges, orientation, one-rings, boundary loops, and clear errors for bad connectivity."""

import numpy as np
import pytest
from conftest import load_mesh

from lacore.errors import MeshError
from lacore.geometry.lengths_angles import check_nondegenerate, lengths_and_angles
from lacore.geometry.topology import MeshTopology, check_vertices


def half_edges(faces):
    return {(int(f[(i + 1) % 3]), int(f[(i + 2) % 3])) for f in faces for i in range(3)}


def test_square4_counts_and_ring():
    X, F = load_mesh("simple/square4.ply")
    topo = MeshTopology.from_faces(F)
    assert (topo.n_vertices, topo.n_edges, topo.n_faces) == (5, 8, 4)
    assert topo.euler_characteristic == 1
    assert len(topo.interior_vertices) == 1 and len(topo.boundary_vertices) == 4
    assert len(topo.interior_edges) == 4 and len(topo.boundary_edges) == 4
    (n, (verts, corners)), = topo.vertex_rings().items()
    assert n == 4
    v = verts[0]
    faces = corners[0] // 3
    # consecutive ring faces share an edge through the centre vertex, and the loop closes
    for k in range(4):
        shared = set(F[faces[k]]) & set(F[faces[(k + 1) % 4]])
        assert len(shared) == 2 and v in shared
    # counter-clockwise about the (upward) normal: angles of the ring's "a" vertices increase
    a = [F[f][(list(F[f]).index(v) + 1) % 3] for f in faces]
    d = X[a] - X[v]
    ang = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    assert np.all(np.diff(ang) > 0)


@pytest.mark.parametrize("rel", ["finger/finger0.ply", "plate/plate121.ply", "sphere/defSphere0.ply",
                                 "hyperbolic/monkey_saddle_1.ply", "simple/SteffensPolyhedron.ply"])
def test_edge_orientation_and_incidence(rel):
    X, F = load_mesh(rel)
    topo = MeshTopology.from_faces(F)
    he = half_edges(F)
    a, b = topo.edges[:, 0], topo.edges[:, 1]
    # the left face traverses the edge a -> b, the right one b -> a
    for e in range(topo.n_edges):
        assert (a[e], b[e]) in he
    left = topo.edge_faces[:, 0]
    lf = F[left]
    pos_a = np.argmax(lf == a[:, None], axis=1)
    assert np.all(lf[np.arange(topo.n_edges), (pos_a + 1) % 3] == b)
    inner = topo.interior_edges
    rf = F[topo.edge_faces[inner, 1]]
    pos_b = np.argmax(rf == b[inner, None], axis=1)
    assert np.all(rf[np.arange(len(inner)), (pos_b + 1) % 3] == a[inner])
    # face_edges[f, i] is the edge opposite local vertex i
    fe = topo.edges[topo.face_edges]
    for i in range(3):
        assert np.all(np.sort(fe[:, i], axis=1) == np.sort(F[:, [(i + 1) % 3, (i + 2) % 3]], axis=1))
    # every edge appears in exactly one or two faces; Euler's formula
    counts = np.bincount(topo.face_edges.ravel(), minlength=topo.n_edges)
    assert set(np.unique(counts)) <= {1, 2}
    assert np.array_equal(counts == 1, topo.is_boundary_edge)
    assert topo.euler_characteristic == topo.n_vertices - topo.n_edges + topo.n_faces


def test_closed_and_disk_invariants():
    _, F = load_mesh("finger/finger0.ply")
    finger = MeshTopology.from_faces(F)
    assert finger.is_closed and finger.euler_characteristic == 2
    assert list(finger.genus()) == [0] and finger.n_components == 1
    assert finger.boundary_loops() == []
    X, F = load_mesh("plate/plate121.ply")
    plate = MeshTopology.from_faces(F)
    loops = plate.boundary_loops()
    assert len(loops) == 1 and len(loops[0]) == len(plate.boundary_vertices) == 40
    assert list(plate.genus()) == [0] and plate.euler_characteristic == 1
    loop = loops[0]
    # consecutive loop vertices are joined by boundary edges in the edge's direction
    be = {tuple(e) for e in plate.edges[plate.boundary_edges]}
    assert all((loop[k], loop[(k + 1) % len(loop)]) in be for k in range(len(loop)))
    # the surface is on the left: the loop runs counter-clockwise about the plate's normal
    n = np.cross(X[F[0, 1]] - X[F[0, 0]], X[F[0, 2]] - X[F[0, 0]])
    P = X[loop]
    signed_area = 0.5 * np.sum(np.cross(P, np.roll(P, -1, axis=0)), axis=0) @ n
    assert signed_area > 0


def test_vertex_rings_cover_all_interior_corners():
    _, F = load_mesh("sphere/defSphere0.ply")
    topo = MeshTopology.from_faces(F)
    seen = []
    for n, (verts, corners) in topo.vertex_rings().items():
        assert corners.shape == (len(verts), n)
        assert np.all(F.ravel()[corners] == verts[:, None])
        assert np.all(topo.vertex_valence[verts] == n)
        seen.append(verts)
    assert np.array_equal(np.sort(np.concatenate(seen)), np.arange(topo.n_vertices))


def test_caller_edge_order_is_kept():
    X, F = load_mesh("plate/plate121.ply")
    ref = MeshTopology.from_faces(F)
    rng = np.random.default_rng(3)
    perm = rng.permutation(ref.n_edges)
    given = ref.edges[perm].copy()
    flip = rng.random(len(given)) < 0.5
    given[flip] = given[flip, ::-1]
    topo = MeshTopology.from_faces(F, edges=given)
    assert np.array_equal(np.sort(topo.edges, 1), np.sort(given, 1))
    z_ref, z = lengths_and_angles(X, ref), lengths_and_angles(X, topo)
    E = ref.n_edges
    np.testing.assert_allclose(z[:E], z_ref[:E][perm], rtol=0, atol=1e-15)
    np.testing.assert_allclose(z[E:], z_ref[E:][perm], rtol=0, atol=1e-15)


def test_two_components():
    _, F = load_mesh("simple/square4.ply")
    topo = MeshTopology.from_faces(np.vstack([F, F + 5]))
    n, labels = topo.face_components()
    assert n == 2 and np.array_equal(labels, np.repeat([labels[0], labels[4]], 4))
    assert len(topo.boundary_loops()) == 2


def test_dual_graph_symmetric():
    _, F = load_mesh("finger/finger0.ply")
    topo = MeshTopology.from_faces(F)
    G = topo.dual_graph()
    assert (G - G.T).nnz == 0
    assert np.all(np.asarray(G.sum(1)).ravel() == 3)


# ---------------------------------------------------------------------------- bad input
SQUARE = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])


@pytest.mark.parametrize("faces, n_vertices, message", [
    (np.vstack([SQUARE, [[1, 4, 5]]]), None, "non-manifold edges"),
    (np.array([[0, 1, 2], [0, 3, 4]]), None, "non-manifold vertices"),
    (np.vstack([SQUARE[:3], SQUARE[3, ::-1]]), None, "inconsistent winding"),
    (np.array([[0, 1, 1], [1, 2, 0]]), None, "degenerate faces"),
    (np.vstack([SQUARE, SQUARE[[0]][:, [1, 2, 0]]]), None, "repeated faces"),
    (SQUARE, 7, "unreferenced vertices"),
    (SQUARE, 4, "out-of-range"),
    (np.array([[0, 1]]), None, r"shape \(F, 3\)"),
])
def test_bad_connectivity_errors(faces, n_vertices, message):
    with pytest.raises(MeshError, match=message):
        MeshTopology.from_faces(faces, n_vertices=n_vertices)


def test_error_names_elements():
    with pytest.raises(MeshError, match=r"\(1, 4\)"):
        MeshTopology.from_faces(np.vstack([SQUARE, [[1, 4, 5]]]))
    with pytest.raises(MeshError, match=r": 0"):
        MeshTopology.from_faces(np.array([[0, 1, 2], [0, 3, 4]]))


def test_edge_list_mismatch():
    topo = MeshTopology.from_faces(SQUARE)
    with pytest.raises(MeshError, match="lacks triangle edges"):
        MeshTopology.from_faces(SQUARE, edges=topo.edges[1:])
    with pytest.raises(MeshError, match="belong to no triangle"):
        MeshTopology.from_faces(SQUARE, edges=np.vstack([topo.edges[1:], [[0, 2]]]))
    with pytest.raises(MeshError, match="repeats edges"):
        MeshTopology.from_faces(SQUARE, edges=np.vstack([topo.edges, topo.edges[:1, ::-1]]))


def test_bad_coordinates():
    X, F = load_mesh("simple/square4.ply")
    topo = MeshTopology.from_faces(F)
    bad = X.copy()
    bad[3, 1] = np.nan
    with pytest.raises(MeshError, match="NaN or infinite coordinates at vertices 3"):
        lengths_and_angles(bad, topo)
    with pytest.raises(MeshError, match="has 4 vertices but the mesh has 5"):
        check_vertices(X[:4], topo.n_vertices)
    flat = X.copy()
    flat[4] = flat[0]  # collapses faces 0 and 3 (which both use vertices 0 and 4)
    with pytest.raises(MeshError, match="degenerate triangles"):
        check_nondegenerate(flat, topo)


def test_octa_meshes_not_in_correspondence():
    X_src, F_src = load_mesh("octa/octa_src_small.ply")
    X_trg, _ = load_mesh("octa/octa_trg_small.ply")
    topo = MeshTopology.from_faces(F_src, n_vertices=len(X_src))
    with pytest.raises(MeshError, match="601 vertices but the mesh has 600"):
        lengths_and_angles(X_trg, topo)
