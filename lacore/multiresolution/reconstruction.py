"""Multiresolution reconstruction: solve coarse, prolong, finish fine (thesis 2.3, 4.3.2).

:class:`MultiresolutionReconstruction` is built once for a group of key shapes
(e.g. the shape keys of a mesh):

1. :func:`~.coarsening.coarsen` all keys at once; the coarse keys are the
   fine keys restricted to the kept vertices, their lengths and angles
   ``z_c`` are encoded once.
2. A target is given by its fine ``z*`` and the key weights it blends
   (``(1 - t, t)`` for an in-between, any weights for an extrapolation or a
   spline sample).  The coarse target is the same blend of the coarse keys'
   ``z_c`` (interpolating the coarse shapes' z, as the thesis does in 4.3.2);
   Gauss-Newton solves it on the coarse mesh (warm-started from the last
   coarse solution when given).
3. :class:`~.prolongation.Prolongation` carries the coarse solution to the
   fine mesh, re-inserting the fine detail in local frames (blended with the
   same key weights).
4. A few fine Gauss-Newton iterations finish, with ``fine_solver``:

   ``"exact"`` (default)
       plain Gauss-Newton steps (one numeric factorization each, through
       :func:`lacore.reconstruction.reconstruct`, with its reuse of the
       factorization near convergence).  From the prolonged start a few steps
       reach the full Gauss-Newton energy of smooth blends.
   ``"reference"``
       no fine factorization per target: the fine Gauss-Newton matrix is
       factorized once, at the reference mesh, and every fine step is solved
       by conjugate gradients preconditioned with it, *rotated to the current
       pose*: ``M^-1 = R A_ref^-1 R^T`` with ``R`` the block-diagonal
       per-vertex rotations (polar factor of the one-ring covariance, the
       local step of as-rigid-as-possible) between reference and current
       vertices.  ``J^T W J`` transforms exactly like that under a rigid motion
       (``Z`` is rigid-invariant), so for near-isometric poses the rotated
       reference factor stays a good preconditioner, far better than without
       the rotation.  Good on near-isometric blends, poor where the blend
       bends far from the reference.
   ``"two_level"``
       no fine factorization at all: every fine step is solved by conjugate
       gradients preconditioned with a symmetric two-level cycle (block-Jacobi
       smoothing and the coarse Galerkin correction ``P (P^T A P)^-1 P^T``,
       :mod:`.two_level`); only the coarse matrix (``3 Vc`` unknowns) is
       factorized per step.

   ``benchmarks/bench_multires.py`` compares the three.

Coarse bending weight
---------------------
With the weights (3.20) the membrane part of ``W_q`` sums ``(dl / l)^2`` over
edges and grows with the number of edges for a given smooth strain, while the
bending part (``l^2 / d`` times ``dtheta^2``) does not; ``eta E_c / E`` (coarse
over fine edge count) would make the coarse problem approximate the same
continuous energy.  That does not pay: it brings the prolonged coarse
solution nearer to the fine optimum, but the energy after a few fine
iterations is the same, and on large meshes the softer coarse problem
converges slower and leaves the fine iterations further from the optimum.
The default is therefore the thesis' choice, the same ``eta`` on both levels
(``coarse_bending_weight`` sets another).
"""

import numbers
import time
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, MeshError, as_float_array, check_integer
from ..geometry.lengths_angles import check_z, lengths_and_angles
from ..progress import report
from ..shapes.projection import check_times
from ..reconstruction.checks import apply_checks
from ..reconstruction import (STATUS_MESSAGES, GaussNewtonOptions, ReconstructionContext, ReconstructionResult,
                              ReconstructionSettings, reconstruct)
from ..reconstruction.assembly import dof_ordering
from ..reconstruction.pcg import preconditioned_cg
from ..linalg.sparse_cholesky import SparseCholesky
from ..geometry.topology import MeshTopology, check_vertices
from .coarsening import Coarsening, coarsen
from .prolongation import Prolongation
from .two_level import TwoLevelPreconditioner, interpolation_matrix

__all__ = ["MultiresolutionReconstruction", "vertex_rotations", "FINE_SOLVERS"]

FINE_SOLVERS = ("reference", "exact", "two_level")


