"""Groupwise quadric-error coarsening by half-edge collapses (thesis 2.3, [GH97], [MG03]).

A *half-edge collapse* ``u -> v`` removes vertex ``u`` and reconnects its
faces to ``v``, which keeps its position.  The coarse mesh's vertices are
therefore a subset of the fine mesh's (``Coarsening.vertex_indices``): every
shape of a group in dense correspondence (all shape keys of one mesh) restricts
to the coarse mesh by indexing, and per-vertex data (skinning weights, colours)
carry over by index.

Error metric
------------
Garland-Heckbert quadrics, summed over the shapes of the group as in [MG03]:
each vertex holds one 4x4 quadric per shape, the sum of its faces' plane
quadrics ``area * [n; d][n; d]^T`` (plus, on boundary edges, a plane through
the edge perpendicular to its face, weighted by ``boundary_weight * l^2``, so
collapses along the boundary keep its shape).  Collapsing ``u -> v`` costs
``sum_s [p_v^s; 1]^T (Q_u^s + Q_v^s) [p_v^s; 1]`` and hands ``Q_u`` on to
``v``.  Collapses are done cheapest first (a priority queue with lazily
invalidated entries).

Validity (checked for every collapse, in every shape)
-----------------------------------------------------
* Link condition (Dey et al.) on the mesh closed by a virtual vertex joined
  to every boundary vertex: the common neighbours of ``u`` and ``v`` are
  exactly the opposite vertices of the edge.  This keeps the mesh a
  manifold with the same Euler characteristic and boundary loops.
* A boundary vertex is removed only along a boundary edge (into a boundary
  vertex), so the boundary never moves inward.
* No moved face turns by more than ``max_normal_angle`` (no flips) or
  falls below the triangle quality ``min_quality``
  (``4 sqrt(3) area / sum l^2``, 1 for an equilateral triangle).

If the queue empties before the target count, the geometric thresholds are
relaxed (quality halved, normal angle widened towards 90 degrees) and the
remaining candidates are retried; flips and topology are never relaxed.

Storing a coarsening
--------------------
The collapse order is greedy: a tie between two equally cheap collapses, or
costs equal up to rounding, is decided by the last bits of floating-point sums,
which differ between CPUs (SIMD paths, BLAS kernels).  Recomputing a coarsening
on another machine can therefore give another (equally good) coarse mesh.
Whatever must be reproduced -- a coarse mesh that fits were made on, the
prolongation back to the fine mesh -- is stored instead:
:meth:`Coarsening.to_arrays` / :meth:`Coarsening.from_arrays` give a versioned
set of plain arrays (integers and the collapse costs) to embed in any ``.npz``,
:meth:`Coarsening.save` / :meth:`Coarsening.load` a file of its own.
"""

import heapq
import os
import time
import zipfile
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, MeshError
from ..geometry.topology import MeshTopology, check_faces
from ..io.atomic import save_npz_atomic
from ..io.npz import open_npz
from ..progress import report

__all__ = ["Coarsening", "coarsen", "vertex_quadrics", "RECORD_FORMAT", "RECORD_VERSION"]

#: A candidate rejected for its geometry is retried (after changes around it) at most this often per round.
_MAX_RETRIES = 3

#: ``format`` entry of a stored coarsening (:meth:`Coarsening.to_arrays`).
RECORD_FORMAT = "lacore.multiresolution.coarsening"
#: Version of the stored layout; :meth:`Coarsening.from_arrays` reads this version.
RECORD_VERSION = 1
#: Arrays of a stored coarsening besides ``format``, ``format_version`` and ``n_fine_vertices``
#: (``vertex_indices`` and ``parent`` follow from the collapses).
_RECORD_ARRAYS = ("fine_faces", "faces", "collapse_sources", "collapse_targets", "ring_offsets", "ring_pairs",
                  "costs")


