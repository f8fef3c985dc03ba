"""The shared set-up of reconstructions: :class:`ReconstructionContext` and :func:`get_context` (thesis 3.4.1).

Rigid motions
-------------
``Z`` is invariant under rigid motions, so ``J^T W J`` has a 6-dimensional
kernel per connected component.  The motion is fixed by the 3-2-1 rule on one
triangle per component (``fixed_face``, vertices ``a, b, c``): in the
triangle's frame (origin ``X_a``, x axis along ``X_b - X_a``, z axis along its
normal) the coordinates ``a.xyz``, ``b.yz`` and ``c.z`` are held at 0.  These
six constraints only remove the rigid motions, so the minimizer is exactly the
one of (3.26); the triangle itself may change shape.  With
``fix_triangle_shape=True`` all nine coordinates of the triangle are held (the
practice of the thesis' experiments, section 3.4.3): its shape then stays that
of the starting mesh, which biases the result when the target changes that
triangle.

The output is expressed in the frame the *reference* mesh gives the fixed
triangle: ``X_a`` is exactly the reference position, ``X_b`` lies on the
reference ray ``a -> b`` and ``X_c`` in the reference plane of the triangle, on
the same side (an undeformed triangle sits exactly where the reference has it,
up to round-off).  The starting mesh may be placed anywhere.

The default fixed face of a component is its central, well-shaped face on the
reference mesh (:func:`lacore.reconstruction.spanning_trees.default_root_faces`),
the same face that roots the frame-based reconstructions; choosing it on the
reference (not on ``z*``) keeps all frames of an animation in one placement.

Units
-----
A context computes in units of ``2^k`` of the caller's length unit
(:attr:`ReconstructionContext.scale_exponent`, ``k = 0`` unless the reference's
coordinates lie outside ``2^-SAFE_EXPONENT .. 2^SAFE_EXPONENT``, about
1e-30 .. 1e30, :func:`lacore.geometry.lengths_angles.safe_scale_exponent`):
canonical coordinates, the objective's target lengths and the Gauss-Newton
matrix are those of the mesh scaled by ``2^-k``, which is exact.  Everything
the context takes and returns -- vertices, targets, energies -- is in the
caller's units, so a mesh and its scaled copy give the same result up to the
scale on every path that uses a context (:func:`lacore.reconstruction.reconstruct`,
:func:`lacore.shapes.interpolation.interpolate`, the CLI, the add-on).  The
weights (3.20) and ``W_q`` with them are scale-free; for the weights (3.21) and
``"uniform"`` and the thin shells energy, whose membrane term has units of
length squared, the context multiplies that term by ``4^k`` so that the energy
(and its minimizer) is the one in the caller's units.

Target scale
------------
The weights (3.20) measure a length's residual relative to the reference's
length, and its bending terms are dimensionless: ``W_q`` weighs stretching
against bending as designed for targets of the reference's size.  A target
``rho`` times larger (geometric mean of its lengths over the reference's) weighs
stretching ``rho^2`` times more: from ``rho = 3`` on, Gauss-Newton on
integrable targets of the deformed spheres ended in crumpled local minima.
So for weights (3.20) and a target outside ``1 / TARGET_SCALE_BAND ..
TARGET_SCALE_BAND`` times the reference's size, the objective divides the
length weights by ``s^2``, ``s = rho / TARGET_SCALE_BAND`` (or ``rho
TARGET_SCALE_BAND`` below the band), and the stopping rules use ``s`` times
the reference's size (:meth:`ReconstructionContext.target_scale`); Gauss-Newton's
default start, the reference, is scaled by ``s`` about its centroid.  Energies
are then those weights' ``W_q``; targets within the band are unaffected.

Factorization
-------------
The symbolic Cholesky factorization of the Gauss-Newton pattern
(:class:`lacore.linalg.sparse_cholesky.SparseCholesky`, CHOLMOD when available) is made
once per context.  Its fill-reducing ordering is the better (fewer nonzeros) of
CHOLMOD's AMD and :func:`lacore.linalg.sparse_cholesky.vertex_ordering` (METIS nested
dissection when pymetis is importable, else a geometric nested dissection of
the reference mesh); from :data:`~lacore.linalg.sparse_cholesky.GIVEN_ONLY_SIZE`
unknowns up METIS' ordering is taken without analysing AMD.
"""