def vertex_rotations(reference_vertices, vertices, edges):
    """Per-vertex rotations from a reference to a deformed mesh (ARAP local step).

    ``R_v`` is the rotation factor of the polar decomposition of
    ``sum_j (x_j - x_v)^ref (x_j - x_v)^T`` over the edges at ``v``, i.e. the
    rotation best mapping the reference one-ring edge vectors onto the
    deformed ones (det +1).

    Parameters
    ----------
    reference_vertices, vertices : (V, 3) array_like
    edges : (E, 2) array_like of int

    Returns
    -------
    (V, 3, 3) ndarray
    """
    Xr = check_vertices(reference_vertices, name="reference_vertices")
    X = check_vertices(vertices, len(Xr))
    a, b = np.asarray(edges).T
    V = len(X)
    outer = ((Xr[b] - Xr[a])[:, :, None] * (X[b] - X[a])[:, None, :]).reshape(-1, 9)
    C = np.empty((V, 9))
    ends = np.concatenate([a, b])
    for k in range(9):
        C[:, k] = np.bincount(ends, weights=np.concatenate([outer[:, k], outer[:, k]]), minlength=V)
    U, _, Vt = np.linalg.svd(C.reshape(V, 3, 3))
    flip = np.linalg.det(U) * np.linalg.det(Vt) < 0
    Vt[flip, 2] *= -1.0
    return np.einsum("vji,vkj->vik", Vt, U)  # V U^T


