"""Homology basis (tree-cotree, lacore.integrability.homology): loop counts, closed cycles, a basis of H_1."""

import numpy as np
import pytest
from conftest import load_topology

from lacore.geometry.topology import MeshTopology
from lacore.integrability.homology import homology_basis
from lacore.samples.human import open_body
from lacore.samples.surfaces import pretzel, pretzel_with_holes


def topo_of(X, F):
    return MeshTopology.from_faces(F, n_vertices=len(X))


def two_components():
    """A torus and an annulus side by side (one mesh, two components)."""
    X1, F1 = pretzel(1, cells=4)
    X2, F2 = pretzel_with_holes(0, 2, cells=4)
    return np.r_[X1, X2 + [3.0, 0, 0]], np.r_[F1, F2 + len(X1)]


MESHES = {                       # name: (builder, genus per component, boundary loops per component)
    "sphere": (lambda: pretzel(0), [0], [0]),
    "disk": (lambda: pretzel_with_holes(0, 1), [0], [1]),
    "annulus": (lambda: pretzel_with_holes(0, 2), [0], [2]),
    "pants": (lambda: pretzel_with_holes(0, 3), [0], [3]),
    "torus": (lambda: pretzel(1), [1], [0]),
    "double_torus": (lambda: pretzel(2), [2], [0]),
    "triple_torus": (lambda: pretzel(3, cells=4), [3], [0]),
    "torus_2_holes": (lambda: pretzel_with_holes(1, 2), [1], [2]),
    "triple_torus_3_holes": (lambda: pretzel_with_holes(3, 3, cells=5), [3], [3]),
    "torus_and_annulus": (two_components, [1, 0], [0, 2]),
}


@pytest.fixture(scope="module")
def body():
    b = open_body()
    return b, topo_of(b.vertices, b.faces)


def check_cycles(topo, B):
    """Every loop is a closed edge cycle and its corridor a closed dual walk next to it."""
    E_ = topo.edges
    for k in range(B.n_loops):
        v, e, fw = B.loop_vertices(k), B.loop_edges(k), B.forward[B.ptr[k]:B.ptr[k + 1]]
        w = np.roll(v, -1)
        assert np.array_equal(np.where(fw, E_[e, 0], E_[e, 1]), v)
        assert np.array_equal(np.where(fw, E_[e, 1], E_[e, 0]), w)
        assert len(np.unique(v)) == len(v)                       # simple cycles
        # corridor: crossing x leaves dual_faces[x] over dual_edges[x] into dual_faces[x + 1] (cyclically)
        s, t = B.dual_ptr[k], B.dual_ptr[k + 1]
        A, c, sg = B.dual_faces[s:t], B.dual_edges[s:t], B.dual_sign[s:t]
        ef = topo.edge_faces[c]
        assert np.all(ef[:, 1] >= 0)                             # interior edges only
        assert np.array_equal(np.where(sg > 0, ef[:, 0], ef[:, 1]), A)
        assert np.array_equal(np.where(sg > 0, ef[:, 1], ef[:, 0]), np.roll(A, -1))
        # every loop edge lies in the face reached after crossings_before crossings
        before = B.crossings_before[B.ptr[k]:B.ptr[k + 1]]
        reached = np.roll(A, -1)[(before - 1) % (t - s)]
        ef_loop = B.edge_faces[B.ptr[k]:B.ptr[k + 1]]
        assert np.array_equal(reached, ef_loop)
        assert np.all((topo.face_edges[ef_loop] == e[:, None]).any(axis=1))


def chains(topo, B):
    out = np.zeros((B.n_loops, topo.n_edges))
    for k in range(B.n_loops):
        s, t = B.ptr[k], B.ptr[k + 1]
        np.add.at(out[k], B.edges[s:t], np.where(B.forward[s:t], 1.0, -1.0))
    return out


@pytest.mark.parametrize("name", MESHES)
def test_counts_and_cycles(name):
    build, genus, n_boundary = MESHES[name]
    topo = topo_of(*build())
    B = homology_basis(topo)
    assert B.genus.tolist() == genus and B.n_boundary_loops.tolist() == n_boundary
    expected = [2 * g + max(b - 1, 0) for g, b in zip(genus, n_boundary, strict=True)]
    assert np.bincount(B.component, minlength=len(genus)).tolist() == expected
    assert B.n_loops == sum(expected)
    assert (B.kind == "handle").sum() == 2 * sum(genus)
    assert list(B.kind) == sorted(B.kind, key=["handle", "hole"].index)          # handles first
    check_cycles(topo, B)
    # holes: every boundary loop but the component's longest, as the boundary loop itself
    loops = topo.boundary_loops()
    for k in np.flatnonzero(B.kind == "hole"):
        j = B.boundary_loop[k]
        assert np.array_equal(B.loop_vertices(k), loops[j])
        assert j != B.reference_hole[B.component[k]]
    _, flab = topo.face_components()
    vlab = np.zeros(topo.n_vertices, np.int64)
    vlab[topo.faces.ravel()] = np.repeat(flab, 3)
    for c, j in enumerate(B.reference_hole):                                      # the longest loop is left out
        mine = [len(lp) for lp in loops if vlab[lp[0]] == c]
        assert (j < 0) == (not mine)
        if mine:
            assert vlab[loops[j][0]] == c and len(loops[j]) == max(mine)
    assert homology_basis(topo) is B                                              # cached on the topology
    B2 = homology_basis(topo_of(*build()))                                        # deterministic
    assert np.array_equal(B2.vertices, B.vertices) and np.array_equal(B2.dual_edges, B.dual_edges)


