"""Frame-based reconstruction (thesis 3.4.2): Algorithm 1, Algorithm 2 with the weights (3.30), the
preassembled tree, the triangle-inequality remark and the least-squares relaxation (3.31)-(3.33)."""

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from conftest import shared_mesh
from scipy.sparse import csgraph
from scipy.spatial.transform import Rotation

from lacore.errors import LengthsAnglesError, MeshError
from lacore.integrability.local import integrability_violation
from lacore.integrability.transitions import edge_frame_angles, standard_frames, transition_rotations
from lacore.geometry.lengths_angles import face_areas, face_normals, lengths_and_angles
from lacore.reconstruction.frame_based import (_composition_schedule, _forest_depths, _jump_rounds,
                                               frame_based_reconstruction, propagate_frames)
from lacore.reconstruction.least_squares import least_squares_reconstruction, nearest_rotations
from lacore.reconstruction.spanning_trees import (DualSpanningTree, adaptive_edge_weights,
                                                  bfs_tree, default_root_faces, dual_spanning_tree, forest_levels,
                                                  minimal_spanning_tree, preassembled_tree, shortest_path_tree)
from lacore.geometry.rigid import rigid_align
from lacore.geometry.topology import MeshTopology
from lacore.geometry.trigonometry import interior_angles

KINDS = ("bfs", "mst", "spt")
ADMISSIBLE = ["finger/finger1.ply", "plate/plate4SD_rolledA.ply", "sphere/defSphere3.ply",
              "hyperbolic/monkey_saddle_2.ply", "simple/SteffensPolyhedron.ply"]
_CACHE = {}


def mesh(rel):
    """(topology, vertices, z) of a shared mesh, cached per module."""
    if rel not in _CACHE:
        m = trimesh.load(shared_mesh(rel), process=False)
        X = np.asarray(m.vertices, float)
        topo = MeshTopology.from_faces(np.asarray(m.faces), n_vertices=len(X))
        _CACHE[rel] = (topo, X, lengths_and_angles(X, topo))
    return _CACHE[rel]


def average(a, b):
    """Non-admissible target: the average of the lengths and angles of two poses (thesis 3.4.3)."""
    topo, Xa, za = mesh(a)
    _, Xb, zb = mesh(b)
    return topo, Xa, Xb, 0.5 * (za + zb)


def finger_average():
    return average("finger/finger0.ply", "finger/finger1.ply")


def size(X):
    return float(np.linalg.norm(X.max(0) - X.min(0)))


def z_errors(Y, z, topo):
    """Max length error and max angle error of the reconstruction ``Y`` against ``z``."""
    E = topo.n_edges
    zy = lengths_and_angles(Y, topo)
    return np.abs(zy[:E] - z[:E]).max(), np.abs(zy[E:] - z[E:]).max()


def rigid_residual(Y, X):
    """Max distance after the best rigid alignment (Kabsch) of ``Y`` onto ``X``."""
    return np.abs(rigid_align(Y, X) - X).max()


def quadratic_residual(z, z_target, topo, X_ref, eta=1e-3):
    """W_q (3.19) with the weights (3.20) of the reference ``X_ref``: w_s = 1/l^2, w_b = l^2/d."""
    E = topo.n_edges
    lbar = lengths_and_angles(X_ref, topo)[:E]
    A = face_areas(X_ref, topo.faces)
    ef = topo.edge_faces
    d = (A[ef[:, 0]] + np.where(ef[:, 1] >= 0, A[np.maximum(ef[:, 1], 0)], 0.0)) / 3.0
    wb = np.where(topo.is_boundary_edge, 0.0, lbar ** 2 / d)
    return float(np.sum((z[:E] - z_target[:E]) ** 2 / lbar ** 2) + eta * np.sum(wb * (z[E:] - z_target[E:]) ** 2))