@dataclass
class Coarsening:
    """Result of :func:`coarsen`: a coarse mesh whose vertices are fine vertices.

    Attributes
    ----------
    n_fine_vertices : int
    fine_faces : (F, 3) int64
    vertex_indices : (Vc,) int64
        Fine index of each coarse vertex, increasing.
    faces : (Fc, 3) int64
        Coarse faces in coarse indexing, oriented as the fine faces.
    collapse_sources, collapse_targets : (K,) int64
        The ``k``-th collapse removed fine vertex ``collapse_sources[k]`` into
        ``collapse_targets[k]`` (fine indices), ``K = V - Vc``.
    parent : (V,) int64
        Coarse index of the vertex that finally absorbed each fine vertex
        (coarse vertices map to themselves).
    ring_offsets : (K + 1,) int64
    ring_pairs : (M, 2) int64
        One-ring of ``collapse_sources[k]`` at the time of its collapse:
        rows ``ring_offsets[k]:ring_offsets[k + 1]`` are the other two corners
        ``(p, q)`` of each face ``(u, p, q)`` (counter-clockwise), in fine
        indices.  All of them exist when ``u`` is re-inserted in reverse order.
    costs : (K,) float64
        Quadric error of each collapse.
    seconds : float
    """

    n_fine_vertices: int
    fine_faces: np.ndarray
    vertex_indices: np.ndarray
    faces: np.ndarray
    collapse_sources: np.ndarray
    collapse_targets: np.ndarray
    parent: np.ndarray
    ring_offsets: np.ndarray
    ring_pairs: np.ndarray
    costs: np.ndarray
    seconds: float = 0.0
    _topology: object = field(default=None, repr=False)

    @property
    def n_vertices(self):
        """Number of coarse vertices ``Vc``."""
        return len(self.vertex_indices)

    @property
    def topology(self):
        """:class:`~lacore.geometry.topology.MeshTopology` of the coarse mesh (built once)."""
        if self._topology is None:
            self._topology = MeshTopology.from_faces(self.faces, n_vertices=self.n_vertices)
        return self._topology

    # ------------------------------------------------------------------ storage
    def to_arrays(self, prefix=""):
        """The coarsening as plain arrays, to store in an ``.npz`` (alone or beside other data).

        Parameters
        ----------
        prefix : str
            Prepended to every key (e.g. ``"coarsening_"`` inside another file's arrays).

        Returns
        -------
        dict of str -> ndarray
            ``format`` (:data:`RECORD_FORMAT`), ``format_version``
            (:data:`RECORD_VERSION`), ``n_fine_vertices``, ``fine_faces``,
            ``faces``, ``collapse_sources``, ``collapse_targets``,
            ``ring_offsets``, ``ring_pairs`` (integers) and ``costs``.  No
            object arrays: :func:`numpy.load` reads them with
            ``allow_pickle=False``.

        Examples
        --------
        A record stored inside another file's arrays, under a prefix:

        >>> import numpy as np
        >>> from lacore.multiresolution import Coarsening, coarsen
        >>> from lacore.samples.bar import bar_mesh, bar_pose
        >>> X, faces = bar_mesh(n_along=12, n_side=1)
        >>> coarsening = coarsen([X, bar_pose(X, 0.5, 0.0)], faces, 20)
        >>> arrays = {"weights": np.ones(3), **coarsening.to_arrays("coarsening_")}
        >>> same = Coarsening.from_arrays(arrays, "coarsening_")
        >>> same.n_vertices, bool(np.array_equal(same.faces, coarsening.faces))
        (20, True)
        """
        out = {prefix + "format": np.array(RECORD_FORMAT), prefix + "format_version": np.array(RECORD_VERSION),
               prefix + "n_fine_vertices": np.array(self.n_fine_vertices, np.int64)}
        for name in _RECORD_ARRAYS:
            out[prefix + name] = np.asarray(getattr(self, name))
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix="", source="coarsening record"):
        """A :class:`Coarsening` from the arrays of :meth:`to_arrays`, checked for consistency.

        Parameters
        ----------
        arrays : mapping of str -> array_like
            E.g. a dict or an open :class:`numpy.lib.npyio.NpzFile`.
        prefix : str
            The prefix given to :meth:`to_arrays`.
        source : str
            Named in error messages (a file name).

        Raises
        ------
        InputError
            Missing or unknown format, another version, arrays of the wrong
            type or shape, or collapses that do not form a valid coarsening
            (an index out of range, a vertex removed twice or used after its
            removal).  The message names ``source`` and the problem.
        """
        def fail(msg):
            return InputError(f"{source}: {msg}")

        def get(name):
            key = prefix + name
            try:
                present = key in arrays
            except TypeError:
                present = False
            if not present:
                raise fail(f"not a coarsening record (no '{key}' array)")
            try:
                return np.asarray(arrays[key])
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                raise fail(f"cannot read '{key}' ({exc})") from None

        fmt, version = get("format"), get("format_version")
        if fmt.shape != () or fmt.dtype.kind != "U" or str(fmt) != RECORD_FORMAT:
            raise fail(f"not a coarsening record (format is not {RECORD_FORMAT!r})")
        if version.shape != () or version.dtype.kind not in "iu" or int(version) != RECORD_VERSION:
            raise fail(f"coarsening record version {version.tolist()!r}; this lacore reads version {RECORD_VERSION}")
        ints = {}
        for name, ndim in (("n_fine_vertices", 0), ("fine_faces", 2), ("faces", 2), ("collapse_sources", 1),
                           ("collapse_targets", 1), ("ring_offsets", 1), ("ring_pairs", 2)):
            a = get(name)
            if a.dtype.kind not in "iu" or a.ndim != ndim or (ndim == 2 and a.shape[1] != (3 if "faces" in name
                                                                                         else 2)):
                want = {0: "an integer", 1: "(K,) integers"}.get(ndim, "(n, 3) integers" if "faces" in name
                                                                 else "(n, 2) integers")
                raise fail(f"'{prefix}{name}' must be {want}, got {a.dtype} {a.shape}")
            ints[name] = a.astype(np.int64)
        costs = get("costs")
        V = int(ints["n_fine_vertices"])
        src, dst = ints["collapse_sources"], ints["collapse_targets"]
        off, pairs = ints["ring_offsets"], ints["ring_pairs"]
        K = len(src)
        if costs.dtype.kind != "f" or costs.shape != (K,):
            raise fail(f"'{prefix}costs' must be ({K},) floats, got {costs.dtype} {costs.shape}")
        if not 4 <= V - K <= V or dst.shape != (K,) or off.shape != (K + 1,):
            raise fail(f"inconsistent sizes: {V} fine vertices, {K} collapses, {len(dst)} targets, "
                       f"{len(off)} ring offsets")
        for name in ("fine_faces", "collapse_sources", "collapse_targets", "ring_pairs"):
            a = ints[name]
            if a.size and (a.min() < 0 or a.max() >= V):
                raise fail(f"'{prefix}{name}' has vertex indices outside 0..{V - 1}")
        if len(np.unique(src)) != K:
            raise fail("a vertex is removed by two collapses")
        if off[0] != 0 or off[-1] != len(pairs) or np.any(np.diff(off) < 1):
            raise fail("the ring offsets do not split the ring pairs into non-empty rings")
        # every vertex a collapse refers to (its target, its ring) is still there at that collapse
        removed_at = np.full(V, K, np.int64)
        removed_at[src] = np.arange(K)
        step = np.repeat(np.arange(K), np.diff(off))
        if np.any(removed_at[dst] <= np.arange(K)) or np.any(removed_at[pairs] <= step[:, None]):
            raise fail("a collapse refers to a vertex removed before it")
        keep = np.flatnonzero(removed_at == K)
        faces = ints["faces"]
        if faces.size == 0 or faces.min() < 0 or faces.max() >= len(keep):
            raise fail(f"'{prefix}faces' must index the {len(keep)} coarse vertices")
        return cls(n_fine_vertices=V, fine_faces=ints["fine_faces"], vertex_indices=keep, faces=faces,
                   collapse_sources=src, collapse_targets=dst, parent=_parents(V, keep, src, dst),
                   ring_offsets=off, ring_pairs=pairs, costs=costs.astype(float))

    def save(self, path):
        """Write :meth:`to_arrays` to a compressed ``.npz`` file, atomically; returns the path written.

        ``.npz`` is appended to a name without it (as :func:`numpy.savez` does).
        """
        return save_npz_atomic(path, compressed=True, **self.to_arrays())

    @classmethod
    def load(cls, path):
        """Read a file written by :meth:`save` (see :meth:`from_arrays` for the checks)."""
        with open_npz(path, "coarsening record") as npz:
            return cls.from_arrays(npz, source=os.fspath(path))

    def restrict(self, vertices):
        """Coarse vertices of fine shapes: ``vertices[..., vertex_indices, :]``.

        Parameters
        ----------
        vertices : (..., V, 3) array_like

        Returns
        -------
        (..., Vc, 3) ndarray
        """
        X = np.asarray(vertices, dtype=float)
        if X.shape[-2:] != (self.n_fine_vertices, 3):
            raise MeshError(f"expected (..., {self.n_fine_vertices}, 3) fine vertices, got {X.shape}")
        return X[..., self.vertex_indices, :]


