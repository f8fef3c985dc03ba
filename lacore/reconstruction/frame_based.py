"""Direct and adaptive frame-based reconstruction (thesis 3.4.2, Algorithms 1 and 2).

Given target lengths and angles ``z* = (l*, theta*)``, a dual spanning tree
(:mod:`.spanning_trees`), a root frame ``F_0`` and a root position ``X_0``:

1. frames are propagated from the root along the tree, ``F_child = F_parent R``
   with the induced transition rotation (3.10), (3.28).  With the conventions of
   :mod:`lacore.integrability.local` (``F_right = F_left R``) this is ``R`` when the
   parent is the left face of the tree edge and ``R^T`` otherwise;
2. vertices are placed with the edge vectors (3.29): half-edge ``i`` of face
   ``f`` is ``l*[f, i] F_f (cos phi_i, sin phi_i, 0)`` with the angles of
   :func:`lacore.integrability.local.edge_frame_angles`.  The root face places its
   three vertices from ``X_0`` (its local vertex 0); every other face places at
   most one vertex, the one opposite its parent edge, if no face earlier in
   the tree's level order (``tree.order``) contains it -- exactly the
   sequential Algorithm 1.  It is placed from the edge's endpoint that follows
   it in the face: ``X_i = X_{i+1} - E_{i+2}``.

For admissible ``z*`` the result reproduces ``z*`` up to rounding, whatever the
tree (Theorem 3.2); for non-admissible ``z*`` the tree decides where the
mismatch goes (Algorithm 2 avoids the violation of integrability).  Triangles
violating the triangle inequality get interior angles 0 (remark after
Algorithm 2): their edges are laid along one line, and everything stays finite.

Implementation
--------------
The walk has no per-face Python loop.  Rotations are unit quaternions stored
as complex pairs ``alpha = w + i z``, ``beta = x + i y`` (product
``(a1 a2 - b1 conj(b2), a1 b2 + b1 conj(a2))``), so the transition rotation
``Rz(a) Rx(theta) Rz(-b)`` is
``(cos(theta/2) e^{i (a-b)/2}, sin(theta/2) e^{i (a+b)/2})`` and needs only the
half-angle phasors ``e^{i gamma/2}`` of the interior angles (Kahan's factors of
``tan(gamma/2)``, no trigonometric call) and ``tan(theta/4)``.  An in-plane edge
vector ``zeta = x + i y`` of a face frame is rotated to
``(alpha^2 zeta + beta^2 conj(zeta), -2 Im(beta conj(alpha zeta)))``.

Frames along root paths are composed by two-level pointer jumping
(:func:`_composition_schedule`): faces that place no vertex and have no such
descendant are pruned, leaves are done last with one product each, the rest
is cut into blocks of 4 levels; pointer jumping inside the blocks and over the
block tops ("portals"), then one product per face.  Every step is one batched
product over a contiguous slice of the values (about ``2-3 F`` products in
10-12 steps, instead of ``F`` products in ``depth`` steps level by level).
Positions ``X_v = X_{parent(v)} + d_v`` over the vertex tree (each vertex hangs
below the vertex it was placed from) are summed with the same kind of
schedule.  All index arrays depend on the tree only and are cached on it, so
repeated reconstructions with one tree (interpolation frames, a preassembled
tree, the cached BFS tree) only do arithmetic.
"""

import math
import weakref

import numpy as np

from ..errors import InputError, MeshError, format_indices
from ..integrability.transitions import standard_frames
from ..geometry.lengths_angles import check_z
from ..geometry.topology import check_vertices
from .spanning_trees import DualSpanningTree, half_theta, stable_order, default_root_faces, dual_spanning_tree

__all__ = ["frame_based_reconstruction", "propagate_frames", "rotation_to_quaternion"]