def literal_algorithm_1(z, topo, tree, root_frame, root_position):
    """Algorithm 1 written out literally: one face at a time in the tree's level order, 3x3 matrices."""
    E = topo.n_edges
    L = z[:E][topo.face_edges]
    phi = edge_frame_angles(interior_angles(L))
    R = transition_rotations(z, topo)
    row = np.full(E, -1)
    row[topo.interior_edges] = np.arange(len(topo.interior_edges))
    frames = np.full((topo.n_faces, 3, 3), np.nan)
    X = np.full((topo.n_vertices, 3), np.nan)

    def half_edge(f, i):
        return L[f, i] * frames[f] @ np.array([np.cos(phi[f, i]), np.sin(phi[f, i]), 0.0])

    r = tree.roots[0]
    frames[r] = root_frame
    p0, p1, p2 = topo.faces[r]
    X[p0] = root_position
    X[p1] = X[p0] + half_edge(r, 2)
    X[p2] = X[p0] - half_edge(r, 1)
    for f in tree.order[1:]:
        p, e = tree.parent[f], tree.parent_edge[f]
        Rk = R[row[e]]
        frames[f] = frames[p] @ (Rk if topo.edge_faces[e, 0] == p else Rk.T)     # (3.28)
        for i in range(3):
            v = topo.faces[f, i]
            if np.isnan(X[v, 0]):
                X[v] = X[topo.faces[f, (i + 1) % 3]] - half_edge(f, (i + 2) % 3)   # (3.29)
    return X


def deformed_icosphere(subdivisions=3):
    """A smooth deformation of an icosphere (reproducible, admissible as the z of real vertices)."""
    ico = trimesh.creation.icosphere(subdivisions=subdivisions)
    X = np.asarray(ico.vertices, float)
    X = X * (1.0 + 0.3 * np.sin(2.0 * X[:, [2]]) + 0.2 * X[:, [0]] ** 2) + np.array([0.0, 0.0, 0.4]) * X[:, [0]] ** 2
    topo = MeshTopology.from_faces(np.asarray(ico.faces), n_vertices=len(X))
    return topo, X


# --------------------------------------------------------------------------- admissible targets
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("rel", ADMISSIBLE)
def test_admissible_target_is_reproduced(rel, kind):
    """Theorem 3.2: any tree reproduces admissible lengths and angles; placed in the reference frame, X itself."""
    topo, X, z = mesh(rel)
    h = size(X)
    Y = frame_based_reconstruction(z, topo, kind=kind)
    dl, dt = z_errors(Y, z, topo)
    assert dl <= 1e-10 * h
    assert dt <= 1e-9
    assert rigid_residual(Y, X) <= 1e-10 * h
    Y = frame_based_reconstruction(z, topo, kind=kind, reference_vertices=X)
    assert np.abs(Y - X).max() <= 1e-10 * h


@pytest.mark.parametrize("kind", KINDS)
def test_propagated_frames_are_the_standard_frames(kind):
    """(3.28) along the tree gives the standard frames of the immersion for admissible z."""
    topo, X, z = mesh("finger/finger1.ply")
    frames = propagate_frames(z, topo, kind=kind, reference_vertices=X)
    assert np.abs(frames - standard_frames(X, topo.faces)).max() < 1e-11


@pytest.mark.parametrize("kind", KINDS)
def test_generated_mesh_and_explicit_root_placement(kind):
    topo, X = deformed_icosphere()
    z = lengths_and_angles(X, topo)
    Q = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    t = np.array([1.0, -2.0, 0.5])
    root = 17
    Y = frame_based_reconstruction(z, topo, kind=kind, root_face=root, root_frame=Q, root_position=t)
    assert np.allclose(Y[topo.faces[root, 0]], t, atol=1e-14)
    assert np.abs(standard_frames(Y, topo.faces[[root]])[0] - Q).max() < 1e-13
    assert rigid_residual(Y, X) < 1e-12 * size(X)


def test_walk_matches_literal_algorithm_1_on_non_admissible_targets():
    """The vectorized walk (quaternions, pointer jumping, raked leaves) is Algorithm 1 exactly, also where the
    order of reconstruction matters (non-admissible targets) and for deep adaptive trees."""
    for topo, X0, _, z in (finger_average(), average("plate/plate121_rolledA.ply", "plate/plate121_rolledB.ply")):
        h = size(X0)
        for kind in KINDS:
            tree = dual_spanning_tree(topo, kind=kind, z=z)
            frame = standard_frames(X0, topo.faces[tree.roots])[0]
            pos = X0[topo.faces[tree.roots[0], 0]]
            Y = frame_based_reconstruction(z, topo, tree=tree, reference_vertices=X0)
            ref = literal_algorithm_1(z, topo, tree, frame, pos)
            assert np.abs(Y - ref).max() < 1e-10 * h, kind