def _parents(V, keep, sources, targets):
    """Coarse index of the vertex that finally absorbed each fine vertex (see :attr:`Coarsening.parent`)."""
    parent = np.full(V, -1, np.int64)
    parent[keep] = np.arange(len(keep))
    for a, b in zip(sources[::-1].tolist(), targets[::-1].tolist(), strict=True):
        parent[a] = parent[b]
    return parent


def _face_planes(P, faces):
    """Unit normals (N,F,3), offsets (N,F), areas (N,F) and raw cross products of faces in every shape."""
    a, b, c = (P[:, faces[:, i]] for i in range(3))
    cr = np.cross(b - a, c - a)
    norm = np.linalg.norm(cr, axis=-1)
    n = cr / np.maximum(norm, 1e-300)[..., None]
    d = -np.einsum("nfi,nfi->nf", n, a)
    return n, d, 0.5 * norm


def _plane_quadrics(n, d, w):
    """Quadrics ``w [n; d][n; d]^T`` as (..., 4, 4)."""
    h = np.concatenate([n, d[..., None]], axis=-1)
    return w[..., None, None] * h[..., :, None] * h[..., None, :]


def vertex_quadrics(shapes, topology, boundary_weight=10.0):
    """Groupwise Garland-Heckbert quadrics of every vertex in every shape.

    Parameters
    ----------
    shapes : (N, V, 3) ndarray
    topology : MeshTopology
    boundary_weight : float
        Weight of the boundary-edge planes relative to the face planes (times
        the squared edge length).

    Returns
    -------
    (V, N, 4, 4) ndarray
    """
    P = shapes
    N, V = P.shape[:2]
    faces = topology.faces
    n, d, area = _face_planes(P, faces)
    Kf = _plane_quadrics(n, d, area)  # (N,F,4,4)
    Q = np.zeros((V, N, 16))
    Kf = Kf.reshape(N, -1, 16).transpose(1, 0, 2)  # (F,N,16)
    for i in range(3):
        np.add.at(Q, faces[:, i], Kf)
    be = topology.boundary_edges
    if be.size and boundary_weight > 0:
        ea, eb = topology.edges[be, 0], topology.edges[be, 1]
        f = topology.edge_faces[be, 0]
        e = P[:, eb] - P[:, ea]
        m = np.cross(e, n[:, f])
        mn = np.linalg.norm(m, axis=-1)
        m = m / np.maximum(mn, 1e-300)[..., None]
        dm = -np.einsum("nfi,nfi->nf", m, P[:, ea])
        Kb = _plane_quadrics(m, dm, boundary_weight * np.einsum("nfi,nfi->nf", e, e))
        Kb = Kb.reshape(N, -1, 16).transpose(1, 0, 2)
        np.add.at(Q, ea, Kb)
        np.add.at(Q, eb, Kb)
    return Q.reshape(V, N, 4, 4)


