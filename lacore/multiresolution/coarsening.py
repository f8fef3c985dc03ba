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
``v``.

Order of collapses
------------------
By default (``batched=True``) collapses are done in rounds, each a set of
collapses that do not interfere.  Collapse ``a -> b`` changes only the faces
around ``a`` (and with them the rings of ``a``'s neighbours) and the quadric
of ``b``; two collapses are independent when neither's two vertices lie in
the other's closed ring of ``a``, and independent collapses give the same
mesh in any order.  A round's candidates are the collapses up to the
cheapest one of the cheapest 5 % of the remaining vertices (compared as
below); in a few passes, each vertex's cheapest open candidate is collapsed
if it is the cheapest of the candidates it interferes with and valid
(below), and candidates that interfere with a collapse of the round wait
for the next round.  A round is thus equivalent to doing its collapses one
at a time, cheapest first, each valid in the mesh it meets; the selection
and the updates are array operations (about 50 rounds for a 13k-vertex body
to 2,500 vertices instead of a loop over 10,880 collapses), and the costs
of the collapses a round did not touch are kept.  A rejected candidate is
retried once the ring of either vertex has changed.  The coarse meshes are
as good as those of one collapse at a time (measured on the sample meshes
and the human body's shape keys: total collapse cost within 2 %, the
largest within 4 %).  ``batched=False`` does one collapse at a time,
cheapest first (a priority queue with lazily invalidated entries, dropped
in one pass when many have piled up), several times slower.

Order of equally cheap collapses
--------------------------------
Costs are compared after rounding to ``2**-30`` (about ``1e-9``) of
the size of the terms summed into them, millions of times their rounding
errors: costs equal in exact arithmetic -- every collapse of a flat region,
the mirror images of a symmetric mesh -- compare equal however their sums
were rounded (SIMD path, summation order), in any unit of length.  Equal
costs go shortest edge first (squared length summed over the shapes, rounded
alike), which coarsens a flat or symmetric region evenly, then by vertex
index.  The geometric checks below likewise decide a value equal to its
threshold the same way whatever its rounding.

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

If no candidate is left before the target count, the geometric thresholds are
relaxed (quality halved, normal angle widened towards 90 degrees) and the
remaining candidates are retried; flips and topology are never relaxed.

Storing a coarsening
--------------------
The collapse order is greedy: a cost within rounding error of a rounding
boundary of the comparison above, or input that differs in its last bits, can
still change one collapse and every later one, giving another (equally good)
coarse mesh.  Whatever must be reproduced -- a coarse mesh that fits were made
on, the prolongation back to the fine mesh -- is stored instead:
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
import scipy.sparse as sp

from ..errors import InputError, MeshError, as_float_array, check_integer, format_indices
from ..geometry.topology import MeshTopology, check_faces
from ..geometry.lengths_angles import degenerate_faces
from ..io.atomic import save_npz_atomic
from ..io.npz import open_npz
from ..progress import report

__all__ = ["Coarsening", "coarsen", "vertex_quadrics", "RECORD_FORMAT", "RECORD_VERSION"]

#: A candidate rejected for its geometry is retried (after changes around it) at most this often per round.
_MAX_RETRIES = 3

#: Passes of the selection of one round's independent collapses (each pass adds the cheapest candidates whose
#: neighbourhoods meet no cheaper open candidate's; the rest wait for the next round).
_MAX_SELECTION_PASSES = 8

#: Share of the remaining vertices whose cheapest collapses bound the candidates of one round (smaller: closer
#: to one collapse at a time, more rounds).
_ROUND_FRACTION = 0.05

#: The next corner of each corner of a triangle.
_NEXT = np.array([1, 2, 0])

def _relaxed_thresholds(relax_round, qmin, cos_max, n_alive, target):
    """The geometric thresholds for relaxation round ``relax_round`` (1 to 6): ``(qmin, qmin / (2 sqrt 3), cos_max)``
    with the quality halved and the normal angle widened (any angle below 90 degrees in the last round); InputError
    after the last."""
    if relax_round > 6:
        raise InputError(f"coarsening stopped at {n_alive} vertices (target {target}): no further "
                         "collapse keeps the mesh manifold and unflipped in every shape")
    qmin *= 0.5
    return qmin, qmin / (2.0 * np.sqrt(3.0)), (max(0.0, cos_max - 0.1) if relax_round < 6 else 0.0)


#: Rows handled at once by the vectorized steps over all faces or edges (bounded temporaries).
_CHUNK = 4096

#: The heap is purged of outdated entries when the outdated entries popped since the last purge exceed this
#: fraction of its size (popping one costs a logarithmic sift, dropping it a constant).
_PURGE_FRACTION = 16

#: Collapse costs are compared after rounding to this many bits below the size of their terms (see
#: :func:`_rounding_shift`): millions of times their rounding errors (about 52 bits below the terms), below the
#: differences that shape a coarse mesh.
_COST_BITS = 30

#: Relative margin of the geometric checks (normal rotation, triangle quality): a value equal to its threshold in
#: exact arithmetic is decided the same way whatever its rounding.
_GEOMETRY_TOLERANCE = 2.0 ** -30

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
        Quadric error of each collapse, rounded as the queue compares them
        (see the module docstring).
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
    #: Insertion levels and ring data of :class:`~lacore.multiresolution.Prolongation` (integers; built once).
    _prolongation_levels: object = field(default=None, repr=False, compare=False)

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


#: Upper-triangle entries ``(i, j)`` of a symmetric 4x4 quadric, and the weight of their products in ``h^T Q h``.
_SYM_I, _SYM_J = np.triu_indices(4)
_SYM_W = np.where(_SYM_I == _SYM_J, 1.0, 2.0)
#: Positions of ``Q[0, 0], Q[1, 1], Q[2, 2]`` among them.
_SYM_TRACE = np.flatnonzero((_SYM_I == _SYM_J) & (_SYM_I < 3))


def _rounding_shift(scales):
    """Shifts ``k`` such that ``(x + k) - k`` rounds ``x`` to a multiple of ``2**-_COST_BITS * scales`` (``scales``
    rounded up to powers of two), for ``|x| <= scales``.

    ``k = 1.5 * 2**52 * step`` with ``step`` that power of two: the floating-point numbers around ``k`` are the
    multiples of ``step``, so the sum rounds ``x`` (to nearest, ties to even) and the difference is exact.  With
    ``scales`` bounding the terms summed into costs, their rounding errors are a few units of ``1e-16 * scales``:
    costs that are equal in exact arithmetic (the mirror images of a symmetric mesh) round to the same value
    however they were summed, and the queue orders them by its next keys (edge length, vertex indices).  Costs
    that differ by more than ``2**-_COST_BITS`` of their terms keep their order.

    Parameters
    ----------
    scales : (k,) ndarray or float
        Positive.

    Returns
    -------
    (k,) ndarray or float
    """
    return np.ldexp(1.5, np.frexp(scales)[1] + (52 - _COST_BITS))


def _cross(u, v):
    """Cross products of (..., 3) arrays (:func:`numpy.cross` without its axis handling: faster on large arrays)."""
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    x0, y0, z0 = u[..., 0], u[..., 1], u[..., 2]
    x1, y1, z1 = v[..., 0], v[..., 1], v[..., 2]
    np.subtract(y0 * z1, z0 * y1, out=out[..., 0])
    np.subtract(z0 * x1, x0 * z1, out=out[..., 1])
    np.subtract(x0 * y1, y0 * x1, out=out[..., 2])
    return out


def _face_planes(P, faces):
    """Unit normals (N,F,3), offsets (N,F), areas (N,F) and raw cross products of faces in every shape."""
    a, b, c = (P[:, faces[:, i]] for i in range(3))
    cr = _cross(b - a, c - a)
    norm = np.linalg.norm(cr, axis=-1)
    n = cr / np.maximum(norm, 1e-300)[..., None]
    d = -np.einsum("nfi,nfi->nf", n, a)
    return n, d, 0.5 * norm


def _plane_quadrics(n, d, w):
    """Upper-triangle entries (:data:`_SYM_I`, :data:`_SYM_J`) of the quadrics ``w [n; d][n; d]^T`` of (N,k)
    planes, as (k, 10 * N) rows (entry by entry, shape by shape)."""
    h = np.concatenate([n, d[..., None]], axis=-1).transpose(1, 0, 2)  # (k,N,4)
    k, N = h.shape[:2]
    return (w.T[..., None] * h[..., _SYM_I] * h[..., _SYM_J]).transpose(0, 2, 1).reshape(k, 10 * N)


def _incidence(*columns, n_vertices):
    """Sparse (V, k) matrix with a 1 at ``(columns[j][i], i)`` for every ``j``: its product with per-item rows sums
    them onto the vertices."""
    k = len(columns[0])
    rows = np.concatenate(columns)
    cols = np.tile(np.arange(k), len(columns))
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, k))


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
    N, V = shapes.shape[:2]
    q = _quadric_entries(shapes, topology, boundary_weight).reshape(V, 10, N).transpose(0, 2, 1)
    Q = np.empty((V, N, 4, 4))
    Q[..., _SYM_I, _SYM_J] = q
    Q[..., _SYM_J, _SYM_I] = q
    return Q


