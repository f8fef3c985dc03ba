"""A homology basis of an oriented manifold triangle mesh with boundary (thesis Theorem 3.2, [Epp03]).

Theorem 3.2 asks, besides the condition at every interior vertex, that the
frames close around every loop of a *dual* homology basis and that the edge
vectors close around every loop of a *primal* one.  :func:`homology_basis`
returns, per connected component of genus ``g`` with ``b`` boundary loops,
``2g + b - 1`` loops (``2g`` on a closed component; none on a sphere or a disk):

``"handle"`` loops (``2g``)
    Tree-cotree decomposition (Eppstein 2003) in which every boundary loop is
    contracted to one node: a breadth-first tree ``T`` of the graph whose nodes
    are the interior vertices and the boundary loops (its edges: the interior
    edges), then a breadth-first tree ``T*`` of the dual graph (faces, interior
    edges) that crosses no edge of ``T``.  Each interior edge in neither tree
    closes one loop with its path in ``T``; where that path passes a boundary
    node, the loop follows the boundary loop between the two edges of ``T``
    (the primal spanning tree contains every boundary loop but for one edge).
``"hole"`` loops (``b - 1``)
    The boundary loops, except the component's longest one (the *reference
    hole*): all boundary loops together bound the surface, so the conditions
    around the reference hole follow from those around the others.

Every loop is a closed cycle of primal edges (``vertices[k]`` to
``vertices[k + 1]`` along ``edges[k]``, cyclically).  Its *corridor* is the
matching dual loop: the faces met by turning, at every loop vertex, from the
face of the incoming edge to the face of the outgoing one (the face to the
loop's left where the edge has one; around an interior vertex the shorter way,
around a boundary vertex the only way).  A corridor is a closed dual walk
freely homotopic to its loop.

Why these loops suffice: the loops generate the fundamental group of the
surface (with the boundary contracted the primal tree leaves exactly ``2g``
cotree edges, and the ``b - 1`` boundary loops supply the free generators the
contraction removed).  So if the frames close around every interior vertex
ring and around every corridor, they close around every dual cycle: the frame
field is consistent (conditions (i) and (ii)).  The edge vectors then form a
closed 1-form, whose periods are linear in the homology class; the loops span
the first homology group (the face boundaries and the loops have rank
``F + 2g + b - 1``), so their accumulated translations are the only periods left
(condition (iii)).

Cost: the basis depends on the connectivity only and is cached on the
topology (``topology.cache``).  Meshes without handles need no trees (a genus-0
mesh has hole loops only).
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

__all__ = ["HomologyBasis", "homology_basis", "LOOP_KINDS"]

#: Kinds of basis loops.
LOOP_KINDS = ("handle", "hole")


@dataclass(frozen=True, eq=False, repr=False)
class HomologyBasis:
    """Loops generating the first homology (and the fundamental group) of a mesh; see the module docstring.

    Build with :func:`homology_basis`.  All arrays are read-only; per-loop data
    of the flat arrays lies in ``ptr[k]:ptr[k + 1]`` (``dual_ptr`` for the corridors).

    Attributes
    ----------
    n_loops : int
    kind : (n,) str array
        ``"handle"`` or ``"hole"``; handles come first, ordered by component.
    component : (n,) int64
        Face component of each loop (labels of ``topology.face_components()``).
    boundary_loop : (n,) int64
        Index into ``topology.boundary_loops()`` of a hole, ``-1`` for a handle.
    genus, n_boundary_loops : (C,) int64
        Per component.
    reference_hole : (C,) int64
        The boundary loop of each component whose loop is left out, ``-1`` if closed.
    ptr : (n + 1,) int64
    vertices, edges : (M,) int64
        The loops as closed cycles: edge ``edges[i]`` joins ``vertices[i]`` and
        the next vertex of the same loop (cyclically).
    forward : (M,) bool
        The loop runs along the edge's stored orientation (``topology.edges[e]``).
    edge_faces : (M,) int64
        Face of every loop edge used for its edge vector: the face to the loop's left where there is one.
    dual_ptr : (n + 1,) int64
    dual_faces, dual_edges : (N,) int64
        The corridors: crossing ``x`` leaves face ``dual_faces[x]`` over edge ``dual_edges[x]``; the face
        after the last crossing of a loop is the face of its first crossing.
    dual_sign : (N,) float64
        ``+1`` where the crossing leaves the edge's left face, ``-1`` where it leaves its right face.
    crossings_before : (M,) int64
        Crossings of the corridor before loop edge ``i`` (``0 .. C_k``); the edge lies in the face reached then.
    """

    n_loops: int
    kind: np.ndarray
    component: np.ndarray
    boundary_loop: np.ndarray
    genus: np.ndarray
    n_boundary_loops: np.ndarray
    reference_hole: np.ndarray
    ptr: np.ndarray
    vertices: np.ndarray
    edges: np.ndarray
    forward: np.ndarray
    edge_faces: np.ndarray
    dual_ptr: np.ndarray
    dual_faces: np.ndarray
    dual_edges: np.ndarray
    dual_sign: np.ndarray
    crossings_before: np.ndarray

    def __repr__(self):
        kinds = dict(zip(*np.unique(self.kind, return_counts=True), strict=True)) if self.n_loops else {}
        return (f"HomologyBasis(n_loops={self.n_loops}, handles={int(kinds.get('handle', 0))}, "
                f"holes={int(kinds.get('hole', 0))}, genus={self.genus.tolist()}, "
                f"boundary_loops={self.n_boundary_loops.tolist()})")

    def loop_vertices(self, k):
        """Vertex cycle of loop ``k``."""
        return self.vertices[self.ptr[k]:self.ptr[k + 1]]

    def loop_edges(self, k):
        """Edge cycle of loop ``k``."""
        return self.edges[self.ptr[k]:self.ptr[k + 1]]

    def loop_faces(self, k):
        """Faces of the corridor (dual loop) of loop ``k``, one per crossing."""
        return self.dual_faces[self.dual_ptr[k]:self.dual_ptr[k + 1]]

    def label(self, k):
        """``"handle 0"``, ``"hole 1"``, ... (numbered per kind, in basis order)."""
        kind = str(self.kind[k])
        return f"{kind} {int(np.count_nonzero(self.kind[:k] == kind))}"

    def summary(self):
        """JSON-friendly description of the loops (no index arrays)."""
        return [{"loop": k, "label": self.label(k), "kind": str(self.kind[k]), "component": int(self.component[k]),
                 "boundary_loop": int(self.boundary_loop[k]), "edges": int(self.ptr[k + 1] - self.ptr[k])}
                for k in range(self.n_loops)]


def homology_basis(topology):
    """The homology basis of a mesh (module docstring), cached on the topology.

    Parameters
    ----------
    topology : MeshTopology

    Returns
    -------
    HomologyBasis

    Examples
    --------
    >>> from lacore import MeshTopology, homology_basis
    >>> from lacore.samples.surfaces import pretzel_with_holes
    >>> X, faces = pretzel_with_holes(1, 2)        # a torus with two holes
    >>> basis = homology_basis(MeshTopology.from_faces(faces, n_vertices=len(X)))
    >>> basis.kind.tolist()                        # 2 g + b - 1 loops
    ['handle', 'handle', 'hole']
    """
    return topology.cache.get((__name__, "basis"), lambda: _build(topology))


# --------------------------------------------------------------------------- construction
def _build(topology):
    V = topology.n_vertices
    n_comp, flab = topology.face_components()
    loops = topology.boundary_loops()
    nl = len(loops)
    genus = np.asarray(topology.genus(), np.int64)
    # the boundary edge leaving every boundary vertex (boundary loops follow their edges' orientation)
    b_edges = topology.boundary_edges
    out_edge = np.full(V, -1, np.int64)
    out_edge[topology.edges[b_edges, 0]] = b_edges
    loop_comp = np.array([flab[topology.edge_faces[out_edge[lp[0]], 0]] for lp in loops], np.int64)
    nb = np.bincount(loop_comp, minlength=n_comp).astype(np.int64)
    lens = np.array([len(lp) for lp in loops], np.int64)
    ref = np.full(n_comp, -1, np.int64)
    for j in (np.lexsort((np.arange(nl), -lens)) if nl else []):      # the longest loop, ties by index
        if ref[loop_comp[j]] < 0:
            ref[loop_comp[j]] = j
    cyc_v, cyc_e, comps = [], [], []
    if genus.any():
        _handle_loops(topology, loops, ref, flab, genus, out_edge, cyc_v, cyc_e, comps)
    n_handles = len(cyc_v)
    holes = [j for j in range(nl) if ref[loop_comp[j]] != j]
    for j in holes:
        cyc_v.append(np.asarray(loops[j], np.int64))
        cyc_e.append(out_edge[loops[j]])
        comps.append(int(loop_comp[j]))
    n = len(cyc_v)
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum([len(c) for c in cyc_v], out=ptr[1:])
    verts = np.concatenate(cyc_v) if n else np.zeros(0, np.int64)
    edges = np.concatenate(cyc_e) if n else np.zeros(0, np.int64)
    forward = topology.edges[edges, 0] == verts
    corr = _corridors(topology, ptr, verts, edges, forward)
    basis = HomologyBasis(
        n_loops=n, kind=np.array(["handle"] * n_handles + ["hole"] * len(holes), dtype="<U6"),
        component=np.array(comps, np.int64), boundary_loop=np.array([-1] * n_handles + holes, np.int64),
        genus=genus, n_boundary_loops=nb, reference_hole=ref, ptr=ptr, vertices=verts, edges=edges,
        forward=forward, **corr)
    for value in vars(basis).values():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return basis


def _bfs_forest(n, a, b, roots):
    """Breadth-first forest of the undirected graph with edges ``(a[k], b[k])`` on nodes ``0 .. n-1``.

    Returns the predecessors (``-1`` at roots and unreached nodes) and, per
    node, the index ``k`` of an edge joining it to its predecessor (``-1`` at roots).
    """
    rows = np.concatenate((a, b, np.full(len(roots), n)))
    cols = np.concatenate((b, a, roots))
    G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + 1, n + 1))
    _, pred = csgraph.breadth_first_order(G, n, directed=True, return_predecessors=True)
    pred = pred[:n].astype(np.int64)
    pred[(pred < 0) | (pred >= n)] = -1
    tree = np.full(n, -1, np.int64)
    k = np.arange(len(a))
    for child, parent in ((a, b), (b, a)):
        hit = pred[child] == parent
        tree[child[hit]] = k[hit]
    return pred, tree


def _dual_bfs_forest(topology, blocked, roots):
    """Breadth-first forest of the dual graph (faces; interior edges not ``blocked``) from ``roots``.

    The graph is the ``(F, 3)`` table of the faces across every face's edges
    (the face itself across a boundary or blocked edge), so no sorting is
    needed.  Returns the tree edge of every face (``-1`` at the roots).
    """
    F = topology.n_faces
    fe = topology.face_edges.ravel()
    left = np.ascontiguousarray(topology.edge_faces[:, 0]).take(fe)
    right = np.ascontiguousarray(topology.edge_faces[:, 1]).take(fe)
    other = np.where(topology.face_edge_is_left.ravel(), right, left)   # the face across (-1 at the boundary)
    cut = (other < 0) | blocked.take(fe)
    other[cut] = np.flatnonzero(cut) // 3                              # a loop to the face itself
    indptr = np.r_[np.arange(0, 3 * F + 1, 3), 3 * F + len(roots)]
    G = sp.csr_matrix((np.ones(3 * F + len(roots)), np.r_[other, roots], indptr), shape=(F + 1, F + 1))
    _, pred = csgraph.breadth_first_order(G, F, directed=True, return_predecessors=True)
    pred = pred[:F].astype(np.int64)
    child = np.flatnonzero((pred >= 0) & (pred < F))
    p = pred[child]
    o = other.reshape(F, 3)[child]
    slot = np.where(o[:, 0] == p, 0, np.where(o[:, 1] == p, 1, 2))
    tree = np.full(F, -1, np.int64)
    tree[child] = fe.take(3 * child + slot)
    return tree


def _tree_path(pred, u, w):
    """Nodes of the tree path ``u -> w`` (inclusive); ``pred`` is a list."""
    pu, pw = [u], [w]
    while pred[pu[-1]] >= 0:
        pu.append(pred[pu[-1]])
    while pred[pw[-1]] >= 0:
        pw.append(pred[pw[-1]])
    while len(pu) > 1 and len(pw) > 1 and pu[-2] == pw[-2]:
        pu.pop()
        pw.pop()
    return pu + pw[-2::-1]


def _handle_loops(topology, loops, ref, flab, genus, out_edge, cyc_v, cyc_e, comps):
    """Tree-cotree handle loops (module docstring), appended to ``cyc_v``, ``cyc_e`` and ``comps``."""
    V, F = topology.n_vertices, topology.n_faces
    n_comp = len(ref)
    node = np.arange(V)
    loop_pos = np.full(V, -1, np.int64)
    for j, lp in enumerate(loops):
        node[lp] = V + j
        loop_pos[lp] = np.arange(len(lp))
    first_face = np.full(n_comp, -1, np.int64)
    first_face[flab[::-1]] = np.arange(F)[::-1]
    roots = np.where(ref >= 0, V + ref, topology.faces[first_face, 0])
    ie = topology.interior_edges
    ev = topology.edges[ie]
    na, nb = node[ev[:, 0]], node[ev[:, 1]]
    proper = np.flatnonzero(na != nb)                          # chords of one boundary loop are no tree edges
    pred, tree = _bfs_forest(V + len(loops), na[proper], nb[proper], roots)
    in_tree = np.zeros(topology.n_edges, bool)
    in_tree[ie[proper[tree[tree >= 0]]]] = True
    ftree = _dual_bfs_forest(topology, in_tree, first_face)
    in_cotree = np.zeros(topology.n_edges, bool)
    in_cotree[ftree[ftree >= 0]] = True
    X = ie[~in_tree[ie] & ~in_cotree[ie]]
    xcomp = flab[topology.edge_faces[X, 0]]
    if not np.array_equal(np.bincount(xcomp, minlength=n_comp), 2 * genus):
        raise RuntimeError("tree-cotree decomposition: the leftover edges do not match the genus")
    tree_edge = np.full(len(pred), -1, np.int64)
    has = tree >= 0
    tree_edge[has] = ie[proper[tree[has]]]
    pred_list = pred.tolist()
    E_ = topology.edges

    def along_boundary(j, p, q):
        """Vertices after ``p`` up to ``q`` and the edges of the primal-tree path ``p -> q`` on boundary loop ``j``."""
        lp = loops[j]
        i, k = loop_pos[p], loop_pos[q]
        if i <= k:
            return lp[i + 1:k + 1], out_edge[lp[i:k]]
        return lp[k:i][::-1], out_edge[lp[k:i]][::-1]

    for x, comp in zip(X[np.lexsort((X, xcomp))], np.sort(xcomp), strict=True):
        a, b = int(E_[x, 0]), int(E_[x, 1])
        path = np.array(_tree_path(pred_list, int(node[b]), int(node[a])), np.int64)   # nodes b -> a
        u, w = path[:-1], path[1:]
        e = np.where(pred[u] == w, tree_edge[u], tree_edge[w])
        p = np.where(node[E_[e, 0]] == u, E_[e, 0], E_[e, 1])                        # end in node u
        q = np.where(p == E_[e, 0], E_[e, 1], E_[e, 0])
        vs, es, last = [np.array([b])], [np.array([x])], 0
        for i in np.flatnonzero(u >= V):                        # a boundary node: follow its loop
            vs.append(q[last:i])
            es.append(e[last:i])
            sv, se = along_boundary(u[i] - V, q[i - 1] if i > 0 else b, p[i])
            vs.append(sv)
            es.append(se)
            last = i
        vs.append(q[last:])
        es.append(e[last:])
        if path[-1] >= V:
            sv, se = along_boundary(path[-1] - V, q[-1] if len(q) else b, a)
            vs.append(sv)
            es.append(se)
        cyc_v.append(np.concatenate([[a]] + vs)[:-1])            # the cycle ends back at a
        cyc_e.append(np.concatenate(es))
        comps.append(int(comp))


def _corner(topology, f, v):
    """Corner ``3 f + i`` of vertex ``v`` in face ``f``."""
    return 3 * f + np.argmax(topology.faces[f] == v[:, None], axis=1)


def _clockwise_corner(topology, c):
    """Corner of the same vertex in the face clockwise of corner ``c`` (across the edge leaving the vertex),
    ``-1`` at the boundary."""
    f, i = c // 3, c % 3
    e = topology.face_edges[f, (i + 2) % 3]
    ef = topology.edge_faces[e]
    g = np.where(ef[:, 0] == f, ef[:, 1], ef[:, 0])
    gg = np.maximum(g, 0)
    v = topology.faces[f, i]
    return np.where(g >= 0, 3 * gg + np.argmax(topology.faces[gg] == v[:, None], axis=1), -1)


def _corridors(topology, ptr, verts, edges, forward):
    """Corridor tables of all loops (see :class:`HomologyBasis`), vectorized over all loops."""
    ef = topology.edge_faces
    interior = ~topology.is_boundary_vertex
    M, n = int(ptr[-1]), len(ptr) - 1
    lid = np.repeat(np.arange(n), np.diff(ptr))
    idx = np.arange(M)
    nxt = np.where(idx + 1 < ptr[lid + 1], idx + 1, ptr[lid]) if M else idx
    side = np.where(forward, 0, 1)
    fl = ef[edges, side]
    fl = np.where(fl >= 0, fl, ef[edges, 1 - side])           # the face left of the loop, else the only one
    v = verts[nxt]                                            # step i turns about the end vertex of edge i
    cg, ch = _corner(topology, fl, v), _corner(topology, fl[nxt], v)
    ccw = np.where(cg == ch, 0, -1)                           # counter-clockwise steps from cg to ch
    cur, active, k = cg.copy(), np.flatnonzero(cg != ch), 0
    while active.size:
        k += 1
        cur[active] = topology.corner_next[cur[active]]
        done = cur[active] == ch[active]
        ccw[active[done]] = k
        active = active[~done & (cur[active] >= 0)]
    valence = topology.vertex_valence[v]
    use_ccw = np.where(interior[v], 2 * ccw <= valence, ccw >= 0)
    cnt = np.where(use_ccw, ccw, valence - ccw)               # interior: the shorter way round
    cw_b = np.flatnonzero(~interior[v] & ~use_ccw)            # boundary vertex, clockwise: count the steps
    if cw_b.size:
        cur, steps, act = cg[cw_b].copy(), np.zeros(len(cw_b), np.int64), np.arange(len(cw_b))
        while act.size:
            cur[act] = _clockwise_corner(topology, cur[act])
            steps[act] += 1
            act = act[cur[act] != ch[cw_b[act]]]
        cnt[cw_b] = steps
    rep = np.repeat(idx, cnt)
    j = np.arange(len(rep)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    corner, ccw_rep = cg[rep].copy(), use_ccw[rep]
    for s in range(1, int(cnt.max(initial=0))):
        sel = np.flatnonzero(j >= s)
        corner[sel] = np.where(ccw_rep[sel], topology.corner_next[corner[sel]],
                               _clockwise_corner(topology, corner[sel]))
    A, li = corner // 3, corner % 3
    crossed = topology.face_edges[A, np.where(ccw_rep, (li + 1) % 3, (li + 2) % 3)]
    C = np.bincount(lid[rep], minlength=n)
    if np.any(C == 0):
        raise RuntimeError("a homology loop whose corridor crosses no edge")
    dual_ptr = np.zeros(n + 1, np.int64)
    np.cumsum(C, out=dual_ptr[1:])
    return {"edge_faces": fl, "dual_ptr": dual_ptr, "dual_faces": A, "dual_edges": crossed,
            "dual_sign": np.where(ef[crossed, 0] == A, 1.0, -1.0),
            "crossings_before": np.cumsum(cnt) - cnt - dual_ptr[lid]}