# --------------------------------------------------------------------------- spanning trees
def check_tree(tree, topo):
    F = topo.n_faces
    child = np.flatnonzero(tree.parent >= 0)
    assert len(child) == F - len(tree.roots)
    ef = topo.edge_faces[tree.parent_edge[child]]
    assert np.all(np.sort(ef, 1) == np.sort(np.stack([child, tree.parent[child]], 1), 1))
    assert np.all(tree.depth[child] == tree.depth[tree.parent[child]] + 1)
    assert np.array_equal(np.sort(tree.order), np.arange(F))
    assert np.all(np.diff(tree.depth[tree.order]) >= 0)
    for d, level in enumerate(tree.levels()):
        assert np.all(tree.depth[level] == d)


def test_tree_properties():
    topo, X0, _, z = finger_average()
    root = int(default_root_faces(topo, vertices=X0)[0])
    w = adaptive_edge_weights(z, topo)
    trees = {k: dual_spanning_tree(topo, root, kind=k, z=z) for k in KINDS}
    for t in trees.values():
        check_tree(t, topo)
        assert t.root_face == root
    # BFS: depth = unweighted dual distance
    G = topo.dual_graph()
    dist = csgraph.shortest_path(G, unweighted=True, indices=root)
    assert np.array_equal(trees["bfs"].depth, dist.astype(int))
    # MST: minimal total weight (compare with scipy's MST on the same weights)
    wi = w[topo.interior_edges] + 1e-9 * w.max()
    d = topo.dual_edges
    mst = csgraph.minimum_spanning_tree(sp.csr_matrix((wi, (d[:, 0], d[:, 1])), shape=G.shape))
    assert trees["mst"].total_weight(w + 1e-9 * w.max()) == pytest.approx(mst.sum(), rel=1e-12)
    assert trees["mst"].total_weight(w) < trees["bfs"].total_weight(w)
    # SPT: the tree path weights are the shortest path distances
    dsp = csgraph.dijkstra(topo.dual_graph(w + 1e-9 * w.max()), indices=root)
    spt = trees["spt"]
    path = np.zeros(topo.n_faces)
    for f in spt.order[1:]:
        path[f] = path[spt.parent[f]] + w[spt.parent_edge[f]] + 1e-9 * w.max()
    assert np.allclose(path, dsp, rtol=1e-12, atol=0)
    # the adaptive trees are deeper than the BFS tree (thesis 3.4.3)
    assert trees["mst"].max_depth > trees["spt"].max_depth > trees["bfs"].max_depth


@pytest.mark.parametrize("block", [2, 3, 4, 8, 64, 10000])
def test_two_level_pointer_jumping_composes_root_paths(block):
    """The composition schedule (blocks, portals, raked leaves) equals the sequential root-path sums."""
    rng = np.random.default_rng(11)
    n = 3000
    parent = np.full(n, -1)
    for v in range(3, n):                       # three roots; long chains (deep tree) mixed with branching
        parent[v] = v - 1 if rng.random() < 0.9 else rng.integers(0, v)
    order, _, depth = forest_levels(parent, np.arange(3))
    need = rng.random(n) < 0.8
    need[:3] = True
    for v in order[::-1]:                       # needed = marked nodes and all their ancestors
        if need[v] and parent[v] >= 0:
            need[parent[v]] = True
    nodes, steps, used_block = _composition_schedule(parent, depth, order, need, parent < 0, block=block)
    assert np.array_equal(np.sort(nodes), np.flatnonzero(need))
    value = rng.normal(size=(n, 2))
    expected = value.copy()
    for v in order:
        if parent[v] >= 0:
            expected[v] += expected[parent[v]]
    D = value[nodes].copy()
    for s, e, tgt in steps:
        D[s:e] += D.take(tgt, axis=0)
    assert np.abs(D - expected[nodes]).max() < 1e-9
    assert depth.max() > 100
    assert used_block == block if block <= 8 else used_block > depth[nodes].max() // 2