def _quadric_entries(P, topology, boundary_weight, cross=None):
    """:func:`vertex_quadrics` as the upper-triangle entries (:data:`_SYM_I`, :data:`_SYM_J`): (V, 10 * N), entry
    by entry, shape by shape.

    ``cross`` (F, 3, N), if given, holds the faces' cross products ``(p1 - p0) x (p2 - p0)`` (see
    :func:`_cross_and_l2`).  A face's plane quadric ``area [n; d][n; d]^T`` is ``c c^T / (2 |x|)`` with ``x`` the
    cross product and ``c = [x; -x . p0]``.
    """
    N, V = P.shape[:2]
    faces = topology.faces
    Pv = P.transpose(1, 2, 0)  # (V,3,N)
    Q = np.zeros((V, 10 * N))
    for i in range(0, len(faces), _CHUNK):  # in chunks of faces: the temporaries stay small
        f = faces[i:i + _CHUNK]
        x = _cross_and_l2(Pv, f)[0] if cross is None else cross[i:i + _CHUNK]  # (k,3,N)
        c = np.empty((len(f), 4, N))
        c[:, :3] = x
        c[:, 3] = -(x * Pv[f[:, 0]]).sum(1)
        c *= np.sqrt(0.5 / np.maximum(np.sqrt((x * x).sum(1)), 1e-300))[:, None]
        q = c[:, _SYM_I] * c[:, _SYM_J]  # (k,10,N)
        Q += _incidence(f[:, 0], f[:, 1], f[:, 2], n_vertices=V) @ q.reshape(len(f), 10 * N)
    be = topology.boundary_edges
    if be.size and boundary_weight > 0:
        ea, eb = topology.edges[be, 0], topology.edges[be, 1]
        e = P[:, eb] - P[:, ea]
        m = _cross(e, _face_planes(P, faces[topology.edge_faces[be, 0]])[0])
        mn = np.linalg.norm(m, axis=-1)
        m = m / np.maximum(mn, 1e-300)[..., None]
        dm = -np.einsum("nfi,nfi->nf", m, P[:, ea])
        Q += _incidence(ea, eb, n_vertices=V) @ _plane_quadrics(m, dm, boundary_weight * np.einsum("nfi,nfi->nf",
                                                                                                  e, e))
    return Q