class MultiresolutionReconstruction:
    """Coarse-to-fine reconstruction for the blends of a group of key shapes.

    Parameters
    ----------
    shapes : (N, V, 3) array_like
        Key shapes in dense correspondence (N >= 1).
    topology : MeshTopology
    n_coarse : int, optional
        Coarse vertex count (default ``V // 10``, at least 4).
    reference : int
        Key giving the weights of ``W_q``, the output frame and the reference
        factorization (default 0).
    coarsening : Coarsening, optional
        A precomputed coarsening of these shapes (``n_coarse`` is then unused).
    settings : ReconstructionSettings, optional
        Settings of the fine problem (default the defaults): ``W_q`` with the
        weights (3.20) or (3.21), ``eta``, fixed face, solver and ordering; the
        coarse problem has the same but its own fixed face and ``eta``.
    coarse_bending_weight : float, optional
        ``eta`` of the coarse problem (default the fine one, see the module docstring).
    progress : callable, optional
        ``progress(done, total, message)`` during the set-up (coarsening).

    Attributes
    ----------
    coarsening : Coarsening
    prolongation : Prolongation
    fine_context, coarse_context : ReconstructionContext
    z_keys, z_coarse_keys : (N, 2E), (N, 2E_c) ndarray
    bending_weight, coarse_bending_weight : float

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.multiresolution import MultiresolutionReconstruction
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=12, n_side=1)
    >>> topo = MeshTopology.from_faces(faces)
    >>> mr = MultiresolutionReconstruction([bar_pose(X, 0.5, 0.0), bar_pose(X, 0.0, 0.5)], topo, n_coarse=20)
    >>> res = mr.reconstruct([0.5, 0.5])              # the in-between at t = 1/2
    >>> res.method, res.vertices.shape, res.coarse_vertices.shape, bool(res.energy <= res.prolonged_energy)
    ('multires', (54, 3), (20, 3), True)
    """

    def __init__(self, shapes, topology, n_coarse=None, *, reference=0, coarsening=None, settings=None,
                 coarse_bending_weight=None, progress=None):
        t0 = time.perf_counter()
        if not isinstance(topology, MeshTopology):
            raise TypeError(f"topology must be a MeshTopology, got {type(topology).__name__}")
        S = as_float_array(shapes, "shapes", MeshError)
        if S.ndim == 2:
            S = S[None]
        if S.ndim != 3 or S.shape[1:] != (topology.n_vertices, 3):
            raise MeshError(f"shapes must be (N, {topology.n_vertices}, 3), got {S.shape}")
        settings = settings if settings is not None else ReconstructionSettings()
        if settings.energy != "quadratic" or settings.weights not in ("frohlich_botsch", "heeren"):
            raise InputError(f"multiresolution supports the quadratic energy with weights 'frohlich_botsch' or "
                             f"'heeren', got energy={settings.energy!r}, weights={settings.weights!r}")
        try:
            ok = check_integer(reference, "reference") < len(S)
        except InputError:
            ok = False
        if not ok:
            raise InputError(f"reference must index one of the {len(S)} shapes, got {reference!r}")
        self.shapes = S
        self.topology = topology
        self.reference = int(reference)
        V = topology.n_vertices
        if coarsening is None:
            n_coarse = max(4, V // 10) if n_coarse is None else n_coarse
            coarsening = coarsen(S, topology.faces, n_coarse, progress=progress)
        elif not isinstance(coarsening, Coarsening) or coarsening.n_fine_vertices != V:
            raise InputError("coarsening must be a Coarsening of these shapes' mesh")
        self.coarsening = coarsening
        self.prolongation = Prolongation(coarsening, S)
        ct = coarsening.topology
        self.coarse_topology = ct
        self.coarse_shapes = coarsening.restrict(S)
        self.z_keys = np.stack([lengths_and_angles(X, topology) for X in S])
        self.z_coarse_keys = np.stack([lengths_and_angles(X, ct) for X in self.coarse_shapes])
        self.bending_weight = settings.bending_weight
        coarse = replace(settings, fixed_face=None, fix_triangle_shape=False,
                         bending_weight=settings.bending_weight if coarse_bending_weight is None
                         else coarse_bending_weight)
        self.coarse_bending_weight = coarse.bending_weight
        self.fine_context = ReconstructionContext(topology, S[self.reference], settings)
        self.coarse_context = ReconstructionContext(ct, self.coarse_shapes[self.reference], coarse)
        self._reference_factor = None
        self._reference_canonical = None
        self._two_level = None
        self.setup_seconds = time.perf_counter() - t0

    # ------------------------------------------------------------------ pieces
    def reference_factor(self):
        """Numeric Cholesky factorization of the fine Gauss-Newton matrix at the reference (made once).

        Returns
        -------
        SparseCholesky
        """
        if self._reference_factor is None:
            ctx = self.fine_context
            pat = ctx.pattern
            Xr = ctx.to_canonical(ctx.reference_vertices)
            ordering = None
            if ctx.backend == "cholmod":  # CHOLMOD keeps it or AMD, whichever fills less
                ordering, _ = dof_ordering(self.topology, pat, ctx.reference_vertices, ctx.settings.ordering)
            chol = SparseCholesky(pat["matrix"], backend=ctx.backend, ordering=ordering)
            _, _, matrix = ctx.objective(self.z_keys[self.reference]).linearize(Xr)
            values = matrix()
            ctx.eliminate_fixed(values)
            chol.factorize(values)
            self._reference_factor = chol
            self._reference_canonical = Xr
        return self._reference_factor

    def coarse_target(self, key_weights):
        """``z_c = sum_s w_s z_c^s``: the coarse target of a blend of the keys."""
        return np.asarray(key_weights, float) @ self.z_coarse_keys

    def fine_target(self, key_weights):
        """``z = sum_s w_s z^s``: the fine target of a blend of the keys (linear in z, thesis 4.9)."""
        return np.asarray(key_weights, float) @ self.z_keys

    def _check_weights(self, key_weights):
        w = as_float_array(key_weights, "key_weights").reshape(-1)
        if w.shape != (len(self.shapes),) or not np.all(np.isfinite(w)):
            raise InputError(f"key_weights must be {len(self.shapes)} finite numbers, got {key_weights!r}")
        return w

    # ------------------------------------------------------------------ solve
    def reconstruct(self, key_weights, z_target=None, *, initial_coarse=None, fine_iterations=3,
                    fine_solver="exact", pcg_rtol=1e-3, pcg_maxiter=20, ftol=1e-6, smoothing_steps=2,
                    coarse_options=None):
        """Reconstruct the blend of the keys with weights ``key_weights``.

        Parameters
        ----------
        key_weights : (N,) array_like
            Blend of the keys (e.g. ``(1 - t, t)``); gives the coarse target and
            the detail blended by the prolongation.
        z_target : (2E,) array_like, optional
            Fine target (default ``key_weights @ z_keys``, the linear blend in
            z).  Any target near that blend works (e.g. a spline sample).
        initial_coarse : (Vc, 3) array_like, optional
            Start of the coarse Gauss-Newton (e.g. the previous frame's
            ``result.coarse_vertices``); default the coarse key of largest
            weight (so a key itself is reproduced at once, and a rolled plate's
            in-between starts from the nearer roll).
        fine_iterations : int
            At most this many fine Gauss-Newton iterations (0: prolongation only).
        fine_solver : {"exact", "reference", "two_level"}
            See the module docstring.
        pcg_rtol, pcg_maxiter : float, int
            Conjugate gradients of ``"reference"`` and ``"two_level"`` steps.
        smoothing_steps : int
            Block-Jacobi sweeps before and after the coarse correction of ``"two_level"``.
        ftol : float
            Stop the fine iterations when one decreases the energy by less than
            ``ftol`` times its value.
        coarse_options : GaussNewtonOptions, optional
            Options of the coarse Gauss-Newton solve (default: the defaults, converge).

        Returns
        -------
        ReconstructionResult
            ``method="multires"``; ``vertices`` in the reference's frame;
            ``timings`` has ``coarse``, ``prolongation``, ``fine``,
            ``reference_factorization`` and ``total``; the extra attributes
            ``coarse_vertices`` (Vc, 3) and ``prolonged_energy`` are set.
            ``success`` as for every reconstruction (:mod:`lacore.reconstruction.checks`): converged, or, with
            ``fine_solver="exact"``, the fine iterations spent (status 6, a budgeted approximation as the hybrid
            method's).  The conjugate-gradient solvers' spent budget is not success (status 0): their truncated
            steps can stop at several times the minimum's energy.
        """
        t_start = time.perf_counter()
        if not isinstance(fine_solver, str) or fine_solver not in FINE_SOLVERS:
            raise InputError(f"unknown fine_solver {fine_solver!r}; use one of {', '.join(FINE_SOLVERS)}")
        fine_iterations = check_integer(fine_iterations, "fine_iterations", 0)
        pcg_maxiter = check_integer(pcg_maxiter, "pcg_maxiter", 1)
        smoothing_steps = check_integer(smoothing_steps, "smoothing_steps", 1)
        if not (isinstance(pcg_rtol, numbers.Real) and not isinstance(pcg_rtol, bool) and 0.0 < pcg_rtol < 1.0):
            raise InputError(f"pcg_rtol must be a number in (0, 1), got {pcg_rtol!r}")
        if not (isinstance(ftol, numbers.Real) and not isinstance(ftol, bool) and 0.0 <= ftol < np.inf):
            raise InputError(f"ftol must be a finite number >= 0, got {ftol!r}")
        w = self._check_weights(key_weights)
        z = self.fine_target(w) if z_target is None else check_z(z_target, self.topology, name="target z")
        timings = {}
        if initial_coarse is None:
            initial_coarse = self.coarse_shapes[int(np.argmax(w))]
        t0 = time.perf_counter()
        coarse = reconstruct(self.coarse_target(w), self.coarse_topology, None, method="gn",
                             context=self.coarse_context, initial_vertices=initial_coarse, options=coarse_options)
        timings["coarse"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        ctx = self.fine_context
        X = ctx.align(self.prolongation(coarse.vertices, w))
        timings["prolongation"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        timings["reference_factorization"] = 0.0
        if fine_iterations and fine_solver == "exact":
            res = reconstruct(z, self.topology, None, method="gn", context=ctx, initial_vertices=X,
                              options=GaussNewtonOptions(max_iterations=int(fine_iterations), ftol=ftol))
            res.method = "multires"
            hist, factorizations, pcg_its, status = res.energy_history, res.factorizations, res.pcg_iterations, \
                res.status
            X, energy, iterations = res.vertices, res.energy, res.iterations
        else:
            if fine_iterations and fine_solver == "reference" and self._reference_factor is None:
                t1 = time.perf_counter()
                self.reference_factor()
                timings["reference_factorization"] = time.perf_counter() - t1
            X, energy, hist, pcg_its, status = self._fine_pcg(z, X, int(fine_iterations), pcg_rtol, pcg_maxiter,
                                                              ftol, fine_solver, smoothing_steps)
            iterations, factorizations = len(hist) - 1, 0
        timings["fine"] = time.perf_counter() - t0 - timings["reference_factorization"]
        timings["total"] = time.perf_counter() - t_start
        message = STATUS_MESSAGES[status]
        if status == 0 and fine_iterations and fine_solver == "exact":
            # the fine budget spent: exact Gauss-Newton steps, an approximation as the hybrid method's
            status, message = 6, f"the {int(fine_iterations)} fine iterations are done"
        elif status == 0 and fine_iterations:
            # conjugate-gradient steps with a spent budget end anywhere from 1 to hundreds of times the minimum
            message = (f"the {int(fine_iterations)} fine iterations of the {fine_solver!r} solver are done, not "
                       "converged (its steps are approximate); use fine_solver='exact' for a converged result")
        result = ReconstructionResult(vertices=X, success=False, status=status,
                                      message=message, method="multires", iterations=iterations,
                                      energy=float(energy), energy_name="quadratic", initial_energy=hist[0],
                                      energy_history=list(hist), factorizations=factorizations,
                                      pcg_iterations=list(pcg_its), timings=timings, fixed_face=ctx.fixed_face,
                                      backend=ctx.backend)
        result = apply_checks(result, z, self.topology, minimizer=True)   # success as for every reconstruction
        result.coarse_vertices = coarse.vertices
        result.coarse_iterations = coarse.iterations
        result.prolonged_energy = hist[0]
        return result

    def two_level_preconditioner(self, smoothing_steps=2):
        """The :class:`~.two_level.TwoLevelPreconditioner` of the fine system (interpolation built once)."""
        if self._two_level is None:
            Ps = interpolation_matrix(self.coarsening, self.prolongation._level_data)
            self._two_level = TwoLevelPreconditioner(Ps, self.fine_context.fixed_dofs,
                                                     backend=self.fine_context.backend)
        self._two_level.smoothing_steps = int(smoothing_steps)
        return self._two_level

    def fine_matrix(self, matrix):
        """The full symmetric fine Gauss-Newton matrix (CSR, fixed rows and columns = identity)."""
        ctx = self.fine_context
        pat = ctx.pattern
        values = matrix()
        ctx.eliminate_fixed(values)
        L = sp.csc_matrix((values, pat["indices"], pat["indptr"]), shape=(pat["n"], pat["n"]))
        return (L + L.T - sp.diags(L.diagonal())).tocsr()

    def _fine_pcg(self, z, X, iterations, rtol, maxiter, ftol, fine_solver="reference", smoothing_steps=2):
        """Fine Gauss-Newton steps by PCG (rotated reference factorization or two-level); Armijo line search."""
        ctx = self.fine_context
        objective = ctx.objective(z)
        fixed = ctx.fixed_dofs
        Xc = ctx.to_canonical(X)
        edges = self.topology.edges
        energy = objective.energy(Xc)
        hist, pcg_its = [energy], []
        status = 0
        atol = objective.noise_floor()
        for _ in range(iterations):
            if energy <= atol:
                status = 1
                break
            energy, grad, matrix = objective.linearize(Xc)
            grad[fixed] = 0.0
            if fine_solver == "two_level":
                A = self.fine_matrix(matrix)
                precondition = self.two_level_preconditioner(smoothing_steps)
                precondition.update(A)
                matvec = A.dot
            else:
                R = vertex_rotations(self._reference_canonical, Xc, edges)
                factor = self._reference_factor
                matvec = matrix.dot

                def precondition(r, R=R, factor=factor):
                    y = np.einsum("vji,vj->vi", R, r.reshape(-1, 3)).ravel()  # R^T r
                    y[fixed] = 0.0
                    y = factor.solve(y)
                    y[fixed] = 0.0
                    return np.einsum("vij,vj->vi", R, y.reshape(-1, 3)).ravel()

            d, n_cg, _ = preconditioned_cg(matvec, -grad, precondition, fixed, rtol, maxiter)
            pcg_its.append(n_cg)
            slope = float(grad @ d)
            if not slope < 0:
                status = -1
                break
            D = d.reshape(-1, 3)
            t = 1.0
            while True:  # Armijo backtracking from the full step
                trial = objective.energy(Xc + t * D)
                if trial <= energy + 1e-4 * t * slope:
                    break
                t *= 0.5
                if t < 1e-6:
                    trial = None
                    break
            if trial is None:
                status = -1
                break
            Xc = Xc + t * D
            decrease = energy - trial
            energy = trial
            hist.append(energy)
            if decrease <= ftol * energy:
                status = 2
                break
        return ctx.from_canonical(Xc), energy, hist, pcg_its, status

    def interpolate(self, factors, keys=(0, 1), *, progress=None, **options):
        """In-betweens ``z(t) = (1 - t) z_a + t z_b`` of two keys, each coarse solve warm-started by the last.

        Parameters
        ----------
        factors : sequence of float
            ``t`` values (outside [0, 1] extrapolates).
        keys : (int, int)
            Indices of the two keys ``a, b``.
        progress : callable, optional
            ``progress(done, total, message)`` after each in-between.
        **options
            Passed to :meth:`reconstruct`.

        Returns
        -------
        list of ReconstructionResult
        """
        N = len(self.shapes)
        try:
            a, b = (check_integer(k, "keys") for k in keys)
            ok = a < N and b < N
        except (InputError, TypeError, ValueError):  # not a pair of indices
            ok = False
        if not ok:
            raise InputError(f"keys must be two indices of the {N} shapes, got {keys!r}")
        out = []
        previous = None
        ts = check_times(factors, "factors").tolist()
        for i, t in enumerate(ts):
            w = np.zeros(N)
            w[a] += 1.0 - t
            w[b] += t
            res = self.reconstruct(w, initial_coarse=previous, **options)
            previous = res.coarse_vertices
            out.append(res)
            report(progress, i + 1, len(ts), f"in-between {t:g}")
        return out