# --------------------------------------------------------------------------- quaternions
def _shepperd(a):
    """Unit quaternion ``(w, x, y, z)`` of one rotation matrix given as nested lists (largest pivot)."""
    tr = a[0][0] + a[1][1] + a[2][2]
    pivot = max(range(4), key=lambda k: (tr, a[0][0], a[1][1], a[2][2])[k])
    if pivot == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = (0.25 * s, (a[2][1] - a[1][2]) / s, (a[0][2] - a[2][0]) / s, (a[1][0] - a[0][1]) / s)
    elif pivot == 1:
        s = 2.0 * math.sqrt(1.0 + a[0][0] - a[1][1] - a[2][2])
        q = ((a[2][1] - a[1][2]) / s, 0.25 * s, (a[0][1] + a[1][0]) / s, (a[0][2] + a[2][0]) / s)
    elif pivot == 2:
        s = 2.0 * math.sqrt(1.0 + a[1][1] - a[0][0] - a[2][2])
        q = ((a[0][2] - a[2][0]) / s, (a[0][1] + a[1][0]) / s, 0.25 * s, (a[1][2] + a[2][1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + a[2][2] - a[0][0] - a[1][1])
        q = ((a[1][0] - a[0][1]) / s, (a[0][2] + a[2][0]) / s, (a[1][2] + a[2][1]) / s, 0.25 * s)
    norm = math.sqrt(sum(v * v for v in q))
    return [v / norm for v in q]


def rotation_to_quaternion(R, check=True):
    """Unit quaternions ``(w, x, y, z)`` of rotation matrices ``(..., 3, 3)`` -> ``(..., 4)``.

    Shepperd's method (largest pivot); with ``check``, matrices that are not
    orthonormal to ``1e-13`` are first projected to the nearest rotation by SVD.

    Raises
    ------
    ValueError
        With ``check``: if a matrix is not finite, far from orthogonal
        (``|R^T R - I| > 1e-6``) or a reflection.
    """
    R = np.asarray(R, float)
    if R.shape[-2:] != (3, 3):
        raise InputError(f"rotation matrices must have shape (..., 3, 3), got {R.shape}")
    if check:
        if not np.all(np.isfinite(R)):
            raise InputError("root_frame has NaN or infinite entries")
        dev = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
        if np.any(dev > 1e-6) or np.any(np.linalg.det(R) <= 0):
            raise InputError("root_frame must be a rotation matrix (orthonormal columns b1, b2, N with det +1)")
        if np.any(dev > 1e-13):
            u, _, vt = np.linalg.svd(R)
            R = u @ vt
    q = np.array([_shepperd(a) for a in R.reshape(-1, 3, 3).tolist()]).reshape(-1, 4)
    return q.reshape(R.shape[:-2] + (4,))


def _reference_root_quaternions(X, root_faces):
    """Quaternions of the standard frames of the reference root faces (few roots: plain Python floats)."""
    if len(root_faces) > 16:
        return rotation_to_quaternion(standard_frames(X, root_faces), check=False)
    out = []
    for a, b, c in root_faces.tolist():
        p0, p1, p2 = X[a].tolist(), X[b].tolist(), X[c].tolist()
        e = [p1[k] - p0[k] for k in range(3)]
        g = [p2[k] - p0[k] for k in range(3)]
        le = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
        b1 = [v / le for v in e]
        n = [b1[1] * g[2] - b1[2] * g[1], b1[2] * g[0] - b1[0] * g[2], b1[0] * g[1] - b1[1] * g[0]]
        ln = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        n = [v / ln for v in n]
        b2 = [n[1] * b1[2] - n[2] * b1[1], n[2] * b1[0] - n[0] * b1[2], n[0] * b1[1] - n[1] * b1[0]]
        out.append(_shepperd([[b1[k], b2[k], n[k]] for k in range(3)]))
    return np.array(out)


def _pair_to_matrix(alpha, beta):
    """Rotation matrices ``(n, 3, 3)`` of complex-pair quaternions ``alpha = w + i z``, ``beta = x + i y``."""
    w, z, x, y = alpha.real, alpha.imag, beta.real, beta.imag
    R = np.empty(alpha.shape + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


# --------------------------------------------------------------------------- schedule (z-independent)
_NEXT = np.array([1, 2, 0])                                    # (i + 1) % 3
_PREV = np.array([2, 0, 1])                                    # (i + 2) % 3
_ROOT_J = np.array([1, 2, 1])                                  # root face: half-edge from local vertex 0


def _jump_rounds(parent_rank, depth_sorted):
    """Pointer-jumping rounds for a forest numbered in level order.

    Returns a list of ``(start, targets)``: in round ``k`` the nodes
    ``start..n-1`` (depth ``>= 2^k``) combine with ``targets`` (their ancestor
    ``2^k`` steps up).  After the last round every node holds the product over
    its whole root path.
    """
    n = len(parent_rank)
    if n == 0 or depth_sorted[-1] < 1:
        return []
    starts = np.searchsorted(depth_sorted, 1 << np.arange(int(depth_sorted[-1]).bit_length())).tolist()
    anc = parent_rank
    rounds = []
    for s in starts:
        # nodes before ``s`` are never combined again, so their (possibly meaningless) ancestors are harmless
        tgt = anc[s:]
        rounds.append((s, tgt))
        anc = anc.take(anc)
    return rounds


def _forest_depths(parent):
    """Depths of the nodes of a forest (``parent`` ``-1`` at the roots) by pointer jumping, ``(n,)`` int64.

    The forest must be acyclic (it is built internally, so this is not checked).
    """
    n = len(parent)
    anc = np.where(parent < 0, n, parent)
    anc = np.append(anc, n)                                    # node n: sentinel above every root
    depth = np.append(parent >= 0, False).astype(np.int64)
    while anc.min() < n:
        depth += depth.take(anc)
        anc = anc.take(anc)
    return depth[:n]


def _composition_schedule(parent, depth, level_order, need, keep, block=4):
    """Steps that compose values along the root paths of a forest (frames, or position offsets).

    Every step is ``(start, stop, targets)`` and means
    ``value[start:stop] = value[targets] o value[start:stop]`` (gather first, then
    combine), in the numbering ``nodes``.  Initially every node holds its own
    edge value (the roots their absolute value); after the steps every node
    holds the composition over its root path.

    Two-level pointer jumping: the needed nodes without needed children
    (*leaves*, except ``keep`` nodes) are raked, i.e. done last with one step
    from their parents.  The other nodes are cut into blocks of ``block``
    levels; nodes at depths ``0, block, 2 block, ...`` are *portals*.

    1. inside every block, pointer jumping (``ceil(log2(block - 1))`` rounds, the
       nodes of relative depth ``>= 2^j`` being a suffix of the inner numbering)
       gives the composition from the block's portal (exclusive) to the node;
    2. every non-root portal combines the finished value of its parent;
    3. pointer jumping over the portal tree (depth ``max_depth / block``);
    4. every inner node combines its portal's value;
    5. leaves combine their parents' values.

    Blocks of 4 levels minimized the number of combined values on the test
    meshes (BFS, MST and SPT trees, depths 75-450; about ``2-3 F`` products
    instead of ``F log2(depth)`` for plain pointer jumping); trees shallower
    than ``2 block`` use a single block (plain pointer jumping).

    Returns
    -------
    nodes : (m,) int64
        The needed nodes in step numbering (portals by depth, the roots first; then inner nodes; then leaves).
    steps : list of (int, int, (k,) int64)
    block : int
    """
    n = len(parent)
    has_parent = parent >= 0
    n_children = np.bincount(parent[need & has_parent], minlength=n)
    leaf = need & (n_children == 0) & ~keep
    internal = need & ~leaf
    max_depth = int(np.max(depth, where=internal, initial=0))
    if max_depth < 2 * block:
        block = max_depth + 1
    pow2 = block & (block - 1) == 0
    rel = depth & (block - 1) if pow2 else depth % block
    # one stable sort of the level order by class: portals (0), inner nodes by relative depth (1 .. block - 1),
    # leaves (block), nodes not needed (block + 1)
    key = np.where(internal, np.where(has_parent, rel, 0), np.where(leaf, block, block + 1))
    key = key.take(level_order)
    perm = stable_order(key)
    counts = np.bincount(key, minlength=block + 2)
    P, N = int(counts[0]), int(counts[1:block].sum())
    m = P + N + int(counts[block])
    nodes = level_order.take(perm[:m])
    o_portal, o_inner, o_leaf = nodes[:P], nodes[P:P + N], nodes[P + N:]
    rel_inner = key.take(perm[P:P + N])
    rank = np.full(n, -1, np.int64)
    rank[nodes] = np.arange(m)
    C = int(np.count_nonzero(~has_parent.take(o_portal)))
    steps = []
    # 1. inside the blocks
    pin = parent.take(o_inner)
    local_parent = np.where(rel_inner >= 2, rank.take(pin) - P, -1)
    rounds = _jump_rounds(local_parent, rel_inner - 1)
    for s, tgt in rounds:
        steps.append((P + s, P + N, tgt + P))
    # block top (nearest portal ancestor, in step numbering) of the inner nodes: the parent of the
    # root of their block forest, found with the same rounds ("keep the ancestor's value")
    first = np.arange(N)
    for s, tgt in rounds:
        first[s:] = first.take(tgt)
    top_rank = rank[pin.take(first)] if N else np.zeros(0, np.int64)
    # 2. portals below the roots take their parent's block composition
    pr = rank.take(parent.take(o_portal[C:]))
    if P > C:
        steps.append((C, P, pr))
    # 3. the portal tree
    pr = np.where(pr >= P, top_rank.take(np.maximum(pr - P, 0)), pr)
    portal_parent = np.concatenate((np.full(C, -1, np.int64), pr))
    pdepth = depth[o_portal]
    pdepth = pdepth >> (block.bit_length() - 1) if pow2 else pdepth // block
    for s, tgt in _jump_rounds(portal_parent, pdepth):
        steps.append((s, P, tgt))
    # 4. inner nodes take their portal's value;  5. leaves their parent's
    if N:
        steps.append((P, P + N, top_rank))
    if len(o_leaf):
        steps.append((P + N, len(nodes), rank[parent[o_leaf]]))
    for _, _, t in steps:
        t.setflags(write=False)
    return nodes, steps, block


def _slot_tables(topology):
    """Per face slot ``3 f + i`` (cached on the topology): the face across edge ``i`` of ``f``, that edge's
    local index in it, and whether ``f`` is the edge's left face (``(3F,)`` each)."""
    def compute():
        e = topology.face_edges.ravel()
        left = topology.face_edge_is_left.ravel()
        ef = topology.edge_faces.take(e, axis=0)
        eli = topology.edge_local_index.take(e, axis=0)
        out = (np.where(left, ef[:, 1], ef[:, 0]), np.where(left, eli[:, 1], eli[:, 0]), left.copy())
        for a in out:
            a.setflags(write=False)
        return out
    return topology.cache.get((__name__, "slot_tables"), compute)


def _walk_schedule(tree, topology, prune=True):
    """Index arrays of the walk over ``tree`` (cached on the tree, tied to ``topology``).

    With ``prune`` only the frames needed for placing vertices are computed:
    faces without a vertex to place and without needed descendants are dropped
    (two pruning passes), see :func:`_composition_schedule` for the rest.
    """
    key = (__name__, "walk_schedule", bool(prune))
    entry = tree.cache.peek(key)
    if entry is not None and entry[0]() is topology:
        return entry[1]
    F, V = topology.n_faces, topology.n_vertices
    if tree.n_faces != F:
        raise MeshError(f"the spanning tree has {tree.n_faces} faces but the mesh has {F}")
    faces, fe = topology.faces, topology.face_edges
    order, C = tree.order, len(tree.roots)
    parent, depth = tree.parent, tree.depth
    child = order[C:]
    e = tree.parent_edge.take(child)
    fc = fe.take(child, axis=0)
    li = np.where(fc[:, 0] == e, 0, np.where(fc[:, 1] == e, 1, 2))   # local index of the parent edge in the child
    slot = 3 * child + li
    across, twin, is_left = _slot_tables(topology)
    if not (np.array_equal(fe.ravel().take(slot), e) and np.array_equal(across.take(slot), parent.take(child))):
        raise MeshError("the spanning tree does not belong to this mesh (tree edges do not join parent and child)")
    li_child = np.empty(F, np.int64)
    li_child[child] = li
    child_slot = np.empty(F, np.int64)
    child_slot[child] = slot

    # vertices: the first face in level order containing a vertex places it
    first = np.full(V, 3 * F, np.int64)
    np.minimum.at(first, faces.take(order, axis=0).ravel(), np.arange(3 * F))
    verts = np.flatnonzero(first < 3 * F)
    unreferenced = np.flatnonzero(first == 3 * F)
    first = first[verts]
    pos, i = np.divmod(first, 3)
    f = order.take(pos)
    is_root = pos < C
    if not np.all(is_root | (i == li_child.take(f))):
        raise MeshError("internal error: a vertex is not opposite the parent edge of its first face")
    j = np.where(is_root, _ROOT_J.take(i), _PREV.take(i))      # half-edge giving X_v - X_src
    src = np.where(is_root, 0, _NEXT.take(i))
    placed = ~(is_root & (i == 0))
    vpar = np.full(V, -1, np.int64)
    vpar[verts[placed]] = faces.ravel().take(3 * f[placed] + src[placed])
    vface = np.full(V, -1, np.int64)
    vface[verts] = f
    vj = np.zeros(V, np.int64)
    vj[verts] = j
    vsign = np.zeros(V)
    vsign[verts] = np.where(is_root & (i == 1), 1.0, -1.0)
    vroot = np.full(V, -1, np.int64)
    vroot[verts[~placed]] = pos[~placed]                      # component (root rank) of the root vertices

    # frames: needed faces = placing faces and their ancestors (pruned iteratively), leaves raked
    is_root_face = parent < 0
    if prune:
        droppable = ~is_root_face                              # neither a root nor placing a vertex
        droppable[vface[verts[placed]]] = False
        n_children = np.bincount(parent.take(child), minlength=F)
        drop = droppable & (n_children == 0)
        need = ~drop
        if drop.any():                                         # second pass: children counts without the dropped
            n_children -= np.bincount(parent[drop], minlength=F)
            drop = need & droppable & (n_children == 0)
            need &= ~drop
    else:
        need = np.ones(F, bool)
    fnodes, f_steps, f_block = _composition_schedule(parent, depth, order, need, is_root_face)
    frank = np.full(F, -1, np.int64)
    frank[fnodes] = np.arange(len(fnodes))
    nc = fnodes[C:]                                            # needed non-root faces, in walk order
    nslot = child_slot.take(nc)

    # vertex tree, leaves raked
    vdepth = _forest_depths(vpar)
    vorder = np.concatenate((verts[~placed], unreferenced, verts[placed]))
    vorder = vorder[stable_order(vdepth.take(vorder))]        # by depth, the roots first
    vnodes, v_steps, v_block = _composition_schedule(vpar, vdepth, vorder, vface >= 0, vpar < 0)
    vrank = np.full(V, len(vnodes), np.int64)                  # unreferenced vertices -> an extra zero row
    vrank[vnodes] = np.arange(len(vnodes))
    pv = vnodes[C:]                                            # placed vertices (the roots come first)

    sched = {
        "C": C,
        "n_faces_walk": len(fnodes),
        "len6": topology.cache.get((__name__, "len6"), lambda: np.ascontiguousarray(fe[:, [0, 1, 2, 0, 1, 2]].T)),
        "tp": twin.take(nslot) * F + parent.take(nc),
        "tc": li_child.take(nc) * F + nc,
        "edge": tree.parent_edge.take(nc),
        "sign": np.where(is_left.take(nslot), -1.0, 1.0),             # +1: the parent is the edge's left face
        "frame_steps": f_steps,
        "frame_block": f_block,
        "face_nodes": fnodes,
        "vface": frank[vface[pv]],
        "vflat": vj[pv] * F + vface[pv],
        "vedge": fe.ravel().take(3 * vface[pv] + vj[pv]),
        "vsign": vsign[pv],
        "vroot_comp": vroot[vnodes[:C]],
        "vertex_steps": v_steps,
        "vertex_block": v_block,
        "vertex_nodes": vnodes,
        "vrank": vrank,
    }
    for value in sched.values():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    tree.cache.put(key, (weakref.ref(topology), sched))
    return sched


# --------------------------------------------------------------------------- arithmetic
def _phasor_table(lengths, sched, F):
    """``exp(i phi / 2)`` of the half-edge direction angles (``edge_frame_angles``), flat ``(3F,)`` complex.

    Entry ``i F + f`` belongs to half-edge ``i`` of face ``f``: ``phi_0 = pi - gamma_1``,
    ``phi_1 = pi + gamma_0``, ``phi_2 = 0`` give ``i conj(h_1)``, ``i h_0`` and ``1`` with
    ``h_i = exp(i gamma_i / 2)``.  Kahan's half-angle factors (A.6) in product form:
    with ``t_i = 2 (s - l_i) = (max(l_j, l_k) - l_i) + min(l_j, l_k)`` (only exact
    differences cancel) and the perimeter ``p``,
    ``cos(gamma_i / 2) = sqrt(p t_i) / (2 sqrt(l_j l_k))`` and
    ``sin(gamma_i / 2) = sqrt(t_j t_k) / (2 sqrt(l_j l_k))``.  The triangle
    inequality is violated (``T_f <= 0``) iff some ``t_i <= 0``; then all angles are 0.
    """
    G = lengths.take(sched["len6"])                            # rows l0 l1 l2 l0 l1 l2
    t = np.maximum(G[1:5], G[2:6])                             # rows t0 t1 t2 t0
    t -= G[0:4]
    t += np.minimum(G[1:5], G[2:6])
    bad = t[0] * t[1]
    bad *= t[2]
    bad = ~(bad > 0)                                           # at most one t_i (the longest side's) is <= 0
    np.abs(t, out=t)                                           # (values of bad faces are replaced below)
    np.sqrt(t, out=t)
    sp = np.sqrt(G[0] + G[1] + G[2])
    r = np.sqrt(G[1:4])                                        # sqrt of l1 l2 l0
    r = r[0:2] * r[1:3]                                        # sqrt(l1 l2), sqrt(l2 l0)
    np.divide(0.5, r, out=r)
    sin_ = t[1:3] * t[2:4]                                     # sqrt(t1 t2), sqrt(t2 t0)
    cos_ = t[0:2] * sp                                         # sqrt(p t0), sqrt(p t1)
    T = np.empty((3, F), complex)
    Tv = T.view(float).reshape(3, F, 2)
    np.multiply(sin_[1], r[1], out=Tv[0, :, 0])                # sin(gamma_1 / 2)
    np.multiply(cos_[1], r[1], out=Tv[0, :, 1])                # cos(gamma_1 / 2)
    np.negative(r[0], out=r[0])
    np.multiply(sin_[0], r[0], out=Tv[1, :, 0])                # -sin(gamma_0 / 2)
    np.negative(r[0], out=r[0])
    np.multiply(cos_[0], r[0], out=Tv[1, :, 1])                # cos(gamma_0 / 2)
    T[2] = 1.0
    if bad.any():                                              # angles 0 (remark after Algorithm 2)
        T[0, bad] = 1j
        T[1, bad] = 1j
    return T.reshape(-1)


def _compose_frames(z, topology, sched, root_q):
    """Frames of the walked faces (``sched["face_nodes"]`` order) as complex-pair quaternions ``(alpha, beta)``."""
    E, F, C = topology.n_edges, topology.n_faces, sched["C"]
    lengths, theta = z[:E], z[E:]
    T = _phasor_table(lengths, sched, F)
    # transition quaternion parent -> child with s = +1 (parent is the left face: R) or -1 (right face: R^T):
    # alpha = s cos(theta/2) P conj(Q),  beta = -s sin(theta/2) P Q,  P = -i e^{i phi_parent/2}, Q = e^{i phi_child/2}
    sign = sched["sign"]
    P = T.take(sched["tp"]) * -1j
    Q = T.take(sched["tc"])
    ch, sh = half_theta(theta.take(sched["edge"]) * sign)    # cos(theta/2), s sin(theta/2)
    ch *= sign
    n = sched["n_faces_walk"]
    alpha = np.empty(n, complex)
    beta = np.empty(n, complex)
    alpha[:C] = root_q[:, 0] + 1j * root_q[:, 3]
    beta[:C] = root_q[:, 1] + 1j * root_q[:, 2]
    alpha[C:] = P * np.conj(Q) * ch
    beta[C:] = P * Q * -sh
    for s, e, tgt in sched["frame_steps"]:
        _left_multiply(alpha.take(tgt), beta.take(tgt), alpha[s:e], beta[s:e])
    return alpha, beta, T


def _left_multiply(a1, b1, a2, b2):
    """In place ``(a2, b2) <- (a1, b1) (a2, b2)`` (Hamilton product of complex-pair quaternions)."""
    na = a1 * a2
    na -= b1 * np.conj(b2)
    b1 *= np.conj(a2)
    a1 *= b2
    a1 += b1
    a2[...] = na
    b2[...] = a1


def _place_vertices(z, topology, sched, alpha, beta, T, root_pos):
    """Vertex positions ``(V, 3)`` from the walked frames, by pointer jumping over the vertex tree."""
    E, C = topology.n_edges, sched["C"]
    fa = alpha.take(sched["vface"])
    fb = beta.take(sched["vface"])
    t = T.take(sched["vflat"])
    zeta = t * t
    zeta *= z[:E].take(sched["vedge"]) * sched["vsign"]        # in-plane vector in the face frame
    g = fa * zeta
    xy = fa * g
    xy += fb * fb * np.conj(zeta)                              # rotated x + i y
    n = len(sched["vflat"]) + C
    D = np.empty((n + 1, 3))                                   # last row: unreferenced vertices
    D[:C] = root_pos[sched["vroot_comp"]]
    D[C:n, 0] = xy.real
    D[C:n, 1] = xy.imag
    D[C:n, 2] = -2.0 * (fb * np.conj(g)).imag                  # rotated z
    D[n] = 0.0
    for s, e, tgt in sched["vertex_steps"]:
        D[s:e] += D.take(tgt, axis=0)
    return D.take(sched["vrank"], axis=0)


def _root_placement(topology, roots, root_frame, root_position, reference_vertices):
    C = len(roots)
    if root_frame is not None:
        root_q = _root_quaternions(root_frame, C)
    elif reference_vertices is not None:
        root_q = _reference_root_quaternions(reference_vertices, topology.faces[roots])
    else:
        root_q = np.zeros((C, 4))
        root_q[:, 0] = 1.0
    if root_position is None:
        if reference_vertices is not None:
            root_position = reference_vertices[topology.faces[roots, 0]]
        else:
            root_position = np.zeros((C, 3))
    root_position = np.asarray(root_position, float)
    if root_position.shape == (3,):
        root_position = np.broadcast_to(root_position, (C, 3))
    if root_position.shape != (C, 3) or not np.all(np.isfinite(root_position)):
        raise InputError(f"root_position must be finite with shape (3,) or ({C}, 3), got {root_position.shape}")
    return root_q, root_position


def _root_quaternions(root_frame, C):
    root_frame = np.asarray(root_frame, float)
    if root_frame.shape == (3, 3):
        root_frame = np.broadcast_to(root_frame, (C, 3, 3))
    if root_frame.shape != (C, 3, 3):
        raise InputError(f"root_frame must have shape (3, 3) or ({C}, 3, 3) (one per root), got {root_frame.shape}")
    return rotation_to_quaternion(root_frame)


def _checked_z(z, topology):
    """``z`` as float64 ``(2E,)``; :func:`~lacore.geometry.lengths_angles.check_z`'s detailed checks on failure."""
    z = np.asarray(z, dtype=np.float64)
    E = topology.n_edges
    if z.shape == (2 * E,) and E and np.isfinite(z).all() and z[:E].min() > 0:
        return z
    return check_z(z, topology)


def _resolve_tree(z, topology, tree, kind, root_face, reference_vertices):
    if tree is not None:
        if not isinstance(tree, DualSpanningTree):
            raise TypeError(f"tree must be a DualSpanningTree, got {type(tree).__name__}")
        if tree.n_faces != topology.n_faces:
            raise MeshError(f"the spanning tree has {tree.n_faces} faces but the mesh has {topology.n_faces}")
        if root_face is not None and not np.array_equal(np.sort(np.atleast_1d(root_face)), tree.roots):
            raise MeshError(f"root_face {root_face} differs from the tree's roots {format_indices(tree.roots)}")
        return tree
    if root_face is None:
        root_face = default_root_faces(topology, z=z, vertices=reference_vertices)
    return dual_spanning_tree(topology, root_face, kind=kind, z=z)


def propagate_frames(z, topology, tree=None, kind="bfs", root_face=None, root_frame=None,
                     reference_vertices=None):
    """Frames of all faces propagated along a dual spanning tree (3.28), ``(F, 3, 3)``.

    ``F_child = F_parent R`` (``R^T`` if the parent is the right face of the tree
    edge).  For admissible ``z`` these are the standard frames
    (:func:`lacore.integrability.local.standard_frames`) of the reconstruction.
    Parameters as in :func:`frame_based_reconstruction`.
    """
    z = check_z(z, topology)
    if reference_vertices is not None:
        reference_vertices = check_vertices(reference_vertices, topology.n_vertices, "reference_vertices")
    tree = _resolve_tree(z, topology, tree, kind, root_face, reference_vertices)
    sched = _walk_schedule(tree, topology, prune=False)
    root_q, _ = _root_placement(topology, tree.roots, root_frame, None, reference_vertices)
    alpha, beta, _ = _compose_frames(z, topology, sched, root_q)
    out = np.empty((topology.n_faces, 3, 3))
    out[sched["face_nodes"]] = _pair_to_matrix(alpha, beta)
    return out


def frame_based_reconstruction(z, topology, tree=None, kind="bfs", root_face=None, root_frame=None,
                               root_position=None, reference_vertices=None):
    """Reconstruct vertex positions from lengths and angles by walking a dual spanning tree.

    Algorithm 1 (``kind="bfs"``) or the adaptive Algorithm 2 (``kind="mst"`` /
    ``"spt"`` with the weights (3.30)), or any prebuilt ``tree`` (e.g. a
    :func:`~.spanning_trees.preassembled_tree`).

    Parameters
    ----------
    z : (2E,) array_like
        Target lengths and dihedral angles ``(l*, theta*)``; need not be admissible.
    topology : MeshTopology
    tree : DualSpanningTree, optional
        Prebuilt tree; its walk indices are cached on it, so reuse it for many targets.
    kind : {"bfs", "mst", "spt"}
        Tree to build when ``tree`` is None.  ``"bfs"`` trees are cached on the
        topology; ``"mst"``/``"spt"`` are built from ``z`` on every call.
    root_face : int or sequence of int, optional
        Root face (one per connected component).  Default: a central, well
        shaped face (:func:`~.spanning_trees.default_root_faces`, quality taken
        from ``reference_vertices`` if given, else from ``z``).
    root_frame : (3, 3) or (C, 3, 3) array_like, optional
        Standard frame ``[b1 | N x b1 | N]`` (columns) of the root face: ``b1``
        along its half-edge ``p0 -> p1``.  Default: that of ``reference_vertices``
        if given, else the identity.
    root_position : (3,) or (C, 3) array_like, optional
        Position of the root face's first vertex ``faces[root, 0]``.  Default:
        its position in ``reference_vertices`` if given, else the origin.
    reference_vertices : (V, 3) array_like, optional
        A mesh in correspondence; the output is placed in its frame (root face
        frame and vertex as in the reference), so reconstructing ``Z(X)`` with
        reference ``X`` returns ``X``.  Without it, components are all rooted
        at the origin with the identity frame (and may overlap).

    Returns
    -------
    (V, 3) ndarray
        The vertex positions (vertices used by no face are at the origin, or at
        their reference position).

    Raises
    ------
    LengthsAnglesError
        For ``z`` of the wrong size, with NaN/inf entries or non-positive lengths.
    MeshError
        For a bad reference mesh (vertex count, NaN), a tree from another mesh,
        or roots that are not one face per connected component.
    ValueError
        For an unknown ``kind`` or a ``root_frame`` that is not a rotation.
    """
    z = _checked_z(z, topology)
    if reference_vertices is not None:
        reference_vertices = check_vertices(reference_vertices, topology.n_vertices, "reference_vertices")
    tree = _resolve_tree(z, topology, tree, kind, root_face, reference_vertices)
    sched = _walk_schedule(tree, topology)
    root_q, root_pos = _root_placement(topology, tree.roots, root_frame, root_position, reference_vertices)
    alpha, beta, T = _compose_frames(z, topology, sched, root_q)
    X = _place_vertices(z, topology, sched, alpha, beta, T, root_pos)
    if reference_vertices is not None and len(sched["vflat"]) + len(tree.roots) < topology.n_vertices:
        free = np.setdiff1d(np.arange(topology.n_vertices), topology.faces.ravel())
        X[free] = reference_vertices[free]
    return X