def _cross_and_l2(Pv, tri):
    """Cross products ``(p1 - p0) x (p2 - p0)`` (k,3,N) and sums of squared edge lengths (k,N) of triangles
    ``tri`` (k,3) of vertices ``Pv`` (V,3,N) (coordinate, shape: the coordinates of all shapes contiguous)."""
    p0, e0, e1 = Pv[tri[:, 0]], Pv[tri[:, 1]], Pv[tri[:, 2]]
    e2 = e1 - e0
    e0 -= p0
    e1 -= p0
    cr = np.empty_like(e0)
    for i, j, m in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # whole rows (all shapes) at a time
        np.multiply(e0[:, j], e1[:, m], out=cr[:, i])
        cr[:, i] -= e0[:, m] * e1[:, j]
    e0 *= e0
    e1 *= e1
    e2 *= e2
    l2 = e0.sum(1)
    l2 += e1.sum(1)
    l2 += e2.sum(1)
    return cr, l2


def _check_shapes(shapes, faces):
    P = as_float_array(shapes, "shapes", MeshError)
    if P.ndim == 2:
        P = P[None]
    if P.ndim != 3 or P.shape[-1] != 3 or P.shape[0] < 1:
        raise MeshError(f"shapes must be (N, V, 3) or (V, 3), got {np.shape(shapes)}")
    if not np.all(np.isfinite(P)):
        bad = np.flatnonzero(~np.isfinite(P).all(axis=(0, 2)))
        raise MeshError(f"shapes have non-finite coordinates at vertices {bad[:8].tolist()}")
    faces = check_faces(faces, P.shape[1])
    topology = MeshTopology.from_faces(faces, n_vertices=P.shape[1])
    for k, X in enumerate(P):
        bad = degenerate_faces(X, topology)
        if bad.size:
            which = f"shape {k}" if len(P) > 1 else "the shape"
            raise MeshError(f"{which} has degenerate triangles (zero area, or edge lengths violating the triangle "
                            f"inequality after rounding): faces {format_indices(bad)}; coarsen shapes whose "
                            "triangles all have an area")
    return P, faces