def arcs_to_reference(topo, B):
    """Per hole loop, a primal path (edges, directions) from its boundary loop to the reference hole's."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import breadth_first_order
    V = topo.n_vertices
    loops = topo.boundary_loops()
    ref = loops[B.reference_hole[0]]
    a, b = topo.edges.T
    G = csr_matrix((np.ones(2 * len(a) + len(ref)), (np.r_[a, b, np.full(len(ref), V)], np.r_[b, a, ref])),
                   shape=(V + 1, V + 1))
    _, pred = breadth_first_order(G, V, return_predecessors=True)
    index = {(min(p, q), max(p, q)): e for e, (p, q) in enumerate(topo.edges.tolist())}
    out = []
    for k in np.flatnonzero(B.kind == "hole"):
        v, es, fw = int(loops[B.boundary_loop[k]][0]), [], []
        while pred[v] != V:
            u = int(pred[v])
            e = index[(min(u, v), max(u, v))]
            es.append(e)
            fw.append(bool(topo.edges[e, 0] == v))
            v = u
        out.append((np.array(es, np.int64), np.array(fw)))
    return out


def intersections(B, rows, cycles):
    """Signed crossings of the corridors of ``rows`` with primal chains ``(edges, forward)``."""
    out = np.zeros((len(rows), len(cycles)), np.int64)
    for a, i in enumerate(rows):
        s, t = B.dual_ptr[i], B.dual_ptr[i + 1]
        crossings = list(zip(B.dual_edges[s:t].tolist(), B.dual_sign[s:t].tolist(), strict=True))
        for b, (edges, fw) in enumerate(cycles):
            sign = dict(zip(edges.tolist(), np.where(fw, 1, -1).tolist(), strict=True))
            out[a, b] = sum(int(sg) * sign.get(c, 0) for c, sg in crossings)
    return out


@pytest.mark.parametrize("name", ["torus", "double_torus", "triple_torus", "annulus", "pants", "torus_2_holes",
                                  "triple_torus_3_holes"])
def test_loops_are_a_homology_basis(name):
    """Intersection numbers of the corridors with the handle loops and with arcs from every hole to the reference
    hole (Lefschetz duality) form a unimodular matrix: the loops are a basis of H_1 over Z; on the handles the
    matrix is antisymmetric."""
    build, genus, n_boundary = MESHES[name]
    topo = topo_of(*build())
    B = homology_basis(topo)
    handles = np.flatnonzero(B.kind == "handle")
    cycles = [(B.loop_edges(k), B.forward[B.ptr[k]:B.ptr[k + 1]]) for k in handles]
    if (B.kind == "hole").any():
        cycles += arcs_to_reference(topo, B)
    M = intersections(B, np.arange(B.n_loops), cycles)
    assert round(abs(np.linalg.det(M))) == 1, M
    Mh = M[np.ix_(handles, np.arange(len(handles)))]
    assert np.array_equal(Mh, -Mh.T)
    assert np.all(M[np.ix_(np.flatnonzero(B.kind == "hole"), np.arange(len(handles)))] == 0)


def test_loops_span_homology_over_q():
    """Small torus with two holes: loop chains and face boundaries have rank ``F + 2g + b - 1`` (dense check)."""
    topo = topo_of(*pretzel_with_holes(1, 2, cells=3, radius=0.06))
    B = homology_basis(topo)
    assert B.n_loops == 3
    faces = np.zeros((topo.n_faces, topo.n_edges))
    faces[np.repeat(np.arange(topo.n_faces), 3), topo.face_edges.ravel()] = np.where(topo.face_edge_is_left.ravel(),
                                                                                     1.0, -1.0)
    assert np.linalg.matrix_rank(np.r_[faces, chains(topo, B)]) - np.linalg.matrix_rank(faces) == 3


@pytest.mark.parametrize("rel", ["sphere/unitSphere1.ply", "finger/finger0.ply", "plate/plate121.ply",
                                 "hyperbolic/monkey_saddle_1.ply"])
def test_shared_meshes_have_no_loops(rel):
    """The shared meshes are spheres and disks: nothing to check beyond the vertices."""
    _, topo = load_topology(rel)
    B = homology_basis(topo)
    assert B.n_loops == 0 and B.vertices.size == 0 and B.dual_faces.size == 0


def test_human_with_openings(body):
    """The body with eyes, mouth and wrists open: genus 0, five boundary loops, four hole loops."""
    b, topo = body
    B = homology_basis(topo)
    assert B.genus.tolist() == [0] and B.n_boundary_loops.tolist() == [5]
    assert B.n_loops == 4 and set(B.kind) == {"hole"}
    lens = sorted(len(lp) for lp in topo.boundary_loops())
    assert lens == sorted(np.diff(B.ptr).tolist() + [len(topo.boundary_loops()[B.reference_hole[0]])])
    assert len(topo.boundary_loops()[B.reference_hole[0]]) == lens[-1]
    check_cycles(topo, B)
    assert [item["label"] for item in B.summary()] == ["hole 0", "hole 1", "hole 2", "hole 3"]