def _cross_and_l2(T):
    """Cross products ``(p1 - p0) x (p2 - p0)`` (k,N,3) and sums of squared edge lengths (k,N) of (k,3,N,3)."""
    e0 = T[:, 1] - T[:, 0]
    e1 = T[:, 2] - T[:, 0]
    e2 = T[:, 2] - T[:, 1]
    cr = np.empty_like(e0)
    cr[..., 0] = e0[..., 1] * e1[..., 2] - e0[..., 2] * e1[..., 1]
    cr[..., 1] = e0[..., 2] * e1[..., 0] - e0[..., 0] * e1[..., 2]
    cr[..., 2] = e0[..., 0] * e1[..., 1] - e0[..., 1] * e1[..., 0]
    return cr, (e0 * e0).sum(-1) + (e1 * e1).sum(-1) + (e2 * e2).sum(-1)


def _check_shapes(shapes, faces):
    P = np.asarray(shapes, dtype=float)
    if P.ndim == 2:
        P = P[None]
    if P.ndim != 3 or P.shape[-1] != 3 or P.shape[0] < 1:
        raise MeshError(f"shapes must be (N, V, 3) or (V, 3), got {np.shape(shapes)}")
    if not np.all(np.isfinite(P)):
        bad = np.flatnonzero(~np.isfinite(P).all(axis=(0, 2)))
        raise MeshError(f"shapes have non-finite coordinates at vertices {bad[:8].tolist()}")
    faces = check_faces(faces, P.shape[1])
    return P, faces