def coarsen(shapes, faces, n_vertices, *, boundary_weight=10.0, max_normal_angle=60.0, min_quality=0.1,
            batched=True, progress=None):
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
    batched : bool
        Collapse in rounds of independent collapses (default; see the module
        docstring), or one at a time (``False``: several times slower).
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
    try:
        target = check_integer(n_vertices, "n_vertices", 4)
    except InputError:
        target = -1
    if not 4 <= target <= V:
        raise InputError(f"n_vertices must be an integer in [4, {V}], got {n_vertices!r}")
    for name, value, lo_, hi_ in (("boundary_weight", boundary_weight, 0.0, np.inf),
                                  ("max_normal_angle", max_normal_angle, 0.0, 180.0),
                                  ("min_quality", min_quality, 0.0, 1.0)):
        try:
            ok = lo_ <= float(value) <= hi_ and (hi_ < np.inf or np.isfinite(float(value)))
        except (TypeError, ValueError):
            ok = False
        if not ok or (name == "max_normal_angle" and float(value) == 0.0):
            bounds = f">= {lo_:g}" if hi_ == np.inf else f"in ({lo_:g}, {hi_:g}]" if name == "max_normal_angle" \
                else f"in [{lo_:g}, {hi_:g}]"
            raise InputError(f"{name} must be a number {bounds}, got {value!r}")
    topo = MeshTopology.from_faces(faces, n_vertices=V)
    # each shape centred on its bounding box, all in units of the largest box diagonal: costs are sums of terms
    # of the size of the shape (not of its distance from the origin), and their rounding (_rounding_shift)
    # does not depend on the unit of length
    lo, hi = P.min(axis=1), P.max(axis=1)
    unit = float(np.sqrt(((hi - lo) ** 2).sum(1).max())) or 1.0
    P = (P - 0.5 * (lo + hi)[:, None]) / unit
    lo, hi = P.min(axis=1), P.max(axis=1)
    Pv = P.transpose(1, 2, 0).copy()  # (V,3,N)
    F = len(faces)
    fcr, fl2 = np.empty((F, 3, N)), np.empty((F, N))  # current faces: cross products, sums of squared lengths
    for i in range(0, F, _CHUNK):
        fcr[i:i + _CHUNK], fl2[i:i + _CHUNK] = _cross_and_l2(Pv, faces[i:i + _CHUNK])
    fnorm = np.sqrt((fcr * fcr).sum(1))
    Q = _quadric_entries(P, topo, boundary_weight, cross=fcr)
    # h^T Q h = M(h) . q(Q) with q the 10 upper-triangle entries of the symmetric Q and M(h) the products
    # h_i h_j (doubled off the diagonal): per vertex, entry by entry and shape by shape, rows of 10 N.
    H = np.ones((V, 4, N))
    H[:, :3] = Pv
    M = H[:, _SYM_I]
    M *= H[:, _SYM_J]
    M *= _SYM_W[:, None]
    M = M.reshape(V, 10 * N)
    self_cost = np.einsum("vk,vk->v", M, Q)  # cost of the quadric of v at v itself
    # the terms of h^T Q h at a point p of the bounding box, for planes (n, d) through points of it (|n| = 1,
    # |p| <= R, |d| <= R): at most 4 R^2 times their weights, whose sum is trace(Q[:3, :3]), per shape
    bound = np.zeros((10, N))
    bound[_SYM_TRACE] = ((hi - lo) ** 2).sum(1)
    bound = bound.ravel()
    # per vertex, the rounding of the costs of its collapses (_rounding_shift): a collapse's terms are at most
    # twice the larger of its two vertices' bounds
    vshift = _rounding_shift(2.0 * (Q @ bound))

    n_remove = V - target
    # the queue: (cost, squared length summed over the shapes, source, target, their stamps when queued), costs
    # and lengths rounded (_rounding_shift); equally cheap collapses (e.g. all of a flat region's) go shortest edge
    # first, which coarsens such a region evenly, then by vertex index
    G = Pv.reshape(V, 3 * N)
    length_shift = float(_rounding_shift(float(((hi - lo) ** 2).sum())))

    def costs(src, dst):
        """Rounded costs of the collapses ``src[i] -> dst[i]`` (arrays)."""
        out = np.empty(len(src))
        for i in range(0, len(src), _CHUNK):  # in chunks: the rows gathered stay small
            s, d = src[i:i + _CHUNK], dst[i:i + _CHUNK]
            shift = np.maximum(vshift[s], vshift[d])
            c = np.einsum("mk,mk->m", M[d], Q[s])
            c += self_cost[d]
            c += shift
            np.subtract(c, shift, out=out[i:i + _CHUNK])
        return out

    def lengths(src, dst):
        """Rounded squared lengths (summed over the shapes) of the edges ``src[i], dst[i]`` (``dst`` an array or one
        vertex)."""
        out = np.empty(len(src))
        for i in range(0, len(src), _CHUNK):
            e = G[src[i:i + _CHUNK]] - G[dst if np.ndim(dst) == 0 else dst[i:i + _CHUNK]]
            out[i:i + _CHUNK] = np.einsum("mk,mk->m", e, e)
        out += length_shift
        out -= length_shift
        return out

    def push(src, dst, l2):
        """Queue the candidates ``src[i] -> dst[i]`` (lists of vertices, squared lengths ``l2``) at their current
        costs."""
        items = zip(costs(np.array(src), np.array(dst)).tolist(), l2, src, dst, [stamp[i] for i in src],
                    [stamp[i] for i in dst], strict=True)
        for item in items:
            heapq.heappush(heap, item)

    if batched:
        state = {"faces": faces, "topo": topo, "Q": Q, "M": M, "self_cost": self_cost, "vshift": vshift,
                 "bound": bound, "Pv": Pv, "fcr": fcr, "fl2": fl2, "fnorm": fnorm, "costs": costs, "lengths": lengths}
        cur, falive, valive, sources, targets, cost_arr, ring_pairs, ring_sizes = _batched_collapses(
            state, target, np.cos(np.radians(max_normal_angle)), float(min_quality), progress)
        return _result(V, faces, cur, falive, valive, sources, targets, cost_arr, ring_pairs, ring_sizes, unit,
                       n_remove, progress, t0)

    fcur = faces.tolist()  # current faces, as Python lists: read and changed a few at a time in the loop
    falive = np.ones(F, bool)
    vf = [set() for _ in range(V)]
    for f, (a, b, c) in enumerate(fcur):
        vf[a].add(f)
        vf[b].add(f)
        vf[c].add(f)
    is_bd = topo.is_boundary_vertex.tolist()
    valive = [True] * V  # Python lists: read one entry at a time in the loop
    stamp = [0] * V  # changes of each vertex's quadric; -1 once removed
    blocked = [set() for _ in range(V)]  # blocked[y]: directed candidates (a, b) touching y

    def nbrs(a):
        s = {x for f in vf[a] for x in fcur[f]}
        s.discard(a)
        return s

    E = topo.edges
    src0, dst0 = np.concatenate([E[:, 0], E[:, 1]]), np.concatenate([E[:, 1], E[:, 0]])
    l0 = lengths(E[:, 0], E[:, 1]).tolist()
    heap = list(zip(costs(src0, dst0).tolist(), l0 + l0, src0.tolist(), dst0.tolist(), [0] * len(src0), [0] * len(src0),
                    strict=True))
    heapq.heapify(heap)


    def geometry(a, b, moved):
        """(ok, cross products, squared lengths, norms of the cross products) of the faces ``moved`` after moving
        their corner a to b."""
        cr, l2 = _cross_and_l2(Pv, np.array([[b if x == a else x for x in fcur[f]] for f in moved.tolist()]))
        nn = cr * cr
        nn = np.sqrt(nn.sum(1))
        no = fnorm[moved]
        if not ((fcr[moved] * cr).sum(1) > (cos_max + _GEOMETRY_TOLERANCE) * no * nn).all():
            return False, None, None, None  # flipped, degenerate or turned too far in some shape
        # a face may not get worse than min_quality (unless it gets no worse than it was; fmin: a degenerate
        # face's NaN quality leaves min_quality)
        ok = bool((nn / l2 >= (1.0 - _GEOMETRY_TOLERANCE) * np.fmin(no / fl2[moved], qmin_scaled)).all())
        return ok, cr, l2, nn

    sources, targets, cost_list, ring_chunks = [], [], [], []
    n_alive = V
    cos_max = np.cos(np.radians(max_normal_angle))
    qmin = float(min_quality)
    qmin_scaled = qmin / (2.0 * np.sqrt(3.0))  # quality 4 sqrt(3) A / sum l^2 = 2 sqrt(3) |cross| / sum l^2
    relax_rounds = 0
    failures = {}
    next_report = 0
    n_stale = 0  # outdated entries popped since the heap was last purged
    while n_alive > target:
        if not heap:
            # relax the geometric thresholds and retry everything still alive
            relax_rounds += 1
            qmin, qmin_scaled, cos_max = _relaxed_thresholds(relax_rounds, qmin, cos_max, n_alive, target)
            for lst in blocked:
                lst.clear()
            failures.clear()
            al = falive.nonzero()[0]
            fa = np.array(fcur)[al]
            src = np.concatenate([fa[:, 0], fa[:, 1], fa[:, 2]])
            dst = np.concatenate([fa[:, 1], fa[:, 2], fa[:, 0]])
            push(src.tolist(), dst.tolist(), lengths(src, dst).tolist())
            continue
        cost, _, a, b, sa, sb = heapq.heappop(heap)
        if stamp[a] != sa or stamp[b] != sb:  # outdated (a removed vertex's stamp is -1)
            n_stale += 1
            if n_stale * _PURGE_FRACTION > len(heap):  # outdated entries pile up: drop them all at once
                heap[:] = [e for e in heap if stamp[e[2]] == e[4] and stamp[e[3]] == e[5]]
                heapq.heapify(heap)
                n_stale = 0
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
            opp = {x for f in shared for x in fcur[f]} - {a, b}
            ok = common == opp
            if ok:
                moved = np.array([f for f in Fa if f not in shared], np.int64)
                ok, cr, l2, nn = geometry(a, b, moved) if len(moved) else (True, None, None, None)
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
                            for p, q, r in (fcur[f] for f in Fa)])
        for f in shared:
            falive[f] = False
            for x in fcur[f]:
                if x != a:
                    vf[x].discard(f)
        for f in moved.tolist():
            fcur[f] = [b if x == a else x for x in fcur[f]]
            vf[b].add(f)
        if len(moved):
            fcr[moved] = cr
            fl2[moved] = l2
            fnorm[moved] = nn
        vf[a] = set()
        valive[a] = False
        stamp[a] = -1
        Q[b] += Q[a]
        self_cost[b] = M[b] @ Q[b]
        vshift[b] = _rounding_shift(2.0 * float(Q[b] @ bound))
        stamp[b] += 1
        sources.append(a)
        targets.append(b)
        cost_list.append(cost)
        n_alive -= 1
        # --- new costs: every half-edge at b; retry blocked candidates around b
        nb = list(nbrs(b))
        retry = set()
        for y in [b, *nb]:
            if blocked[y]:
                retry |= blocked[y]
                blocked[y].clear()
        retry = [(s_, d_) for s_, d_ in retry if valive[s_] and valive[d_] and s_ != b and d_ != b]
        if nb:
            lb = lengths(np.array(nb), b).tolist()  # each edge at b queued both ways
            src, dst, l2 = [b] * len(nb) + nb, nb + [b] * len(nb), lb + lb
            if retry:
                rs, rd = [s_ for s_, _ in retry], [d_ for _, d_ in retry]
                src, dst, l2 = src + rs, dst + rd, l2 + lengths(np.array(rs), np.array(rd)).tolist()
            push(src, dst, l2)
        done = V - n_alive
        if progress is not None and done >= next_report:
            report(progress, done, n_remove, "coarsening")
            next_report = done + max(1, n_remove // 100)

    return _result(V, faces, np.array(fcur, np.int64), falive, np.array(valive, bool), np.asarray(sources, np.int64),
                   np.asarray(targets, np.int64), np.asarray(cost_list, float),
                   np.array([pq for c in ring_chunks for pq in c], np.int64).reshape(-1, 2),
                   np.array([len(c) for c in ring_chunks], np.int64), unit, n_remove, progress, t0)


def _result(V, faces, cur, falive, valive, sources, targets, costs, ring_pairs, ring_sizes, unit, n_remove, progress,
            t0):
    """The :class:`Coarsening` of a finished collapse loop (costs in units of the scaled shapes)."""
    keep = np.flatnonzero(valive)
    new_index = np.full(V, -1, np.int64)
    new_index[keep] = np.arange(len(keep))
    cfaces = new_index[cur[falive]]
    parent = _parents(V, keep, sources, targets)
    offsets = np.zeros(len(ring_sizes) + 1, np.int64)
    np.cumsum(ring_sizes, out=offsets[1:])
    pairs = np.asarray(ring_pairs, np.int64).reshape(-1, 2)
    if progress is not None:
        report(progress, n_remove, n_remove, "coarsening done")
    return Coarsening(n_fine_vertices=V, fine_faces=faces, vertex_indices=keep, faces=cfaces,
                      collapse_sources=sources, collapse_targets=targets, parent=parent, ring_offsets=offsets,
                      ring_pairs=pairs, costs=costs * unit ** 4, seconds=time.perf_counter() - t0)


def _csr_rows(indptr, indices, rows):
    """Concatenated entries of CSR rows ``rows`` and the number in each."""
    start = indptr[rows]
    sizes = indptr[rows + 1] - start
    seg = np.zeros(len(rows) + 1, np.int64)
    np.cumsum(sizes, out=seg[1:])
    return indices[np.repeat(start - seg[:-1], sizes) + np.arange(seg[-1])], sizes


def _batched_collapses(state, target, cos_max, qmin, progress):
    """Collapse rounds of :func:`coarsen` (see the module docstring): per round, the cheapest candidates that
    do not interfere are collapsed at once.

    ``state`` holds the scaled arrays of :func:`coarsen` (``faces, topo, Q, M, self_cost, vshift, bound, Pv,
    fcr, fl2, fnorm, costs, lengths``).  Returns ``(faces, falive, valive, sources, targets, costs, ring_pairs,
    ring_sizes)``.
    """
    faces, Q, M, self_cost, vshift, bound = (state[k] for k in ("faces", "Q", "M", "self_cost", "vshift", "bound"))
    Pv, fcr, fl2, fnorm = state["Pv"], state["fcr"], state["fl2"], state["fnorm"]
    costs, lengths = state["costs"], state["lengths"]
    topo = state["topo"]
    V, F = topo.n_vertices, len(faces)
    is_bd = topo.is_boundary_vertex
    cur = faces.copy()
    falive = np.ones(F, bool)
    valive = np.ones(V, bool)
    version = np.zeros(V, np.int64)  # changes of each vertex's ring: a rejected candidate is retried after one
    qmin_scaled = qmin / (2.0 * np.sqrt(3.0))
    # every half-edge that may collapse (a boundary vertex only along the boundary): source, target, number of
    # faces of the edge, rounded cost and squared length, and the versions of its ends when it was rejected
    E, ne = topo.edges, 2 - (topo.edge_faces[:, 1] < 0)
    hs, hd, hc = np.concatenate([E[:, 0], E[:, 1]]), np.concatenate([E[:, 1], E[:, 0]]), np.concatenate([ne, ne])
    keep = ~(is_bd[hs] & (hc == 2))
    hs, hd, hc = hs[keep], hd[keep], hc[keep]
    le = lengths(E[:, 0], E[:, 1])
    hcost, hl2, hfail = costs(hs, hd), np.concatenate([le, le])[keep], np.full(len(hs), -1, np.int64)
    out_src, out_dst, out_cost, rings, ring_sizes = [], [], [], [], []
    n_alive, n_remove, relax_rounds = V, V - target, 0
    while n_alive > target:
        valid = hfail != version[hs] + version[hd]
        if not valid.any():
            relax_rounds += 1
            qmin, qmin_scaled, cos_max = _relaxed_thresholds(relax_rounds, qmin, cos_max, n_alive, target)
            hfail[:] = -1
            continue
        # --- this round's candidates: collapses no dearer than the cheapest collapse of the cheapest
        # _ROUND_FRACTION of the vertices, cheapest first (equal costs shortest edge first, then by vertex index)
        best = np.full(V, np.inf)
        np.minimum.at(best, hs[valid], hcost[valid])
        best = best[np.isfinite(best)]
        k = min(len(best), max(1, int(_ROUND_FRACTION * n_alive))) - 1
        cand = np.flatnonzero(valid & (hcost <= np.partition(best, k)[k]))
        cand = cand[np.lexsort((hd[cand], hs[cand], hl2[cand], hcost[cand]))]
        heads = np.sort(np.unique(hs[cand], return_index=True)[1])  # each source's cheapest, in order
        cand = cand[:heads[min(k, len(heads) - 1)] + 1]
        cs, cd, ccost = hs[cand], hd[cand], hcost[cand]
        n = len(cand)
        # faces around each vertex (CSR)
        fid = np.flatnonzero(falive)
        vf_ptr, vf_faces = _adjacency(cur[fid].ravel(), np.repeat(fid, 3), V)
        # collapse a -> b changes the faces around a and the quadric of b: two collapses are independent if
        # neither's two vertices lie in the other's closed ring of a
        lock_ring = np.zeros(V, bool)  # closed rings of the sources collapsed this round
        lock_pair = np.zeros(V, bool)  # sources and targets collapsed this round
        open_ = np.ones(n, bool)
        needed = n_alive - target
        accepted, geo, n_acc = [], [], 0
        for _ in range(_MAX_SELECTION_PASSES):
            idx = np.flatnonzero(open_)
            if not len(idx):
                break
            pool = np.sort(idx[np.unique(cs[idx], return_index=True)[1]])  # each source's cheapest open candidate
            a, b = cs[pool], cd[pool]
            nb, seg = _rings(a, cur, vf_ptr, vf_faces)
            hit = lock_ring[a] | lock_ring[b] | lock_pair[a] | np.logical_or.reduceat(lock_pair[nb], seg[:-1])
            open_[pool[hit]] = False
            if hit.any():
                pool, a, b = pool[~hit], a[~hit], b[~hit]
                if not len(pool):
                    continue
                nb, seg = _rings(a, cur, vf_ptr, vf_faces)
            rank = np.repeat(pool, np.diff(seg))
            ring_min = np.full(V, n, np.int64)
            np.minimum.at(ring_min, nb, rank)
            np.minimum.at(ring_min, a, pool)
            pair_min = np.full(V, n, np.int64)
            np.minimum.at(pair_min, a, pool)
            np.minimum.at(pair_min, b, pool)
            local = ((ring_min[a] == pool) & (ring_min[b] == pool) & (pair_min[a] == pool)
                     & np.logical_and.reduceat(pair_min[nb] >= rank, seg[:-1]))
            S, a, b = pool[local], a[local], b[local]
            open_[S] = False
            # link condition: the common neighbours of a and b are the edge's opposite corners (one per face)
            ok = _common_neighbours(a, b, cur, vf_ptr, vf_faces) == hc[cand[S]]
            good = np.flatnonzero(ok)
            ok_geo, moved = _collapse_geometry(a[good], b[good], cur, vf_ptr, vf_faces, Pv, fcr, fl2, fnorm,
                                               cos_max, qmin_scaled)
            ok[good[~ok_geo]] = False
            hfail[cand[S[~ok]]] = version[a[~ok]] + version[b[~ok]]
            S, a, b = S[ok], a[ok], b[ok]
            if len(S):
                lock_ring[_rings(a, cur, vf_ptr, vf_faces)[0]] = True
                lock_ring[a] = True
                lock_pair[a] = lock_pair[b] = True
                accepted.append(S)
                geo.append(moved)
                n_acc += len(S)
                if progress is not None:
                    report(progress, V - n_alive + min(n_acc, needed), n_remove, "coarsening")
                if n_acc >= needed:
                    break
        if not accepted:
            continue
        acc = np.sort(np.concatenate(accepted))[:needed]
        a, b = cs[acc], cd[acc]
        # --- ring of each source before its collapse: the other two corners of each face, counter-clockwise
        f_of, f_count = _csr_rows(vf_ptr, vf_faces, a)
        owner = np.repeat(np.arange(len(a)), f_count)
        tri = cur[f_of]
        at = np.argmax(tri == a[owner, None], axis=1)
        rows = np.arange(len(tri))
        ring = np.stack([tri[rows, _NEXT[at]], tri[rows, _NEXT[_NEXT[at]]]], 1)
        rings.append(ring)
        ring_sizes.append(f_count)
        ring_v, _ = _rings(a, cur, vf_ptr, vf_faces)
        version[ring_v] += 1
        # --- the collapses: faces, their geometry, quadrics
        shared = (tri == b[owner, None]).any(1)
        falive[f_of[shared]] = False
        mv, ow = f_of[~shared], owner[~shared]
        cur[mv] = np.where(tri[~shared] == a[ow, None], b[ow, None], tri[~shared])
        mf, mcr, ml2, mnn = (np.concatenate(x) for x in zip(*geo, strict=True))
        sel = np.isin(mf, mv)
        fcr[mf[sel]], fl2[mf[sel]], fnorm[mf[sel]] = mcr[sel], ml2[sel], mnn[sel]
        Q[b] += Q[a]
        self_cost[b] = np.einsum("mk,mk->m", M[b], Q[b])
        vshift[b] = _rounding_shift(2.0 * (Q[b] @ bound))
        valive[a] = False
        # --- half-edges: those at a or b replaced by the edges now at b (new costs: b's quadric changed)
        ends = np.zeros(V, bool)
        ends[a] = ends[b] = True
        keep = ~(ends[hs] | ends[hd])
        bf, bcount = _csr_rows(vf_ptr, vf_faces, b)
        bf = np.concatenate([bf, mv])
        bown = np.concatenate([np.repeat(b, bcount), b[ow]])
        live = falive[bf]
        bf, bown = bf[live], bown[live]
        corners = cur[bf]
        other = corners[corners != bown[:, None]].reshape(-1, 2)
        ekey, ecount = np.unique(np.repeat(bown, 2) * V + other.ravel(), return_counts=True)
        eb, ex = np.divmod(ekey, V)
        ns, nd, nc = np.concatenate([eb, ex]), np.concatenate([ex, eb]), np.concatenate([ecount, ecount])
        ok = ~(is_bd[ns] & (nc == 2))
        le = lengths(eb, ex)
        ns, nd, nc, nl = ns[ok], nd[ok], nc[ok], np.concatenate([le, le])[ok]
        hs, hd, hc = np.concatenate([hs[keep], ns]), np.concatenate([hd[keep], nd]), np.concatenate([hc[keep], nc])
        hcost = np.concatenate([hcost[keep], costs(ns, nd)])
        hl2 = np.concatenate([hl2[keep], nl])
        hfail = np.concatenate([hfail[keep], np.full(len(ns), -1, np.int64)])
        out_src.append(a)
        out_dst.append(b)
        out_cost.append(ccost[acc])
        n_alive -= len(a)
    empty = np.empty(0, np.int64)
    return (cur, falive, valive, np.concatenate(out_src) if out_src else empty,
            np.concatenate(out_dst) if out_dst else empty, np.concatenate(out_cost) if out_cost else np.empty(0),
            np.concatenate(rings) if rings else np.empty((0, 2), np.int64),
            np.concatenate(ring_sizes) if ring_sizes else empty)


def _adjacency(rows, cols, n):
    """CSR arrays ``(indptr, indices)`` of the pairs ``(rows[i], cols[i])`` (``n`` rows, each row's entries in
    the order given)."""
    order = np.argsort(rows, kind="stable")
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=ptr[1:])
    return ptr, cols[order]


