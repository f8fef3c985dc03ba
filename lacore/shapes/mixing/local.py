"""The local correction of a mix: one Gauss-Newton step of ``W_q`` on the few vertices the reduced space misses.

A reduced space spanned by keys, derivatives and Newton vectors holds a mix's shape to a few thousandths of a
percent of the mesh size, but where one key stretches a small region far (the armpit of a raised arm) the
minimizer of ``W_q`` bends that region in detail no global vector carries, and the reduced mix's energy can exceed
the projection's by several percent while its vertices are all but exact.  The build finds those vertices: at its
training points (:meth:`ShapeMixer._training`) the gradient of the full energy outside the space,
``g_perp = (I - U U^T) g``, says per vertex how much a step of that vertex alone would lower the energy,
``|g_perp,v|^2 / h_v`` (``h_v`` a third of the trace of the vertex's 3x3 block of the Gauss-Newton matrix);
:func:`hot_vertices` keeps the :attr:`MixerOptions.local_vertices` vertices of the largest mean density when they
hold at least :data:`HOT_SHARE` of it (the error is local), else none.  A mix then takes one Gauss-Newton step
of the full energy on those vertices with every other vertex held (:class:`LocalCorrection`): the lengths and
angles of a patch around them, a sparse factorization of the size of the patch (symbolic analysis once), and the
step where it lowers the energy (the energy change is exact: only the rows the step moves change), then
:data:`CHORD_STEPS` steps with the same factorization and the gradient where the last step ended.

On the CC0 body (13k vertices, keys raising an arm, bending a knee and twisting the torso), where the reduced
mixes' excess energy over converged Gauss-Newton sits in a few dozen edges of the left armpit, 150 such vertices
(a patch of about 470) took the benchmark's weights in ``[0, 1]^3`` within 2 % of that energy from 5 to 9 of 10
(``benchmarks/bench_mixer.py``; 14 to 22 of 24 more random weights) for a step of about 0.65 ms per mix.  On the
bars and the MakeHuman body the excess is spread over the mesh (the 150 vertices of the largest density hold 11-48 %
of it; a trial with 1,000 and 3,000 vertices on the 50k bar recovered 1-10 % of its excess) and the build keeps
none.
"""

import numpy as np
import scipy.sparse as sp

from ...geometry.lengths_angles import lengths_and_angles_jacobian, wrap_angle
from ...geometry.topology import MeshTopology
from ...linalg.sparse_cholesky import SparseCholesky
from .reduced import edge_stencils, element_eval

__all__ = ["LocalCorrection", "hot_vertices", "space_error_density", "HOT_SHARE", "CHORD_STEPS"]

#: Least share of the space's error density (:func:`space_error_density`, the mean over the build's training points
#: of each one's share per vertex) that the local correction's vertices must hold for the build to keep it
#: (:func:`hot_vertices`): with less, the error is not local and the step would cost a mix time for little.
HOT_SHARE = 0.5

#: Steps of the local correction after its Gauss-Newton step that reuse that step's factorization (a chord method:
#: the gradient at the new point, the same matrix), each where it lowers the energy.  The armpit's stretch is
#: nonlinear enough that one step leaves some of it: on the CC0 body (``bench_mixer``) one chord step took the
#: benchmark's weights in ``[0, 1]^3`` within 2 % of converged Gauss-Newton's energy from 9 to 10 of 10 (the last one's
#: ``energy_goal`` 1.058 -> 0.966), for about 0.25 ms per mix; three took it to 0.936 for 0.6 ms.
CHORD_STEPS = 1


def space_error_density(gradients, basis, vertex_scale):
    """Per vertex, the energy a Gauss-Newton step of that vertex alone, outside the space, would gain.

    Parameters
    ----------
    gradients : (3V,) or (3V, S) ndarray
        Gradients ``g`` of the full energy at points of the space (one per column).
    basis : (3V, r) ndarray
        Orthonormal basis ``U`` of the space.
    vertex_scale : (V,) ndarray
        Per vertex, a third of the trace of its 3x3 block of the Gauss-Newton matrix ``H``.

    Returns
    -------
    (V,) or (S, V) ndarray
        ``|g_perp,v|^2 / (2 vertex_scale_v)`` with ``g_perp = (I - U U^T) g``: the decrease ``g^T H^-1 g / 2``
        of one vertex's step with its block taken as ``vertex_scale_v I``.

    Examples
    --------
    >>> import numpy as np
    >>> U = np.eye(6)[:, :3]                      # the space moves the first vertex only
    >>> space_error_density(np.arange(6.0), U, np.ones(2)).tolist()
    [0.0, 25.0]
    """
    g = np.asarray(gradients, float)
    G = g.reshape(len(g), -1)
    Gp = G - basis @ (G.T @ basis).T                  # (G^T U)^T: faster than U^T G in OpenBLAS for a tall G
    d = (Gp.reshape(-1, 3, G.shape[1]) ** 2).sum(axis=1).T / (2.0 * np.maximum(vertex_scale, np.finfo(float).tiny))
    return d[0] if g.ndim == 1 else d