def test_forest_depths_and_jump_rounds():
    """Pointer-jumping depths equal the BFS depths; the jump rounds compose whole root paths."""
    rng = np.random.default_rng(5)
    n = 2000
    parent = np.full(n, -1)
    for v in range(2, n):
        parent[v] = v - 1 if rng.random() < 0.95 else rng.integers(0, v)
    perm = rng.permutation(n)                   # node labels in no particular order
    inv = np.empty(n, np.int64)
    inv[perm] = np.arange(n)
    parent = np.where(parent[perm] >= 0, inv[np.maximum(parent[perm], 0)], -1)
    order, _, depth = forest_levels(parent, np.flatnonzero(parent < 0))
    assert np.array_equal(_forest_depths(parent), depth)
    assert np.array_equal(_forest_depths(np.full(4, -1)), np.zeros(4, np.int64))
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    pr = np.where(parent[order] >= 0, rank[np.maximum(parent[order], 0)], -1)
    value = rng.normal(size=n)
    D = value[order].copy()
    for s, tgt in _jump_rounds(pr, depth[order]):
        D[s:] += D.take(tgt)
    expected = value.copy()
    for v in order:
        if parent[v] >= 0:
            expected[v] += expected[parent[v]]
    assert np.abs(D - expected[order]).max() < 1e-9
    assert _jump_rounds(np.full(3, -1), np.zeros(3, np.int64)) == []


def test_bfs_tree_is_cached_and_walk_indices_are_reused():
    topo, X, z = mesh("finger/finger1.ply")
    t1 = bfs_tree(topo, 5)
    assert bfs_tree(topo, 5) is t1
    frame_based_reconstruction(z, topo, tree=t1)
    sched = t1.cache.peek(("lacore.reconstruction.frame_based", "walk_schedule", True))[1]
    frame_based_reconstruction(0.5 * z, topo, tree=t1)
    assert t1.cache.peek(("lacore.reconstruction.frame_based", "walk_schedule", True))[1] is sched


def test_tree_from_parents_and_errors():
    topo, X, z = mesh("plate/plate121_rolledA.ply")
    t = bfs_tree(topo, 0)
    t2 = DualSpanningTree.from_parents(topo, t.parent)
    assert np.array_equal(t2.parent_edge, t.parent_edge) and np.array_equal(t2.depth, t.depth)
    f = t.order[-1]
    far = t.order[np.flatnonzero(~np.isin(t.order, topo.edge_faces[topo.face_edges[f]].ravel()))[0]]
    bad = t.parent.copy()
    bad[f] = far
    with pytest.raises(MeshError, match="not adjacent"):
        DualSpanningTree.from_parents(topo, bad)
    a = t.order[1]                              # a child of the root ...
    b = np.flatnonzero(t.parent == a)[0]        # ... and its child: make them each other's parent (a cycle)
    cyc = t.parent.copy()
    cyc[a] = b
    with pytest.raises(MeshError, match="not reachable"):
        DualSpanningTree.from_parents(topo, cyc)
    other, _, zo = mesh("sphere/defSphere3.ply")
    with pytest.raises(MeshError, match="faces"):
        frame_based_reconstruction(zo, other, tree=t)
    with pytest.raises(ValueError, match="kind"):
        frame_based_reconstruction(z, topo, kind="dfs")
    with pytest.raises(ValueError, match="z"):
        dual_spanning_tree(topo, 0, kind="mst")


# --------------------------------------------------------------------------- weights (3.30)
def test_adaptive_weights_average_the_vertex_violation():
    topo, X0, _, z = finger_average()
    v = integrability_violation(z, topo)
    assert v.max() > 1e-3                                        # really non-admissible
    w = adaptive_edge_weights(z, topo)
    e = topo.edges
    assert np.allclose(w, 0.5 * (v[e[:, 0]] + v[e[:, 1]]), rtol=1e-12, atol=1e-13)
    _, _, z1 = mesh("finger/finger1.ply")
    assert adaptive_edge_weights(z1, topo).max() < 1e-12        # admissible: (numerically) zero weights
    # triangle-inequality violations: inf in the violation, "visited last" finite weights
    rng = np.random.default_rng(7)
    zb = z.copy()
    zb[:topo.n_edges] *= rng.uniform(0.1, 3.0, topo.n_edges)
    vb = integrability_violation(zb, topo)
    assert np.isinf(vb).sum() > 100
    wb = adaptive_edge_weights(zb, topo)
    assert np.all(np.isfinite(wb))
    big = wb.max()
    ok = np.isfinite(0.5 * (vb[e[:, 0]] + vb[e[:, 1]]))
    assert big == pytest.approx(10 * (0.5 * (vb[e[ok, 0]] + vb[e[ok, 1]])).max() + 1)


