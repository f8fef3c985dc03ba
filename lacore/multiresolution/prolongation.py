"""Prolongation from a coarse mesh of :func:`~.coarsening.coarsen` to the fine mesh.

The half-edge collapses are undone in reverse order.  A removed vertex ``u``
is re-inserted in a local frame of its one-ring at the time of its collapse
(all ring vertices exist again by then): the ring's centre
``c = mean(p, q)`` over the ring's corner pairs ``(p, q)``, its vector area
``n = sum (p - c) x (q - c)`` (normalized) and the direction to the vertex
``v`` that absorbed ``u``, ``t1 = normalize((v - c) - ((v - c).n) n)``,
``t2 = n x t1``.  Its coordinates ``alpha = (u - c) . (t1, t2, n)`` are taken
from the key shapes (one set per shape; in-betweens blend them with the same
weights as the shapes, e.g. ``(1 - t, t)``) and put into the frame of the
coarse solution.  The frame moves with the ring, so the prolongation is

* exact for every key shape: ``prolong(restrict(X_s), weights=e_s) == X_s``;
* equivariant under rigid motions (and exact for rigidly moved key shapes);
* local and detail preserving: this is the deformation transfer of the fine
  detail of [BSPG06] (thesis 2.3) in its simplest form.

It is not exact for an arbitrary admissible fine shape whose detail is no
blend of the keys' detail; a few fine Gauss-Newton iterations
(:mod:`.reconstruction`) then finish the job.

Vertices re-inserted independently of each other are processed together
(levels: a vertex's level is one more than the highest level of its ring
vertices, coarse vertices have level 0), so the work is a few dozen
vectorized steps.

A prolongation is stored as its coarsening record plus the local coordinates
``alpha`` (:meth:`Prolongation.to_arrays`, :meth:`Prolongation.save`): loaded,
it prolongs exactly as the original, on any machine, without the key shapes.
"""

import os

import numpy as np

from ..errors import InputError, MeshError, as_float_array, format_indices
from ..geometry.lengths_angles import cross_rows as _cross
from ..geometry.lengths_angles import dot_rows as _dot
from ..io.atomic import save_npz_atomic
from ..io.npz import open_npz
from .coarsening import Coarsening

__all__ = ["Prolongation", "POSE_BATCH"]

#: Poses prolonged together by :meth:`Prolongation.__call__` (bounds the scratch arrays: about
#: ``POSE_BATCH`` times 50 doubles per fine vertex).
POSE_BATCH = 16