def hot_vertices(densities, max_vertices, share=HOT_SHARE):
    """The ``max_vertices`` vertices of the largest error density, if they hold at least ``share`` of it.

    Parameters
    ----------
    densities : (S, V) array_like
        :func:`space_error_density` at ``S`` points; each is normalized to sum 1 (points where the space is exact
        are left out) and the mean taken.
    max_vertices : int
        How many vertices the correction moves (0: none).
    share : float

    Returns
    -------
    (n,) int64 ndarray
        Sorted vertex indices; empty when the error is not local (the vertices hold less than ``share``).

    Examples
    --------
    >>> import numpy as np
    >>> hot_vertices([[0.05, 0.7, 0.05, 0.2]], 2).tolist()
    [1, 3]
    >>> hot_vertices(np.full((1, 100), 0.01), 10).tolist()      # spread out: no correction
    []
    """
    D = np.atleast_2d(np.asarray(densities, float))
    totals = D.sum(axis=1)
    ok = totals > 0
    if not max_vertices or not ok.any():
        return np.zeros(0, np.int64)
    mean = (D[ok] / totals[ok, None]).mean(axis=0)
    order = np.argsort(-mean, kind="stable")[:int(max_vertices)]
    if mean[order].sum() < share:
        return np.zeros(0, np.int64)
    return np.sort(order).astype(np.int64)