from collections import OrderedDict

import numpy as np

from ..errors import InputError, MeshError, format_indices
from ..geometry.lengths_angles import SAFE_EXPONENT, lengths_and_angles, safe_scale_exponent
from ..linalg.sparse_cholesky import GIVEN_ONLY_SIZE, SparseCholesky, default_backend
from ..geometry.topology import check_vertices
from .assembly import dof_ordering, gauss_newton_pattern
from .objectives import QuadraticObjective, ShellsObjective, reference_weights
from .settings import split_options
from .spanning_trees import default_root_faces

__all__ = ["ReconstructionContext", "get_context", "triangle_frame", "CONTEXTS_PER_TOPOLOGY"]

#: A unit-dependent energy in a scaled context is multiplied by ``4^k`` (module docstring, "Units"): at most
#: ``2^1000``, leaving float64's exponent range (``2^+-1022``) room for the energy's own magnitude.
_MAX_ENERGY_EXPONENT = 1000


def triangle_frame(vertices, face):
    """3-2-1 frame of a triangle: origin ``X_a`` and rotation ``Q`` (rows: x, y, z axes).

    Parameters
    ----------
    vertices : (V, 3) ndarray
    face : (3,) int
        Vertex indices ``a, b, c`` (counter-clockwise).

    Returns
    -------
    origin : (3,) ndarray
    Q : (3, 3) ndarray
        Orthonormal rows ``e1 = (X_b - X_a) / |X_b - X_a|``, ``e2 = n x e1`` and
        the unit normal ``n``.  Canonical coordinates are ``(X - origin) @ Q.T``.

    Raises
    ------
    MeshError
        If the triangle is degenerate.
    """
    a, b, c = vertices[face[0]], vertices[face[1]], vertices[face[2]]
    e1 = b - a
    n = np.cross(e1, c - a)
    ln, l1 = np.linalg.norm(n), np.linalg.norm(e1)
    if not (ln > 0 and l1 > 0 and np.isfinite(ln)):
        raise MeshError(f"the fixed face {tuple(int(v) for v in face)} is degenerate (zero area)")
    e1 = e1 / l1
    n = n / ln
    return a.copy(), np.stack([e1, np.cross(n, e1), n])


def _fixed_faces(topology, reference_vertices, fixed_face):
    """One fixed face per connected component: ``fixed_face`` (int or sequence) completed by the defaults."""

    n_comp, labels = topology.face_components()
    faces = np.asarray(default_root_faces(topology, vertices=reference_vertices), np.int64)
    if fixed_face is None:
        return faces
    given = np.atleast_1d(np.asarray(fixed_face))
    if given.ndim != 1 or not np.issubdtype(given.dtype, np.integer):
        raise MeshError(f"fixed_face must be a face index (or one per component), got {fixed_face!r}")
    bad = given[(given < 0) | (given >= topology.n_faces)]
    if bad.size:
        raise MeshError(f"fixed_face {format_indices(bad)} out of range: the mesh has {topology.n_faces} faces")
    comp = labels[given]
    if len(np.unique(comp)) != len(comp):
        raise MeshError(f"fixed faces {format_indices(given)} include two faces of the same component")
    faces[comp] = given
    return faces


def _gauge_dofs(faces, fix_triangle_shape):
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    dofs = [3 * a, 3 * a + 1, 3 * a + 2, 3 * b + 1, 3 * b + 2, 3 * c + 2]
    if fix_triangle_shape:
        dofs += [3 * b, 3 * c, 3 * c + 1]
    return np.unique(np.concatenate(dofs))