def _rings(a, cur, vf_ptr, vf_faces):
    """Neighbours of the vertices ``a`` (each listed once per face it shares with ``a[k]``: twice inside the
    mesh) and the offsets of each vertex's entries."""
    f_of, count = _csr_rows(vf_ptr, vf_faces, a)
    corners = cur[f_of]
    nb = corners[corners != np.repeat(a, count)[:, None]]
    seg = np.zeros(len(a) + 1, np.int64)
    np.cumsum(2 * count, out=seg[1:])
    return nb, seg


def _common_neighbours(a, b, cur, vf_ptr, vf_faces):
    """Number of common neighbours of ``a[k]`` and ``b[k]``."""
    na, sa = _rings(a, cur, vf_ptr, vf_faces)
    nb, sb = _rings(b, cur, vf_ptr, vf_faces)
    m = len(vf_ptr)
    ka = np.unique(np.repeat(np.arange(len(a)), np.diff(sa)) * m + na)
    kb = np.unique(np.repeat(np.arange(len(b)), np.diff(sb)) * m + nb)
    both = np.intersect1d(ka, kb, assume_unique=True)
    return np.bincount(both // m, minlength=len(a))


def _collapse_geometry(a, b, cur, vf_ptr, vf_faces, Pv, fcr, fl2, fnorm, cos_max, qmin_scaled):
    """Geometric validity of collapses ``a[k] -> b[k]`` (no face turning by more than the largest normal angle,
    none worse than the quality bound) and the moved faces' new ``(faces, cross products, squared lengths,
    norms)`` of the valid ones."""
    f_of, f_count = _csr_rows(vf_ptr, vf_faces, a)
    owner = np.repeat(np.arange(len(a)), f_count)
    tri = cur[f_of]
    moved = ~(tri == b[owner, None]).any(1)
    f_of, owner, tri = f_of[moved], owner[moved], tri[moved]
    tri = np.where(tri == a[owner, None], b[owner, None], tri)
    m = len(f_of)
    cr = np.empty((m,) + fcr.shape[1:])
    l2 = np.empty((m,) + fl2.shape[1:])
    for i in range(0, m, _CHUNK):
        cr[i:i + _CHUNK], l2[i:i + _CHUNK] = _cross_and_l2(Pv, tri[i:i + _CHUNK])
    nn = np.sqrt((cr * cr).sum(1))
    no = fnorm[f_of]
    face_ok = ((fcr[f_of] * cr).sum(1) > (cos_max + _GEOMETRY_TOLERANCE) * no * nn).all(1)
    face_ok &= (nn / l2 >= (1.0 - _GEOMETRY_TOLERANCE) * np.fmin(no / fl2[f_of], qmin_scaled)).all(1)
    ok = np.bincount(owner[~face_ok], minlength=len(a)) == 0
    keep = ok[owner]
    return ok, (f_of[keep], cr[keep], l2[keep], nn[keep])