# --------------------------------------------------------------------------- non-admissible targets
def test_finger_average_adaptive_trees_beat_bfs():
    """Thesis 3.4.3 (finger): BFS walks over the violation, MST/SPT avoid it; measured W_q (eta = 1e-3,
    weights of finger0): BFS 6.18, MST 0.190, SPT 0.324, least squares 0.0229."""
    topo, X0, X1, z = finger_average()
    res = {}
    n0 = face_normals(X0, topo.faces)
    for kind in KINDS + ("lsq",):
        if kind == "lsq":
            Y = least_squares_reconstruction(z, topo, reference_vertices=X0)
        else:
            Y = frame_based_reconstruction(z, topo, kind=kind, reference_vertices=X0)
        assert np.all(np.isfinite(Y))
        res[kind] = quadratic_residual(lengths_and_angles(Y, topo), z, topo, X0)
        # no flipped triangles: normals agree with the reference pose, no dihedral angle off by > pi/2
        assert np.mean(np.sum(face_normals(Y, topo.faces) * n0, 1) > 0) > 0.999
        E = topo.n_edges
        assert np.all(np.abs(lengths_and_angles(Y, topo)[E:] - z[E:]) < np.pi / 2)
    assert res["mst"] < 0.1 * res["bfs"]
    assert res["spt"] < 0.1 * res["bfs"]
    assert res["lsq"] < res["mst"]
    assert 5.0 < res["bfs"] < 7.5


def test_rolled_plate_average_finite():
    """Non-localized violation (two plates rolled differently): all methods stay finite; least squares is best
    (measured W_q: BFS 137, MST 1.6e4, SPT 1.1e3, least squares 15.6 -- the adaptive trees get deep and jump,
    like the cactus of thesis Fig. 3.8)."""
    topo, X0, _, z = average("plate/plate4SD_rolledA.ply", "plate/plate4SD_rolledB.ply")
    res = {}
    for kind in KINDS + ("lsq",):
        Y = (least_squares_reconstruction(z, topo, reference_vertices=X0) if kind == "lsq"
             else frame_based_reconstruction(z, topo, kind=kind, reference_vertices=X0))
        assert np.all(np.isfinite(Y))
        res[kind] = quadratic_residual(lengths_and_angles(Y, topo), z, topo, X0)
    assert res["lsq"] < min(res[k] for k in KINDS)


def test_preassembled_tree_serves_an_interpolation_path():
    """Remark after Algorithm 2: weights = max over samples; one tree for all targets on the path."""
    topo, X0, X1, _ = finger_average()
    z0, z1 = lengths_and_angles(X0, topo), lengths_and_angles(X1, topo)
    samples = np.array([(1 - t) * z0 + t * z1 for t in np.linspace(0.0, 1.0, 5)])
    w = np.max([adaptive_edge_weights(s, topo) for s in samples], axis=0)
    for kind in ("mst", "spt"):
        tree = preassembled_tree(samples, topo, root_face=None, kind=kind)
        check_tree(tree, topo)
        ref = (minimal_spanning_tree if kind == "mst" else shortest_path_tree)(topo, tree.roots, w)
        assert np.array_equal(tree.parent, ref.parent)
        h = size(X0)
        # endpoints are admissible: reproduced exactly with the same tree
        for zt, Xt in ((z0, X0), (z1, X1)):
            assert rigid_residual(frame_based_reconstruction(zt, topo, tree=tree), Xt) < 1e-10 * h
        # intermediate targets: finite and as good as the per-target adaptive tree, much better than BFS
        for t in (0.25, 0.5, 0.75):
            zt = (1 - t) * z0 + t * z1
            Y = frame_based_reconstruction(zt, topo, tree=tree, reference_vertices=X0)
            assert np.all(np.isfinite(Y))
            r_pre = quadratic_residual(lengths_and_angles(Y, topo), zt, topo, X0)
            r_bfs = quadratic_residual(lengths_and_angles(
                frame_based_reconstruction(zt, topo, kind="bfs", reference_vertices=X0), topo), zt, topo, X0)
            assert r_pre < 0.2 * r_bfs
    with pytest.raises(ValueError, match="kind"):
        preassembled_tree(samples, topo, kind="bfs")