class ReconstructionContext:
    """Everything about a reconstruction set-up that does not depend on the target.

    Holds the residual weights (from the reference mesh), the fixed faces and
    their reference frames, the Gauss-Newton sparsity pattern and the sparse
    Cholesky object with its symbolic (and last numeric) factorization.
    (Spanning trees are cached on the topology (BFS) or passed as ``tree=`` to
    :func:`lacore.reconstruction.reconstruct`, e.g. a preassembled tree.)  Pass one context to
    many :func:`lacore.reconstruction.reconstruct` calls (e.g. the frames of an
    interpolation, each warm-started from the previous one) to share all of it.
    :func:`get_context` keeps the last few contexts per topology, so repeated
    calls with identical settings share them without passing one explicitly.

    A context holds one numeric factorization and is not thread-safe: use one
    context per thread.

    Parameters
    ----------
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh: source of the weights (3.20)/(3.21), the default
        starting point and the output frame.
    settings : ReconstructionSettings, optional
        Energy, weights, bending weight, fixed face, ``fix_triangle_shape``,
        solver backend (default: the defaults of :class:`ReconstructionSettings`).
    **kwargs
        Fields of :class:`ReconstructionSettings` as keywords (override ``settings``).

    Raises
    ------
    MeshError
        For reference vertices that do not fit the topology, a bad or degenerate
        fixed face.
    InputError
        Invalid settings (unknown energy, weights or solver, negative bending weight);
        a unit-dependent energy (thin shells, weights (3.21) or uniform) at coordinates
        so large or small that its value does not fit float64 (module docstring, "Units").
    """

    def __init__(self, topology, reference_vertices, settings=None, **kwargs):
        settings = split_options(kwargs, settings, caller="ReconstructionContext", accept=("settings",)).settings
        self.settings = settings
        backend = default_backend() if settings.solver is None else settings.solver
        self.topology = topology
        X = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices").copy()
        X.setflags(write=False)
        self.reference_vertices = X
        #: the context computes in units of ``2^scale_exponent`` (module docstring, "Units")
        self.scale_exponent = safe_scale_exponent(X)
        Xi = self.internal_vertices(X)
        Xi.setflags(write=False)
        #: the reference in the context's units
        self.internal_reference = Xi
        self._check_units()
        self.backend = backend
        self.fixed_faces = _fixed_faces(topology, Xi, settings.fixed_face)
        self.fixed_face = int(self.fixed_faces[0])
        self._face_vertices = topology.faces[self.fixed_faces]  # (C, 3)
        frames = [triangle_frame(Xi, f) for f in self._face_vertices]
        self._origins = np.array([o for o, _ in frames])
        self._Qs = np.array([Q for _, Q in frames])
        labels = topology.face_components()[1]
        #: component label of every vertex ``(V,)`` (a vertex in no face: 0), whose fixed face places it
        self.vertex_component = np.zeros(topology.n_vertices, np.int64)
        self.vertex_component[topology.faces.ravel()] = np.repeat(labels, 3)
        self.fixed_dofs = _gauge_dofs(self._face_vertices, self.fix_triangle_shape)
        #: bounding-box diagonal of the reference, in the context's units
        self.size = float(np.linalg.norm(Xi.max(0) - Xi.min(0))) or 1.0
        self._residual_weights = None
        self._reference_lengths = None
        #: Whether objectives follow a target's size beyond :data:`TARGET_SCALE_BAND` (module docstring, "Target
        #: scale").  A shape mixer turns it off in its own context: its reduced energy, Newton points and polish
        #: share the basis' weights at every mix.
        self.follows_target_scale = True
        self._solver = None
        self._buffer = None
        self._fixed_entries = None
        #: the ordering method given to CHOLMOD ("metis" / "geometric"; None until :attr:`solver` is built,
        #: and with the SciPy backend, whose SuperLU orders by itself)
        self.ordering = None

    # units
    def _check_units(self):
        """InputError when the energy's membrane factor ``4^k`` (module docstring) does not fit float64."""
        k = self.scale_exponent
        unit_dependent = self.energy_name == "shells" or self.weights_kind != "frohlich_botsch"
        if unit_dependent and abs(2 * k) > _MAX_ENERGY_EXPONENT:
            what = ("the thin shells energy" if self.energy_name == "shells"
                    else f"W_q with weights {self.weights_kind!r}")
            raise InputError(f"{what} depends on the unit of length (its membrane term is in length units "
                             f"squared), and at coordinates of magnitude 2^{k} that term does not fit a float64 "
                             "number: scale the mesh (e.g. to metres), or use energy 'quadratic' with weights "
                             "'frohlich_botsch', which are scale-free")

    def internal_vertices(self, vertices):
        """Vertices in the context's units (``X 2^-k``, exact; the array itself when ``k = 0``)."""
        X = np.asarray(vertices, float)
        return np.ldexp(X, -self.scale_exponent) if self.scale_exponent else X

    def internal_z(self, z):
        """Lengths and angles in the context's units (lengths ``2^-k``, exact; ``z`` itself when ``k = 0``)."""
        z = np.asarray(z, float)
        if not self.scale_exponent:
            return z
        out = z.copy()
        E = self.topology.n_edges
        out[:E] = np.ldexp(z[:E], -self.scale_exponent)
        return out

    def external_vertices(self, vertices):
        """Vertices in the context's units -> the caller's units (``X 2^k``)."""
        X = np.asarray(vertices, float)
        return np.ldexp(X, self.scale_exponent) if self.scale_exponent else X

    @property
    def units_note(self):
        """A note for results computed in scaled units, or None when ``k = 0``."""
        k = self.scale_exponent
        if not k:
            return None
        return (f"coordinates of magnitude 2^{k} are outside 2^-{SAFE_EXPONENT}..2^{SAFE_EXPONENT}: computed in "
                f"units of 2^{k} (an exact scaling); vertices and energies are in the input's units")

    # the settings, under the names used throughout lacore
    @property
    def energy_name(self):
        """``"quadratic"`` or ``"shells"`` (:attr:`ReconstructionSettings.energy`)."""
        return self.settings.energy

    @property
    def weights_kind(self):
        """Weights of ``W_q`` (:attr:`ReconstructionSettings.weights`)."""
        return self.settings.weights

    @property
    def bending_weight(self):
        """``eta`` (:attr:`ReconstructionSettings.bending_weight`)."""
        return self.settings.bending_weight

    @property
    def fix_triangle_shape(self):
        """:attr:`ReconstructionSettings.fix_triangle_shape`."""
        return self.settings.fix_triangle_shape

    @property
    def pattern(self):
        """:func:`gauss_newton_pattern` of the topology."""
        return gauss_newton_pattern(self.topology)

    @property
    def residual_weights(self):
        """``(2E,)`` weights of ``W_q`` (lengths: ``w_s``, angles: ``eta w_b``)."""
        if self._residual_weights is None:
            w = reference_weights(self.internal_reference, self.topology, self.weights_kind, self.bending_weight)
            if self.scale_exponent and self.weights_kind != "frohlich_botsch":
                # (3.21) and uniform length weights are scale-invariant; the length residuals in the context's
                # units are 2^-k times the caller's: 4^k keeps the energy (units, module docstring)
                E = self.topology.n_edges
                w[:E] = np.ldexp(w[:E], 2 * self.scale_exponent)
            w.setflags(write=False)
            self._residual_weights = w
        return self._residual_weights

    @property
    def solver(self):
        """The :class:`~lacore.linalg.sparse_cholesky.SparseCholesky` (symbolic analysis on first use)."""
        if self._solver is None:
            pat = self.pattern
            ordering = None
            if self.backend == "cholmod":
                ordering, self.ordering = dof_ordering(self.topology, pat, self.internal_reference,
                                                       self.settings.ordering)
            # a large system ordered by METIS: no AMD analysis besides (METIS fills less there, GIVEN_ONLY_SIZE)
            big = ordering is not None and self.ordering == "metis" and len(ordering) >= GIVEN_ONLY_SIZE
            s = SparseCholesky(pat["matrix"], backend=self.backend, ordering=ordering, try_amd=not big)
            if not (np.array_equal(s.indptr, pat["indptr"]) and np.array_equal(s.indices, pat["indices"])):
                raise RuntimeError("sparse Cholesky pattern mismatch")  # pragma: no cover
            self._solver = s
        return self._solver

    @property
    def fixed_entries(self):
        """Value positions touching fixed coordinates (zeroed) and their diagonal positions (set to 1)."""
        if self._fixed_entries is None:
            pat = self.pattern
            is_fixed = np.zeros(pat["n"], bool)
            is_fixed[self.fixed_dofs] = True
            touch = np.flatnonzero(is_fixed[pat["indices"]] | is_fixed[pat["cols"]])
            diag = touch[pat["indices"][touch] == pat["cols"][touch]]
            self._fixed_entries = (touch, diag)
        return self._fixed_entries

    def eliminate_fixed(self, values):
        """Gauss-Newton matrix values (pattern order) with the fixed coordinates' rows and columns replaced by
        the identity, in place: the system the solver factorizes.  Returns ``values``."""
        touch, diag = self.fixed_entries
        values[touch] = 0.0
        values[diag] = 1.0
        return values

    # coordinates
    def to_canonical(self, vertices):
        """Rigidly move every component so that its fixed face sits in the 3-2-1 position.

        Takes vertices in the caller's units; returns ``(V, 3)`` coordinates in the
        context's units whose fixed coordinates are exactly 0.
        """
        X = self.internal_vertices(vertices)
        frames = [triangle_frame(X, f) for f in self._face_vertices]
        origins = np.array([o for o, _ in frames])
        Qs = np.array([Q for _, Q in frames])
        comp = self.vertex_component
        Xc = np.einsum("vij,vj->vi", Qs[comp], X - origins[comp])
        a, b, c = self._face_vertices.T
        Xc[a] = 0.0
        Xc[b, 1:] = 0.0
        Xc[c, 2] = 0.0
        return Xc

    def from_canonical(self, Xc):
        """Canonical coordinates -> the reference mesh's frame, in the caller's units (see module docstring)."""
        comp = self.vertex_component
        return self.external_vertices(np.einsum("vji,vj->vi", self._Qs[comp], Xc) + self._origins[comp])

    def align(self, vertices, keep_degenerate=False):
        """Rigidly move ``vertices`` (per component) into the output frame of this context.

        A fixed face that is degenerate in ``vertices`` raises :class:`MeshError`,
        or with ``keep_degenerate`` returns the vertices where they are (a start
        for Gauss-Newton, which places any start itself).
        """
        try:
            return self.from_canonical(self.to_canonical(vertices))
        except MeshError:
            if not keep_degenerate:
                raise
            return np.asarray(vertices, float)

    def target_scale(self, z_target):
        """``s``: how much larger than the reference a target is, beyond the band of sizes the weights are for.

        ``rho`` is the geometric mean of the ratios of the target's lengths to the reference's (continuous in the
        target, exact for a scaled copy); ``s = 1`` for ``rho`` within
        ``1 / TARGET_SCALE_BAND .. TARGET_SCALE_BAND``, else ``rho`` over the band's nearer end (continuous).
        Always 1 unless the energy is ``W_q`` with the scale-free weights (3.20) (module docstring,
        "Target scale"); also when :attr:`follows_target_scale` is off, and for targets beyond
        ``2^+-SAFE_EXPONENT`` (about 1e+-30) times that size, whose scaled weights float64 cannot hold.

        Examples
        --------
        >>> from lacore import MeshTopology, lengths_and_angles
        >>> from lacore.reconstruction import get_context
        >>> from lacore.samples.bar import bar_mesh
        >>> X, faces = bar_mesh(n_along=4, n_side=1)
        >>> topo = MeshTopology.from_faces(faces)
        >>> context = get_context(topo, X)
        >>> [round(context.target_scale(lengths_and_angles(k * X, topo)), 6) for k in (1.4, 3.0, 0.1)]
        [1.0, 2.0, 0.15]
        """
        if not self.follows_target_scale or self.energy_name != "quadratic" or self.weights_kind != "frohlich_botsch":
            return 1.0
        if self._reference_lengths is None:
            self._reference_lengths = lengths_and_angles(self.reference_vertices, self.topology)[:self.topology.n_edges]
        E = self.topology.n_edges
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = float(np.exp(np.mean(np.log(np.asarray(z_target, float)[:E] / self._reference_lengths))))
        scale = max(rho / TARGET_SCALE_BAND, 1.0) * min(rho * TARGET_SCALE_BAND, 1.0)
        if not 2.0 ** -SAFE_EXPONENT <= scale <= 2.0 ** SAFE_EXPONENT:  # NaN, or weights scaled out of float64
            return 1.0
        return scale

    def objective(self, z_target):
        """The energy ``X -> W[z*, Z(X)]`` of canonical coordinates for a target (``z*`` already validated).

        ``z_target`` is in the caller's units; the objective's ``z_target`` and
        coordinates are in the context's, its values in the caller's.  Its
        ``size`` is the length the stopping rules compare steps with: the
        reference's bounding-box diagonal times its ``target_scale``
        (:meth:`target_scale`), which also scales the length weights and the
        default start (module docstring, "Target scale").
        """
        z = self.internal_z(z_target)
        if self.energy_name == "quadratic":
            if self._buffer is None:  # outer-product values, reused by all targets of this context
                self._buffer = np.empty(len(self.pattern["slots"]))
            scale = self.target_scale(z_target)
            weights = self.residual_weights
            if scale != 1.0:
                weights = weights.copy()
                weights[:self.topology.n_edges] /= scale ** 2
            objective = QuadraticObjective(z, weights, self.topology, self.pattern, self._buffer)
            objective.size, objective.target_scale = self.size * scale, scale
            return objective
        k = self.scale_exponent  # W_TS = 4^k (membrane + eta 4^-k bending) in the context's units
        objective = ShellsObjective(z, self.topology, np.ldexp(self.bending_weight, -2 * k), self.solver,
                                    self.pattern, value_exponent=2 * k)
        objective.size, objective.target_scale = self.size, 1.0
        return objective

    def energy(self, z_target, vertices):
        """``W[z*, Z(vertices)]`` under this context's energy (both in the caller's units)."""
        z = lengths_and_angles(self.internal_vertices(vertices), self.topology)
        return self.objective(np.asarray(z_target, float)).value_z(z)


