"""Shared pieces of the energies: argument parsing, sparse block assembly, edge areas, the base class."""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, LengthsAnglesError
from ..geometry.trigonometry import triangle_areas


#: Weight schemes of ``W_q``: (3.20) of [FB11], (3.21) of [HRS+16], all ones.
WEIGHT_SCHEMES = ("frohlich_botsch", "heeren", "uniform")
#: Weight scheme used when none is given: (3.20).  Every default of ``weights`` in lacore is this one.
DEFAULT_WEIGHTS = "frohlich_botsch"
#: ``eta`` of ``W_q`` (3.19) and ``W_TS`` (3.25) when none is given.  Every default of ``bending_weight``
#: in lacore except the shape models' (:data:`lacore.models.settings.DEFAULT_BENDING_WEIGHT`) is this one.
DEFAULT_BENDING_WEIGHT = 1e-3


# --------------------------------------------------------------------------- helpers
def _as_z(z, topology, name):
    """``z`` as float ``(2E,)``; LengthsAnglesError for a wrong shape or non-finite entries."""
    z = np.asarray(z, dtype=float)
    E = topology.n_edges
    if z.shape != (2 * E,):
        raise LengthsAnglesError(f"{name} must have shape ({2 * E},) = 2 x {E} edges of the energy's mesh, "
                                 f"got {z.shape}")
    bad = np.flatnonzero(~np.isfinite(z))
    if bad.size:
        where = [f"{'length' if i < E else 'angle'} of edge {i % E}" for i in bad[:5]]
        raise LengthsAnglesError(f"{name} has NaN or infinite entries ({bad.size}): " + ", ".join(where))
    return z


def _parse_argument(argument):
    """``0``, ``1`` or the mixed block ``(0, 1)`` / ``(1, 0)``."""
    if isinstance(argument, (int, np.integer)) and not isinstance(argument, bool) and argument in (0, 1):
        return int(argument)
    if isinstance(argument, (tuple, list)) and tuple(argument) in ((0, 1), (1, 0)):
        return tuple(int(a) for a in argument)
    raise InputError(f"argument must be 0, 1, (0, 1) or (1, 0), got {argument!r}")


def _scatter(index, values, n):
    """Sum ``values`` into a length-``n`` vector at ``index`` (same shapes)."""
    return np.bincount(np.ravel(index), weights=np.ravel(values), minlength=n)


def _project_psd(H):
    """Clamp the negative eigenvalues of every symmetric block of ``H (n, k, k)`` to 0."""
    if H.shape[0] == 0:
        return H
    lam, V = np.linalg.eigh(H)
    return (V * np.maximum(lam, 0.0)[:, None, :]) @ np.swapaxes(V, 1, 2)


@dataclass
class _Blocks:
    """Per-element dense blocks of a sparse matrix.

    ``vals[n]`` is added at ``(rows[n, i], cols[n, j])``.  ``key`` names the
    (topology-only) index structure; equal keys must mean equal ``rows``/``cols``.
    ``vertices (n, m)`` are the element's vertices (used by the Gauss-Newton
    Hessian in vertex coordinates; ``None`` for mixed blocks).
    """

    key: str
    rows: np.ndarray
    cols: np.ndarray
    vals: np.ndarray
    vertices: np.ndarray = None


def _assemble(topology, key, index_fn, vals, shape):
    """Sum element values into a CSR matrix with a cached symbolic pattern.

    Parameters
    ----------
    topology : MeshTopology
        Owner of the cache.
    key : str
        Unique name of the index structure returned by ``index_fn``.
    index_fn : callable
        ``() -> (rows, cols)`` flat int arrays matching ``vals.ravel()``; called once per topology and key.
    vals : ndarray
    shape : (int, int)
    """
    def compute():
        rows, cols = index_fn()
        flat = np.ravel(rows).astype(np.int64) * shape[1] + np.ravel(cols)
        uniq, inverse = np.unique(flat, return_inverse=True)
        r = uniq // shape[1]
        indptr = np.r_[0, np.cumsum(np.bincount(r, minlength=shape[0]))]
        return {"inverse": inverse.ravel(), "indices": (uniq % shape[1]).astype(np.int32),
                "indptr": indptr.astype(np.int32), "nnz": len(uniq)}
    pat = topology.cache.get((__name__, "assembly_pattern", key), compute)
    data = np.bincount(pat["inverse"], weights=np.ravel(vals), minlength=pat["nnz"])
    return sp.csr_matrix((data, pat["indices"].copy(), pat["indptr"].copy()), shape=shape)