def _patch_faces(faces, inside, n_vertices):
    """Faces with a corner in ``inside`` (V,) bool, grown by the whole fan of every vertex where the patch would not
    be a manifold (more than two boundary edges)."""
    sel = inside[faces].any(axis=1)
    while True:
        pf = faces[sel]
        e = np.sort(np.concatenate([pf[:, [0, 1]], pf[:, [1, 2]], pf[:, [2, 0]]]), axis=1)
        keys, counts = np.unique(e[:, 0] * n_vertices + e[:, 1], return_counts=True)
        b = keys[counts == 1]
        bad = np.bincount(np.concatenate([b // n_vertices, b % n_vertices]), minlength=n_vertices) > 2
        if not bad.any():
            return pf
        sel |= bad[faces].any(axis=1)


class LocalCorrection:
    """One Gauss-Newton step of ``W_q[z(w), Z(X)]`` on the vertices ``hot``, every other vertex held, and
    :data:`CHORD_STEPS` more with its factorization.

    Parameters
    ----------
    topology : MeshTopology
        The mixer's mesh.
    hot : (n,) int array_like
        The vertices that move.
    key_x : (3V,) ndarray
        The basis key in the mixer's canonical coordinates.
    basis : (3V, r) ndarray
        The reduced basis ``U`` (a mix is ``key_x + U q``).
    problem : :class:`.subspace.FullProblem`
        The full energy (targets, weights, floors).
    fixed_dofs : (k,) int array_like
        Canonical coordinates that never move (the context's gauge).
    output_map : (V, 3, 3) ndarray
        Per vertex, the linear map from canonical displacements to the caller's frame and units.

    Notes
    -----
    The step's system is ``2 J_h^T W J_h`` over the free coordinates of ``hot`` (``J_h`` the rows of the lengths
    and angles of the edges whose stencil touches them, on a patch: the faces with a corner in ``hot`` or next to
    it, so every such row has both its faces).  Only those rows are evaluated: the element gradients of their
    edges' stencils (:func:`.reduced.element_eval`), gathered pairwise into the lower CSC values of the block
    (symbolic analysis once).  ``O(n)`` per step, independent of the mesh.
    """

    def __init__(self, topology, hot, key_x, basis, problem, fixed_dofs, output_map):
        V = topology.n_vertices
        hot = np.asarray(hot, np.int64)
        self.hot = hot
        inside = np.zeros(V, bool)
        inside[hot] = True
        faces = topology.faces
        near = inside.copy()
        near[faces[inside[faces].any(axis=1)].ravel()] = True
        pf = _patch_faces(faces, near, V)
        pv = np.unique(pf)
        local = np.full(V, -1, np.int64)
        local[pv] = np.arange(len(pv))
        self.vertices = pv
        tp = MeshTopology.from_faces(local[pf], n_vertices=len(pv))
        Ep = tp.n_edges
        # the patch's edges among the mesh's
        ge = pv[tp.edges]
        gkey = np.minimum(ge[:, 0], ge[:, 1]) * V + np.maximum(ge[:, 0], ge[:, 1])
        mkey = np.minimum(topology.edges[:, 0], topology.edges[:, 1]) * V + np.maximum(topology.edges[:, 0],
                                                                                       topology.edges[:, 1])
        sorter = np.argsort(mkey)
        gedge = sorter[np.searchsorted(mkey, gkey, sorter=sorter)]
        # free coordinates: those of the hot vertices, less the gauge
        fixed = np.zeros(3 * V, bool)
        fixed[np.asarray(fixed_dofs, np.int64)] = True
        dofs = (3 * hot[:, None] + np.arange(3)).ravel()
        keep = ~fixed[dofs]
        free = (3 * local[hot][:, None] + np.arange(3)).ravel()[keep]
        self._free = free
        self._x0 = np.asarray(key_x, float).reshape(V, 3)[pv].ravel()
        self._U = np.ascontiguousarray(np.asarray(basis, float).reshape(V, 3, -1)[pv].reshape(3 * len(pv), -1))
        # the rows whose stencil touches a free coordinate (both faces of such an edge lie in the patch)
        J = lengths_and_angles_jacobian(self._x0.reshape(-1, 3), tp)
        mark = np.zeros(3 * len(pv), bool)
        mark[free] = True
        counts = np.diff(J.indptr)
        hit = np.zeros(2 * Ep, bool)
        nz = counts > 0
        hit[nz] = np.add.reduceat(mark[J.indices].astype(np.int64), J.indptr[:-1][nz]) > 0
        rows = np.flatnonzero(hit)
        self._angle = rows >= Ep
        edge = gedge[rows % Ep]
        grow = np.where(self._angle, topology.n_edges + edge, edge)
        self._z0 = problem.z0[grow]
        self._dz = np.ascontiguousarray(problem.dz[:, grow])
        self._floor = np.where(self._angle, -np.inf, problem.floor[edge])
        self._w = problem.w[grow]
        # the rows' stencils (:func:`.reduced.edge_stencils`, the conventions of :func:`.reduced.element_eval`): each
        # needed edge once; a row reads its value from (l, theta) of those edges at ``_z_of_row``
        edges, where_edge = np.unique(rows % Ep, return_inverse=True)
        n_e = len(edges)
        stencil = edge_stencils(tp)[edges]
        self._stencil = np.ascontiguousarray((3 * stencil[:, :, None] + np.arange(3)).reshape(n_e, 12).T)  # (12, n_e)
        self._z_of_row = np.where(self._angle, n_e, 0) + where_edge
        # free coordinates of every row's stencil entries: a row of an edge's length reads the first 6 entries of the
        # element gradients (``gl``, flat index k n_e + edge), a row of its angle all 12 (``gt``, after ``gl``)
        n = 3 * len(pv)
        where = np.full(n, -1, np.int64)
        where[free] = np.arange(len(free))
        m = len(free)
        src, slot_of, row_of = [], [], []
        for size, offset, sel in ((6, 0, ~self._angle), (12, 6 * n_e, self._angle)):
            rr = np.flatnonzero(sel)
            k = np.arange(size)
            src.append(offset + k[None, :] * n_e + where_edge[rr][:, None])           # (rows, size)
            slot_of.append(where[self._stencil[k][:, where_edge[rr]].T])              # (rows, size)
            row_of.append(np.broadcast_to(rr[:, None], (len(rr), size)))
        # the gradient 2 J^T W r on the free coordinates: entries of free coordinates, scattered by ``bincount``
        grad_src, grad_slot, grad_row = [], [], []
        for a, b, c in zip(src, slot_of, row_of, strict=True):
            ok = b >= 0
            grad_src.append(a[ok])
            grad_slot.append(b[ok])
            grad_row.append(c[ok])
        self._grad_src, self._grad_slot = np.concatenate(grad_src), np.concatenate(grad_slot)
        self._grad_row = np.concatenate(grad_row)
        # the block of 2 J^T W J: every pair (i <= j) of free stencil entries of a row, its weight (doubled when both
        # entries are one coordinate) and its slot in the lower CSC values of the block
        pairs = []
        for a, b, c in zip(src, slot_of, row_of, strict=True):
            ii, jj = np.triu_indices(a.shape[1])
            fa, fb = b[:, ii], b[:, jj]
            keep_pair = (fa >= 0) & (fb >= 0) & (self._w[c[:, 0]] > 0)[:, None]
            same = (fa == fb) & (ii != jj)[None, :]
            pairs.append((a[:, ii][keep_pair], a[:, jj][keep_pair], np.minimum(fa, fb)[keep_pair],
                          np.maximum(fa, fb)[keep_pair],
                          (2.0 * self._w[c[:, 0]][:, None] * np.where(same, 2.0, 1.0))[keep_pair]))
        first, second, lo, hi, weight = (np.concatenate(x) for x in zip(*pairs, strict=True))
        entries = np.unique(hi * m + lo)                                  # column-major, sorted rows: (col lo, row hi)
        rows_b, cols_b = entries // m, entries % m
        block = sp.csc_matrix((np.ones(len(entries)), (rows_b, cols_b)), shape=(m, m))
        self._solver = SparseCholesky(block)
        key = cols_b * m + rows_b
        order = np.argsort(key)
        if not np.array_equal(self._solver.indices, rows_b[order]):
            # the solver's lower CSC order is column-major with sorted rows: the order of ``key``
            raise RuntimeError("local correction: pattern order mismatch")  # pragma: no cover
        self._slots = np.searchsorted(key[order], lo * m + hi)
        self._n_values = len(entries)
        self._first, self._second, self._pair_weight = first, second, weight
        self._map = np.asarray(output_map, float)[hot].reshape(-1, 3, 3)
        self._keep = keep.reshape(-1, 3)

    @property
    def nbytes(self):
        return int(self._U.nbytes + self._dz.nbytes + self._x0.nbytes)

    def _residuals(self, x, target, gradients):
        """Weighted-energy residuals of the rows at the patch coordinates ``x`` ``(3 n_patch,)``, and the element
        gradients ``(18 n_e,)`` (``gl`` then ``gt``, flat) when ``gradients``."""
        l, th, gl, gt = element_eval(x[self._stencil], gradients)
        r = np.concatenate([l, th])[self._z_of_row] - target
        a = self._angle
        r[a] = wrap_angle(r[a])
        return float(np.dot(self._w * r, r)), r, (np.concatenate([gl.ravel(), gt.ravel()]) if gradients else None)

    def _gradient(self, G, r):
        """``2 J^T W r`` on the free coordinates from the element gradients ``G`` and the residuals ``r``."""
        return 2.0 * np.bincount(self._grad_slot, weights=G[self._grad_src] * (self._w * r)[self._grad_row],
                                 minlength=len(self._free))

    def step(self, q, weights, chord_steps=CHORD_STEPS):
        """The correction of the mix ``key_x + U q`` for ``weights``: a Gauss-Newton step on the free coordinates,
        then ``chord_steps`` steps with the same matrix and the gradient where the last one ended (each taken, whole
        or halved, where it lowers the energy; the steps stop at the first that does not).

        Returns ``(dX (n, 3), change)``: the displacement of every vertex of :attr:`hot` in the caller's frame
        and units (zeros when no step lowers the energy) and the change of the full energy (``<= 0``).
        """
        target = self._z0 + np.asarray(weights, float) @ self._dz
        np.maximum(target, self._floor, out=target)
        x = self._x0 + self._U @ q
        e0, r, G = self._residuals(x, target, True)
        values = np.bincount(self._slots, weights=self._pair_weight * G[self._first] * G[self._second],
                             minlength=self._n_values)
        self._solver.factorize(values)
        d = -self._solver.solve(self._gradient(G, r))
        moved, e = np.zeros(len(self._free)), e0
        for k in range(int(chord_steps) + 1):
            last = k == chord_steps
            for t in (1.0, 0.5):
                x1 = x.copy()
                x1[self._free] += t * d
                e1, r1, G1 = self._residuals(x1, target, not last)
                if e1 < e:
                    break
            else:
                break
            x, e, moved = x1, e1, moved + t * d
            if not last:
                d = -self._solver.solve(self._gradient(G1, r1))
        if not e < e0:
            return np.zeros((len(self.hot), 3)), 0.0
        out = np.zeros(3 * len(self.hot))
        out[self._keep.ravel()] = moved
        return np.einsum("vij,vj->vi", self._map, out.reshape(-1, 3)), e - e0