class Prolongation:
    """Coarse-to-fine prolongation by local ring frames (see the module docstring).

    Parameters
    ----------
    coarsening : Coarsening
    shapes : (N, V, 3) or (V, 3) array_like
        Key shapes whose detail is transferred (usually the shapes given to
        :func:`~.coarsening.coarsen`).

    Attributes
    ----------
    levels : list of (k,) int64 arrays
        Collapse indices re-inserted together, in order.
    alpha : (N, K, 3) ndarray
        Local coordinates of every removed vertex in every shape.
    """

    def __init__(self, coarsening, shapes):
        c = coarsening
        if not isinstance(c, Coarsening):
            raise InputError(f"coarsening must be a Coarsening (lacore.multiresolution.coarsen), got "
                             f"{type(c).__name__}")
        P = as_float_array(shapes, "shapes", MeshError)
        if P.ndim == 2:
            P = P[None]
        if P.ndim != 3 or P.shape[1:] != (c.n_fine_vertices, 3):
            raise MeshError(f"shapes must be (N, {c.n_fine_vertices}, 3), got {P.shape}")
        if not np.all(np.isfinite(P)):
            bad = np.flatnonzero(~np.isfinite(P).all(axis=(0, 2)))
            raise MeshError(f"shapes have non-finite coordinates at vertices {format_indices(bad)}")
        self._set_levels(c)
        K = len(c.collapse_sources)
        self.alpha = np.zeros((len(P), K, 3))
        for s in range(0, len(P), POSE_BATCH):  # the shapes of a batch together (coordinates first)
            Ps = np.ascontiguousarray(P[s:s + POSE_BATCH].transpose(2, 1, 0))  # (3, V, n)
            for ks, u, v, pr, seg, sizes in self._level_data:
                centre, t1, t2, n = self._frames(Ps, v, pr, seg, sizes)
                d = Ps[:, u] - centre
                local = np.stack([_dot(t1, d), _dot(t2, d), _dot(n, d)], axis=-1)  # (k, n, 3)
                self.alpha[s:s + POSE_BATCH, ks] = local.swapaxes(0, 1)

    @classmethod
    def from_coordinates(cls, coarsening, alpha):
        """A prolongation from stored local coordinates ``alpha`` ``(N, K, 3)`` (no key shapes needed)."""
        alpha = np.asarray(alpha)
        K = len(coarsening.collapse_sources)
        if alpha.dtype.kind != "f" or alpha.ndim != 3 or alpha.shape[0] < 1 or alpha.shape[1:] != (K, 3):
            raise InputError(f"local coordinates must be (N, {K}, 3) floats, got {alpha.dtype} {alpha.shape}")
        if not np.all(np.isfinite(alpha)):
            raise InputError("local coordinates must be finite")
        out = cls.__new__(cls)
        out._set_levels(coarsening)
        out.alpha = alpha.astype(float)
        return out

    def to_arrays(self, prefix=""):
        """The coarsening record (:meth:`Coarsening.to_arrays`) plus ``prolongation_alpha`` ``(N, K, 3)``.

        ``prefix`` is prepended to every key, as for :meth:`Coarsening.to_arrays`.
        """
        out = self.coarsening.to_arrays(prefix)
        out[prefix + "prolongation_alpha"] = self.alpha
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix="", source="prolongation record"):
        """A :class:`Prolongation` from the arrays of :meth:`to_arrays`; InputError naming ``source`` if invalid."""
        c = Coarsening.from_arrays(arrays, prefix, source)
        key = prefix + "prolongation_alpha"
        if key not in arrays:
            raise InputError(f"{source}: a coarsening record without prolongation ('{key}' is missing)")
        try:
            return cls.from_coordinates(c, np.asarray(arrays[key]))
        except InputError as exc:
            raise InputError(f"{source}: '{key}': {exc}") from None

    def save(self, path):
        """Write :meth:`to_arrays` to a compressed ``.npz`` file, atomically; returns the path written."""
        return save_npz_atomic(path, compressed=True, **self.to_arrays())

    @classmethod
    def load(cls, path):
        """Read a file written by :meth:`save`."""
        with open_npz(path, "prolongation record") as npz:
            return cls.from_arrays(npz, source=os.fspath(path))

    def _set_levels(self, c):
        """Insertion levels and the ring data of every level (integers only)."""
        self.coarsening = c
        cached = getattr(c, "_prolongation_levels", None)  # integers that depend on the coarsening only
        if cached is not None:
            self.levels, self._level_data = cached
            return
        K = len(c.collapse_sources)
        # insertion levels, by one pass over the collapses in reverse order
        level = np.zeros(c.n_fine_vertices, np.int64)
        pair_max = np.zeros(K, np.int64)
        src = c.collapse_sources.tolist()
        off = c.ring_offsets.tolist()
        pairs = c.ring_pairs
        lv = level.tolist()
        ring_vertices = pairs.tolist()
        for k in range(K - 1, -1, -1):
            m = 0
            for p, q in ring_vertices[off[k]:off[k + 1]]:
                m = max(m, lv[p], lv[q])
            lv[src[k]] = m + 1
            pair_max[k] = m + 1
        order = np.argsort(pair_max, kind="stable")
        bounds = np.flatnonzero(np.diff(pair_max[order])) + 1
        self.levels = np.split(order, bounds) if K else []
        # per level: ring pairs gathered once
        self._level_data = []
        for ks in self.levels:
            sizes = c.ring_offsets[ks + 1] - c.ring_offsets[ks]
            idx = np.repeat(c.ring_offsets[ks] - np.r_[0, np.cumsum(sizes)[:-1]], sizes) + np.arange(sizes.sum())
            seg = np.r_[0, np.cumsum(sizes)]
            self._level_data.append((ks, c.collapse_sources[ks], c.collapse_targets[ks], pairs[idx], seg, sizes))
        c._prolongation_levels = (self.levels, self._level_data)

    @classmethod
    def from_local_coordinates(cls, coarsening, alpha):
        """A prolongation from stored local coordinates ``alpha (N, K, 3)`` (see :attr:`alpha`), no key shapes."""
        c = coarsening
        alpha = np.asarray(alpha, dtype=float)
        K = len(c.collapse_sources)
        if alpha.ndim != 3 or alpha.shape[1:] != (K, 3):
            raise MeshError(f"local coordinates must be (N, {K}, 3) for {K} collapses, got {alpha.shape}")
        if not np.all(np.isfinite(alpha)):
            raise MeshError("local coordinates must be finite")
        obj = cls.__new__(cls)
        obj._set_levels(c)
        obj.alpha = alpha
        return obj

    @staticmethod
    def _frames(X, v, pr, seg, sizes):
        """Centres and frame rows ``t1, t2, n`` of the rings of one level, each ``(3, k)`` (``(3, k, T)``).

        ``X`` is ``(3, V)`` or, for ``T`` poses at once, ``(3, V, T)``: coordinates first, so every
        gather and product runs over contiguous rows.
        """
        Pp, Pq = np.take(X, pr[:, 0], axis=1), np.take(X, pr[:, 1], axis=1)
        centre = np.add.reduceat(Pp + Pq, seg[:-1], axis=1) / (2.0 * sizes).reshape((-1,) + (1,) * (X.ndim - 2))
        cr = np.repeat(centre, sizes, axis=1)
        n = np.add.reduceat(_cross(Pp - cr, Pq - cr), seg[:-1], axis=1)
        n /= np.maximum(np.sqrt(_dot(n, n)), 1e-300)
        t = np.take(X, v, axis=1) - centre
        t -= _dot(t, n) * n
        t /= np.maximum(np.sqrt(_dot(t, t)), 1e-300)
        return centre, t, _cross(n, t), n

    def __call__(self, coarse_vertices, weights=None):
        """Fine vertices from coarse ones, one pose or ``T`` poses at once.

        Parameters
        ----------
        coarse_vertices : (Vc, 3) or (T, Vc, 3) array_like
        weights : (N,) or (T, N) array_like, optional
            Blend of the key shapes' local coordinates (default: the first
            shape only, ``(1, 0, ..., 0)``), one row per pose or one for all.
            They need not sum to 1 (an extrapolation ``(-0.5, 1.5)`` is fine).

        Returns
        -------
        (V, 3) or (T, V, 3) ndarray
            Poses are prolonged :data:`POSE_BATCH` at a time, each level's gathers
            and products over all of them (several times cheaper per pose than
            one at a time); every pose comes out as alone.

        Examples
        --------
        Two key shapes (the straight and a bent bar); a batch of two poses gives what they
        give one at a time:

        >>> import numpy as np
        >>> from lacore.multiresolution import Prolongation, coarsen
        >>> from lacore.samples.bar import bar_mesh, bar_pose
        >>> X0, F = bar_mesh()
        >>> keys = np.stack([X0, bar_pose(X0, 0.8, 0.3)])
        >>> c = coarsen(keys, F, len(X0) // 3)
        >>> P = Prolongation(c, keys)
        >>> coarse = keys[:, c.vertex_indices]
        >>> fine = P(coarse, [[1.0, 0.0], [0.0, 1.0]])
        >>> fine.shape == (2, len(X0), 3), bool(np.allclose(fine[1], P(coarse[1], [0.0, 1.0])))
        (True, True)
        >>> bool(np.allclose(fine, keys))          # exact for the key shapes
        True
        """
        c = self.coarsening
        Xc = as_float_array(coarse_vertices, "coarse vertices", MeshError)
        single = Xc.ndim == 2
        Xb = Xc[None] if single else Xc
        if Xb.ndim != 3 or Xb.shape[1:] != (c.n_vertices, 3):
            raise MeshError(f"coarse vertices must be ({c.n_vertices}, 3) or (T, {c.n_vertices}, 3), got {Xc.shape}")
        if not np.all(np.isfinite(Xb)):
            bad = np.flatnonzero(~np.isfinite(Xb).all(axis=(0, 2)))
            raise MeshError(f"coarse vertices have NaN or infinite coordinates at vertices {format_indices(bad)}")
        N, K = self.alpha.shape[:2]
        T = len(Xb)
        if weights is None:
            w = np.zeros((1, N))
            w[0, 0] = 1.0
        else:
            w = as_float_array(weights, "weights")
            if w.ndim == 1 and w.shape == (N,):
                w = w[None]
            elif not (w.ndim == 2 and w.shape[1] == N and len(w) in (1, T)) or (single and w.shape[0] != 1):
                raise InputError(f"weights must have shape ({N},)" + ("" if single else f" or ({T}, {N})")
                                 + f", got {w.shape}")
            if not np.all(np.isfinite(w)):
                raise InputError(f"weights must be finite, got {w.tolist() if w.size <= 8 else 'NaN or inf entries'}")
        w = np.broadcast_to(w, (T, N))
        out = np.empty((T, c.n_fine_vertices, 3))
        for s in range(0, T, POSE_BATCH):
            Xs, ws = Xb[s:s + POSE_BATCH], w[s:s + POSE_BATCH]
            n = len(Xs)
            alpha = (ws @ self.alpha.reshape(N, 3 * K)).reshape(n, K, 3).transpose(2, 1, 0)   # (3, K, n)
            X = np.zeros((3, c.n_fine_vertices, n))                                           # coordinates first
            X[:, c.vertex_indices] = Xs.transpose(2, 1, 0)
            for ks, u, v, pr, seg, sizes in self._level_data:
                centre, t1, t2, nrm = self._frames(X, v, pr, seg, sizes)
                a = alpha[:, ks]
                X[:, u] = centre + t1 * a[0] + t2 * a[1] + nrm * a[2]
            out[s:s + n] = X.transpose(2, 1, 0)
        return out[0] if single else out