def _assemble_blocks(topology, blocks, shape, prefix):
    """Assemble a list of :class:`_Blocks` into one CSR matrix of ``shape``."""
    key = prefix + "|" + "+".join(b.key for b in blocks)

    def index_fn():
        rows = [np.broadcast_to(b.rows[:, :, None], b.vals.shape).ravel() for b in blocks]
        cols = [np.broadcast_to(b.cols[:, None, :], b.vals.shape).ravel() for b in blocks]
        return np.concatenate(rows), np.concatenate(cols)
    vals = np.concatenate([b.vals.ravel() for b in blocks])
    return _assemble(topology, key, index_fn, vals, shape)


def _interior_quads(topology):
    """``(E_int, 4)`` vertices ``(a, b, left opposite, right opposite)`` of the interior edges."""
    def compute():
        ie = topology.interior_edges
        return np.column_stack([topology.edges[ie], topology.edge_opposite_vertices[ie]])
    return topology.cache.get((__name__, "interior_quads"), compute)


def edge_areas(lengths, topology):
    """Edge-associated areas ``d_e = (a_f + a_f') / 3`` (Def. 1.29), ``(E,)``.

    Boundary edges have one face: ``d_e = a_f / 3``.  Areas by Kahan's formula
    from the per-edge ``lengths (E,)``.
    """
    A = triangle_areas(np.asarray(lengths, float)[topology.face_edges])
    return _scatter(topology.face_edges, np.repeat(A / 3.0, 3), topology.n_edges)


# --------------------------------------------------------------------------- base class
class DeformationEnergy:
    """Common interface of the deformation energies ``W[z_a, z_b]`` on lengths and angles.

    Subclasses implement ``value``, ``gradient`` and ``_hessian_blocks``;
    :meth:`hessian` assembles the blocks.
    """

    def __init__(self, topology):
        self.topology = topology

    @property
    def n_edges(self):
        return self.topology.n_edges

    def _pair(self, z_a, z_b):
        return _as_z(z_a, self.topology, "z_a"), _as_z(z_b, self.topology, "z_b")

    def value(self, z_a, z_b):
        raise NotImplementedError

    def gradient(self, z_a, z_b, argument=1):
        raise NotImplementedError

    def _hessian_blocks(self, z_a, z_b, argument, project):
        raise NotImplementedError

    def hessian(self, z_a, z_b, argument=1, project=False):
        """Hessian ``d^2 W`` with respect to ``argument`` as a ``(2E, 2E)`` CSR matrix.

        Parameters
        ----------
        z_a, z_b : (2E,) array_like
        argument : 0, 1, (0, 1) or (1, 0)
            Differentiated slot(s); ``(0, 1)`` is ``d^2 W / dz_a dz_b`` (rows ``z_a``).
        project : bool
            Clamp the negative eigenvalues of every element block to 0, giving a
            positive semi-definite approximation (only for ``argument`` 0 or 1).
        """
        z_a, z_b = self._pair(z_a, z_b)
        arg = _parse_argument(argument)
        if project and isinstance(arg, tuple):
            raise InputError("project=True needs a symmetric Hessian block (argument 0 or 1)")
        if arg == (1, 0):
            return self.hessian(z_a, z_b, (0, 1)).T.tocsr()
        blocks = self._hessian_blocks(z_a, z_b, arg, project)
        n = 2 * self.n_edges
        return _assemble_blocks(self.topology, blocks, (n, n), f"z{arg}")