def test_triangle_inequality_violated_everywhere_is_finite():
    """Remark after Algorithm 2: triangles violating (T) get interior angles 0; best effort, never NaN."""
    topo, X0, _, z = finger_average()
    rng = np.random.default_rng(3)
    zb = z.copy()
    zb[:topo.n_edges] *= rng.uniform(0.1, 3.0, topo.n_edges)
    L = zb[:topo.n_edges][topo.face_edges]
    assert np.mean(L.sum(1) - 2 * L.max(1) <= 0) > 0.3
    for kind in KINDS:
        Y = frame_based_reconstruction(zb, topo, kind=kind)
        assert np.all(np.isfinite(Y))
    assert np.all(np.isfinite(least_squares_reconstruction(zb, topo)))
    assert np.all(np.isfinite(preassembled_tree([z, zb], topo).depth))


# --------------------------------------------------------------------------- least squares (3.31)-(3.33)
@pytest.mark.parametrize("rel", ["finger/finger1.ply", "hyperbolic/monkey_saddle_2.ply",
                                 "simple/SteffensPolyhedron.ply"])
def test_least_squares_reproduces_admissible_targets(rel):
    topo, X, z = mesh(rel)
    h = size(X)
    for method in ("two_step", "composite"):
        Y = least_squares_reconstruction(z, topo, reference_vertices=X, method=method)
        assert np.abs(Y - X).max() < 1e-8 * h
        Y = least_squares_reconstruction(z, topo, method=method, frame_weight=10.0)
        assert rigid_residual(Y, X) < 1e-8 * h


def test_nearest_rotations_match_the_svd_projection():
    rng = np.random.default_rng(5)
    M = rng.normal(size=(500, 3, 3))
    M[:10] = 1e-12 * rng.normal(size=(10, 3, 3)) + np.eye(3)[None, [0, 0, 1]]   # rank 1 (singular) matrices
    u, _, vt = np.linalg.svd(M)
    u[np.linalg.det(u @ vt) < 0, :, 2] *= -1.0
    R = nearest_rotations(M)
    assert np.abs(R[10:] - (u @ vt)[10:]).max() < 1e-12
    assert np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max() < 1e-13
    assert np.all(np.linalg.det(R) > 0)


def test_least_squares_caches_the_position_factorization():
    topo, X, z = mesh("sphere/defSphere3.ply")
    w = np.linspace(1.0, 2.0, topo.n_edges)
    least_squares_reconstruction(z, topo, reference_vertices=X, edge_weights=w)
    cache = topo.cache.peek(("lacore.reconstruction.least_squares", "factors"))
    entries = {k: v for k, v in cache.items() if k[0] == "positions"}
    Y = least_squares_reconstruction(0.5 * z + 0.5 * lengths_and_angles(X * 1.1, topo), topo, reference_vertices=X,
                                     edge_weights=w)
    assert {k: v for k, v in cache.items() if k[0] == "positions"} == entries
    assert np.all(np.isfinite(Y))
    Yw = least_squares_reconstruction(z, topo, reference_vertices=X, edge_weights=w)
    assert np.abs(Yw - X).max() < 1e-8 * size(X)


# --------------------------------------------------------------------------- components, bad input
def test_several_components():
    ta, Xa = deformed_icosphere(2)
    _, Xb, _ = mesh("plate/plate121_rolledA.ply")
    fb = mesh("plate/plate121_rolledA.ply")[0].faces
    X = np.r_[Xa, Xb + 3.0]
    topo = MeshTopology.from_faces(np.r_[ta.faces, fb + len(Xa)], n_vertices=len(X))
    assert topo.n_components == 2
    z = lengths_and_angles(X, topo)
    for kind in KINDS:
        Y = frame_based_reconstruction(z, topo, kind=kind, reference_vertices=X)
        assert np.abs(Y - X).max() < 1e-10 * size(X)
    assert np.abs(least_squares_reconstruction(z, topo, reference_vertices=X) - X).max() < 1e-8 * size(X)
    with pytest.raises(MeshError, match="2 connected components"):
        frame_based_reconstruction(z, topo, root_face=0)
    roots = default_root_faces(topo, vertices=X)
    assert len(roots) == 2
    Y = frame_based_reconstruction(z, topo, root_face=roots[::-1])
    assert np.all(np.isfinite(Y))