def coarsen(shapes, faces, n_vertices, *, boundary_weight=10.0, max_normal_angle=60.0, min_quality=0.1,
            progress=None):
    """Coarsen a group of shapes in dense correspondence by half-edge collapses.

    Parameters
    ----------
    shapes : (N, V, 3) or (V, 3) array_like
        The shapes (e.g. all shape keys); the error and every validity check
        consider all of them.
    faces : (F, 3) array_like of int
        Manifold, consistently oriented triangles (as for
        :meth:`MeshTopology.from_faces`).
    n_vertices : int
        Target number of coarse vertices ``Vc`` (``4 <= Vc <= V``).
    boundary_weight : float
        Weight of the boundary-preserving planes (see the module docstring).
    max_normal_angle : float
        Largest rotation (degrees) of a face normal caused by one collapse, in
        any shape (default 60).
    min_quality : float
        Smallest quality ``4 sqrt(3) A / (a^2 + b^2 + c^2)`` a face may get by
        a collapse (default 0.1), unless it was already worse.
    progress : callable, optional
        ``progress(done, total, message)`` (see :mod:`lacore.progress`).

    Returns
    -------
    Coarsening

    Raises
    ------
    MeshError
        Non-manifold or badly shaped input, shapes that do not match.
    InputError
        A target count that cannot be reached without breaking the topology
        (the message says how far it got).

    Examples
    --------
    >>> from lacore.multiresolution import coarsen
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=12, n_side=1)
    >>> c = coarsen([X, bar_pose(X, 0.5, 0.0)], faces, 20)   # both shapes decide every collapse
    >>> c.n_fine_vertices, c.n_vertices, c.faces.shape
    (54, 20, (36, 3))
    >>> bool((c.restrict(X) == X[c.vertex_indices]).all())     # the coarse shape: kept fine vertices
    True
    """
    t0 = time.perf_counter()
    P, faces = _check_shapes(shapes, faces)
    N, V = P.shape[:2]
    target = int(n_vertices)
    if target != n_vertices or not 4 <= target <= V:
        raise InputError(f"n_vertices must be an integer in [4, {V}], got {n_vertices!r}")
    topo = MeshTopology.from_faces(faces, n_vertices=V)
    Q = vertex_quadrics(P, topo, boundary_weight)
    H = np.concatenate([P, np.ones((N, V, 1))], axis=-1).transpose(1, 0, 2).copy()  # (V,N,4)
    Pv = P.transpose(1, 0, 2).copy()  # (V,N,3)

    F = len(faces)
    fcur = faces.copy()
    falive = np.ones(F, bool)
    vf = [set() for _ in range(V)]
    for f, (a, b, c) in enumerate(faces.tolist()):
        vf[a].add(f)
        vf[b].add(f)
        vf[c].add(f)
    is_bd = topo.is_boundary_vertex.copy()
    valive = np.ones(V, bool)
    stamp = np.zeros(V, np.int64)
    blocked = [set() for _ in range(V)]  # blocked[y]: directed candidates (a, b) touching y

    def nbrs(a):
        s = set(fcur[list(vf[a])].ravel().tolist())
        s.discard(a)
        return s

    def costs(src, dst):
        Qs = Q[src] + Q[dst]
        h = H[dst]
        return np.einsum("mni,mnij,mnj->m", h, Qs, h)

    heap = []

    def push(src, dst):
        if not len(src):
            return
        c = costs(src, dst).tolist()
        st = stamp[src].tolist()
        sd = stamp[dst].tolist()
        for item in zip(c, src.tolist(), dst.tolist(), st, sd, strict=True):
            heapq.heappush(heap, item)

    E = topo.edges
    src0, dst0 = np.concatenate([E[:, 0], E[:, 1]]), np.concatenate([E[:, 1], E[:, 0]])
    heap = list(zip(costs(src0, dst0).tolist(), src0.tolist(), dst0.tolist(), [0] * len(src0), [0] * len(src0),
                    strict=True))
    heapq.heapify(heap)

    fcr, fl2 = _cross_and_l2(Pv[faces])  # current faces: cross products (F,N,3), sums of squared lengths (F,N)
    fnorm = np.sqrt((fcr * fcr).sum(-1))

    def geometry(a, b, moved):
        """(ok, cross products, squared lengths) of the faces ``moved`` after moving their corner a to b."""
        tri = fcur[moved]
        cr, l2 = _cross_and_l2(Pv[np.where(tri == a, b, tri)])
        nn = np.sqrt((cr * cr).sum(-1))
        no = fnorm[moved]
        if not np.all((fcr[moved] * cr).sum(-1) > cos_max * no * nn):
            return False, None, None  # flipped, degenerate or turned too far in some shape
        q_new = nn / l2
        # a face may not get worse than min_quality (unless it gets no worse than it was)
        ok = bool(np.all((q_new >= qmin_scaled) | (q_new >= no / fl2[moved])))
        return ok, cr, l2

    sources, targets, cost_list, ring_chunks = [], [], [], []
    n_alive = V
    n_remove = V - target
    cos_max = np.cos(np.radians(max_normal_angle))
    qmin = float(min_quality)
    qmin_scaled = qmin / (2.0 * np.sqrt(3.0))  # quality 4 sqrt(3) A / sum l^2 = 2 sqrt(3) |cross| / sum l^2
    relax_rounds = 0
    failures = {}
    next_report = 0
    while n_alive > target:
        if not heap:
            # relax the geometric thresholds and retry everything still alive
            relax_rounds += 1
            if relax_rounds > 6:
                raise InputError(f"coarsening stopped at {n_alive} vertices (target {target}): no further "
                                 "collapse keeps the mesh manifold and unflipped in every shape")
            qmin *= 0.5
            qmin_scaled = qmin / (2.0 * np.sqrt(3.0))
            cos_max = max(0.0, cos_max - 0.1) if relax_rounds < 6 else 0.0
            for lst in blocked:
                lst.clear()
            failures.clear()
            al = falive.nonzero()[0]
            fa = fcur[al]
            src = np.concatenate([fa[:, 0], fa[:, 1], fa[:, 2]])
            dst = np.concatenate([fa[:, 1], fa[:, 2], fa[:, 0]])
            push(src, dst)
            continue
        cost, a, b, sa, sb = heapq.heappop(heap)
        if not (valive[a] and valive[b]) or stamp[a] != sa or stamp[b] != sb:
            continue
        Fa = vf[a]
        shared = Fa & vf[b]
        ns = len(shared)
        if ns == 0:
            continue  # no longer an edge
        edge_bd = ns == 1
        ok = not (is_bd[a] and not edge_bd)
        if ok:
            Na = nbrs(a)
            common = Na & nbrs(b)
            opp = set(fcur[list(shared)].ravel().tolist()) - {a, b}
            ok = common == opp
            if ok:
                moved = [f for f in Fa if f not in shared]
                ok, cr, l2 = geometry(a, b, moved) if moved else (True, None, None)
                if not ok:  # geometry changes only with the faces around a; retried a few times
                    n_fail = failures.get((a, b), 0) + 1
                    failures[(a, b)] = n_fail
                    if n_fail <= _MAX_RETRIES:
                        blocked[a].add((a, b))
                    continue
        if not ok:  # topology: changes with the neighbourhood of a or b
            blocked[a].add((a, b))
            blocked[b].add((a, b))
            continue
        # --- collapse a -> b
        ring_chunks.append([(q, r) if p == a else (r, p) if q == a else (p, q)
                            for p, q, r in fcur[list(Fa)].tolist()])
        for f in shared:
            falive[f] = False
            for x in fcur[f].tolist():
                if x != a:
                    vf[x].discard(f)
        for f in moved:
            row = fcur[f]
            row[row == a] = b
            vf[b].add(f)
        if moved:
            fcr[moved] = cr
            fl2[moved] = l2
            fnorm[moved] = np.sqrt((cr * cr).sum(-1))
        vf[a] = set()
        valive[a] = False
        Q[b] += Q[a]
        stamp[b] += 1
        sources.append(a)
        targets.append(b)
        cost_list.append(cost)
        n_alive -= 1
        # --- new costs: every half-edge at b; retry blocked candidates around b
        nb = np.fromiter(nbrs(b), np.int64)
        src = [np.full(len(nb), b), nb]
        dst = [nb, np.full(len(nb), b)]
        retry = set()
        for y in [b, *nb.tolist()]:
            if blocked[y]:
                retry |= blocked[y]
                blocked[y].clear()
        retry = [(s_, d_) for s_, d_ in retry if valive[s_] and valive[d_] and s_ != b and d_ != b]
        if retry:
            r = np.array(retry, np.int64)
            src.append(r[:, 0])
            dst.append(r[:, 1])
        push(np.concatenate(src), np.concatenate(dst))
        done = V - n_alive
        if progress is not None and done >= next_report:
            report(progress, done, n_remove, "coarsening")
            next_report = done + max(1, n_remove // 100)

    keep = np.flatnonzero(valive)
    new_index = np.full(V, -1, np.int64)
    new_index[keep] = np.arange(len(keep))
    cfaces = new_index[fcur[falive]]
    sources = np.asarray(sources, np.int64)
    targets = np.asarray(targets, np.int64)
    parent = _parents(V, keep, sources, targets)
    sizes = np.array([len(c) for c in ring_chunks], np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    pairs = np.array([pq for c in ring_chunks for pq in c], np.int64).reshape(-1, 2)
    if progress is not None:
        report(progress, n_remove, n_remove, "coarsening done")
    return Coarsening(n_fine_vertices=V, fine_faces=faces, vertex_indices=keep, faces=cfaces,
                      collapse_sources=sources, collapse_targets=targets, parent=parent, ring_offsets=offsets,
                      ring_pairs=pairs, costs=np.asarray(cost_list, float), seconds=time.perf_counter() - t0)