#: Targets whose lengths are within ``1 / TARGET_SCALE_BAND .. TARGET_SCALE_BAND`` times the reference's (geometric mean
#: ratio) use the reference's weights (3.20) as they are; beyond, the length weights follow the target's size
#: (module docstring, "Target scale").
TARGET_SCALE_BAND = 1.5

#: How many contexts :func:`get_context` keeps per topology (least recently used first out).
CONTEXTS_PER_TOPOLOGY = 4


def get_context(topology, reference_vertices, settings=None, **kwargs):
    """A cached :class:`ReconstructionContext` for these reference vertices and settings.

    The last :data:`CONTEXTS_PER_TOPOLOGY` contexts are kept on the topology,
    keyed by the reference coordinates' bytes and the (frozen, hashable)
    :class:`ReconstructionSettings`, so repeated reconstructions with the same
    set-up reuse weights and the symbolic factorization.

    Parameters
    ----------
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
    settings : ReconstructionSettings, optional
    **kwargs
        Fields of :class:`ReconstructionSettings` (override ``settings``).

    Examples
    --------
    >>> import numpy as np
    >>> from lacore import MeshTopology
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import lengths_and_angles, reconstruct
    >>> from lacore.reconstruction import get_context
    >>> context = get_context(topo, X)                # cached per topology, reference and settings
    >>> context is get_context(topo, X)
    True
    >>> res = reconstruct(lengths_and_angles(bar_pose(X, 0.3, 0.0), topo), topo, X, context=context)
    >>> res.success, res.fixed_face == context.fixed_face
    (True, True)
    """
    X = check_vertices(reference_vertices, topology.n_vertices, name="reference vertices")
    settings = split_options(kwargs, settings, caller="get_context", accept=("settings",)).settings
    cache = topology.cache.get((__name__, "contexts"), OrderedDict)
    key = (X.tobytes(), settings)
    ctx = cache.get(key)
    if ctx is None:
        ctx = ReconstructionContext(topology, X, settings)
        cache[key] = ctx
        while len(cache) > CONTEXTS_PER_TOPOLOGY:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    return ctx