def test_distance_sums_are_those_of_one_search_per_source():
    """The root tie-break's sums of dual distances (64 sources per bit-parallel search) equal one breadth-first
    search per source, also across chunks of 64, from a repeated source, and with nodes a source cannot reach."""
    from lacore.reconstruction.spanning_trees import _distance_sums, _dual_csr

    rng = np.random.default_rng(3)
    A = sp.random(300, 300, density=0.01, random_state=4, format="csr")
    A = ((A + A.T) != 0).astype(float)
    A = sp.block_diag([A, sp.csr_matrix((5, 5))], format="csr")             # five isolated nodes
    sources = np.r_[rng.choice(305, 130, replace=False), 7, 7]
    d = csgraph.shortest_path(A, unweighted=True, indices=sources)
    expected = np.where(np.isfinite(d), d, 0.0).sum(axis=1)
    assert expected.max() > 1000 and (expected == 0).any()
    assert np.array_equal(_distance_sums(A, sources), expected)
    topo, _ = deformed_icosphere(2)
    G = _dual_csr(topo)
    faces = np.arange(0, topo.n_faces, 3)
    d = csgraph.shortest_path(G, unweighted=True, indices=faces)
    assert np.array_equal(_distance_sums(G, faces), d.sum(axis=1))


def test_bad_input():
    topo, X, z = mesh("finger/finger1.ply")
    E = topo.n_edges
    for fn in (frame_based_reconstruction, least_squares_reconstruction, adaptive_edge_weights):
        with pytest.raises(LengthsAnglesError, match="shape"):
            fn(z[:-1], topo)
        zn = z.copy()
        zn[E + 3] = np.nan
        with pytest.raises(LengthsAnglesError, match="NaN"):
            fn(zn, topo)
        zn = z.copy()
        zn[4] = -1.0
        with pytest.raises(LengthsAnglesError, match="non-positive"):
            fn(zn, topo)
    with pytest.raises(LengthsAnglesError):
        preassembled_tree(np.zeros((2, 5)), topo)
    octa_src = trimesh.load(shared_mesh("octa/octa_src_small.ply"), process=False)
    octa_trg = trimesh.load(shared_mesh("octa/octa_trg_small.ply"), process=False)
    ot = MeshTopology.from_faces(np.asarray(octa_src.faces), n_vertices=len(octa_src.vertices))
    oz = lengths_and_angles(np.asarray(octa_src.vertices), ot)
    with pytest.raises(MeshError, match="601 vertices but the mesh has 600"):
        frame_based_reconstruction(oz, ot, reference_vertices=np.asarray(octa_trg.vertices))
    with pytest.raises(MeshError, match="601 vertices but the mesh has 600"):
        least_squares_reconstruction(oz, ot, reference_vertices=np.asarray(octa_trg.vertices))
    with pytest.raises(ValueError, match="rotation"):
        frame_based_reconstruction(z, topo, root_frame=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(MeshError, match="root"):
        frame_based_reconstruction(z, topo, root_face=[1, 2])
    with pytest.raises(ValueError, match="edge_weights"):
        minimal_spanning_tree(topo, 0, -np.ones(E))


def test_mst_single_root_fast_path_matches_generic_rooting():
    """The undirected search over the one-directional MST gives the same rooted tree as a symmetric copy."""
    from lacore.reconstruction.spanning_trees import _bfs_forest, _csr_from_pairs, _dual_csr, _interior_weights

    topo, X0, _, z = finger_average()
    roots = default_root_faces(topo, vertices=X0)
    w = adaptive_edge_weights(z, topo)
    tree = minimal_spanning_tree(topo, roots, w)
    mst = csgraph.minimum_spanning_tree(_dual_csr(topo, _interior_weights(topo, w), "one"))
    F = topo.n_faces
    rows = np.repeat(np.arange(F), np.diff(mst.indptr))
    cols = mst.indices.astype(np.int64)
    order, pred = _bfs_forest(_csr_from_pairs(np.r_[rows, cols], np.r_[cols, rows], F), roots)
    assert np.array_equal(tree.parent, pred)
    assert np.array_equal(tree.order, order)
    # parent edges join parent and child
    child = np.flatnonzero(tree.parent >= 0)
    ef = topo.edge_faces[tree.parent_edge[child]]
    assert np.all(np.sort(ef, 1) == np.sort(np.c_[child, tree.parent[child]], 1))
    assert np.all(tree.parent_edge[tree.parent < 0] == -1)
