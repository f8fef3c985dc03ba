"""Is ``z`` the lengths and angles of a mesh?  All of Theorem 3.2 in one verdict.

:func:`check_integrability` evaluates every condition of the discrete
fundamental theorem (Theorem 3.2) and reports them separately:

``local``
    the frames close around every interior vertex (3.11):
    ``|tr I_v - 3| = 2 (1 - cos a_v)`` per vertex (:func:`~lacore.integrability.local.integrability_violation`),
    at most :data:`LOCAL_TOLERANCE`;
``holonomy``
    the frames close around every loop of the homology basis (around every
    hole and handle, :mod:`lacore.integrability.global_conditions`): the angle
    (radians) by which they fail, at most :data:`HOLONOMY_TOLERANCE`;
``translation``
    the edge vectors close around every basis loop: the gap relative to the
    loop's length, at most :data:`TRANSLATION_TOLERANCE`;

and every triangle satisfies the triangle inequality (3.6).  ``integrable`` is
True when all hold.

The three tolerances are one level: ``|tr I - 3| = 1e-8`` is a rotation by
``1e-4`` rad, and a relative gap of ``1e-4`` is the same first-order mismatch.
Lengths and angles computed from a mesh meet them with a wide margin (round-off
gives ``|tr I - 3|`` of 1e-30 .. 1e-14 and loop residuals of 1e-16 .. 1e-13);
averages and extrapolations of shapes, or lengths and angles edited by hand,
usually miss them by orders of magnitude.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .global_conditions import _tables, _z
from .homology import HomologyBasis
from .local import integrability_violation
from .transitions import triangle_inequality_map

__all__ = ["IntegrabilityCheck", "check_integrability", "LOCAL_TOLERANCE", "HOLONOMY_TOLERANCE",
           "TRANSLATION_TOLERANCE"]

#: Largest ``|tr I_v - 3|`` at an interior vertex of integrable lengths and angles (a rotation by 1e-4 rad).
LOCAL_TOLERANCE = 1e-8
#: Largest angle (radians) by which the frames may fail to close around a basis loop.
HOLONOMY_TOLERANCE = 1e-4
#: Largest gap of the edge vectors around a basis loop, relative to the loop's length.
TRANSLATION_TOLERANCE = 1e-4

_WHERE = {"vertex": "at a vertex", "hole": "around a hole", "handle": "around a handle",
          "triangle": "in a triangle"}


@dataclass(frozen=True, eq=False, repr=False)
class IntegrabilityCheck:
    """Outcome of :func:`check_integrability`.

    Attributes
    ----------
    integrable : bool
        Every condition of Theorem 3.2 holds (within the tolerances).
    local : (V,) ndarray
        ``|tr I_v - 3|`` per vertex (0 on the boundary, ``inf`` next to a
        triangle violating the triangle inequality).
    holonomy, translation : (n_loops, 3) ndarray
        :func:`~lacore.integrability.global_conditions.loop_holonomy` and
        :func:`~lacore.integrability.global_conditions.loop_translation`.
    holonomy_angle, translation_gap : (n_loops,) ndarray
        Their norms (``inf`` for a loop through a triangle violating the triangle inequality).
    basis : HomologyBasis
        The loops (:func:`~lacore.integrability.homology.homology_basis`).
    failing_vertices, failing_loops, failing_faces : int64 ndarray
        Interior vertices, basis loops and triangles (triangle inequality) that fail.
    loops_at_failing_vertices : (n_loops,) bool
        The loop's corridor touches a failing vertex: its holonomy and translation
        then depend on the path around that vertex, so its failure is not
        counted as one around a hole or handle (:meth:`failing_parts`).
    """

    integrable: bool
    local: np.ndarray
    holonomy: np.ndarray
    translation: np.ndarray
    holonomy_angle: np.ndarray
    translation_gap: np.ndarray
    basis: HomologyBasis
    failing_vertices: np.ndarray
    failing_loops: np.ndarray
    failing_faces: np.ndarray
    loops_at_failing_vertices: np.ndarray
    tolerances: dict = field(default_factory=dict)

    def __repr__(self):
        return f"IntegrabilityCheck(integrable={self.integrable}, {self.describe()!r})"

    @property
    def max_local(self):
        return float(self.local.max()) if self.local.size else 0.0

    @property
    def max_holonomy(self):
        return float(self.holonomy_angle.max()) if self.holonomy_angle.size else 0.0

    @property
    def max_translation(self):
        return float(self.translation_gap.max()) if self.translation_gap.size else 0.0

    def failing_parts(self):
        """Where the conditions fail, in order: a subset of ``["triangle", "vertex", "hole", "handle"]``."""
        parts = []
        if self.failing_faces.size:
            parts.append("triangle")
        if self.failing_vertices.size:
            parts.append("vertex")
        own = self.failing_loops[~self.loops_at_failing_vertices[self.failing_loops]]
        kinds = set(self.basis.kind[own].tolist())
        parts += [k for k in ("hole", "handle") if k in kinds]
        return parts

    def where(self):
        """The failing parts in words: ``"at a vertex, around a hole"`` (``""`` if integrable)."""
        return ", ".join(_WHERE[p] for p in self.failing_parts())

    def _loop_text(self, k):
        b = self.basis
        text = b.label(int(k))
        if b.kind[k] == "hole":
            text += f" (boundary loop {int(b.boundary_loop[k])}, {int(b.ptr[k + 1] - b.ptr[k])} edges)"
        else:
            text += f" ({int(b.ptr[k + 1] - b.ptr[k])} edges)"
        ang, gap = self.holonomy_angle[k], self.translation_gap[k]
        if not (np.isfinite(ang) and np.isfinite(gap)):
            return text + ": through a triangle violating the triangle inequality"
        if self.loops_at_failing_vertices[k]:
            text += " next to failing vertices"
        misses = []
        if ang > self.tolerances["holonomy"]:
            misses.append(f"the frames turn by {ang:.3g} rad")
        if gap > self.tolerances["translation"]:
            misses.append(f"the edges miss by {100 * gap:.3g} % of its length")
        return text + ": " + " and ".join(misses)

    def describe(self):
        """One line: the verdict and, if not integrable, what fails where (largest mismatches first)."""
        n = self.basis.n_loops
        if self.integrable:
            text = f"integrable: the frames close around every vertex (|tr I - 3| <= {self.max_local:.2g})"
            if not n:
                return text + "; no loop around a hole or handle to check"
            return (text + f" and around the {n} loop{'s' if n != 1 else ''} of holes and handles (by "
                    f"{self.max_holonomy:.2g} rad), the edges close around them (to {self.max_translation:.2g} of "
                    "the loop length)")
        out = []
        if self.failing_faces.size:
            out.append(f"{self.failing_faces.size} triangle{'s' if self.failing_faces.size != 1 else ''} violate "
                       "the triangle inequality")
        if self.failing_vertices.size:
            v = self.local[self.failing_vertices]
            worst = int(self.failing_vertices[np.argmax(v)])
            out.append(f"the frames do not close around {self.failing_vertices.size} "
                       f"{'vertices' if self.failing_vertices.size != 1 else 'vertex'} (largest |tr I - 3| "
                       f"{float(v.max()):.3g} at vertex {worst})")
        order = self.failing_loops[np.argsort(-np.nan_to_num(self.holonomy_angle[self.failing_loops] +
                                                             self.translation_gap[self.failing_loops], posinf=1e300),
                                              kind="stable")]
        out += [self._loop_text(k) for k in order[:3]]
        if len(order) > 3:
            out.append(f"{len(order) - 3} more loops")
        return "not integrable " + self.where() + ": " + "; ".join(out)

    def summary(self):
        """JSON-friendly dict: verdict, largest violation per part, tolerances and every basis loop."""
        def num(x):
            return float(x) if np.isfinite(x) else None
        b = self.basis
        loops = []
        for k, item in enumerate(b.summary()):
            item.update(holonomy=num(self.holonomy_angle[k]), translation=num(self.translation_gap[k]),
                        closes=bool(k not in set(self.failing_loops.tolist())))
            loops.append(item)
        return {"integrable": self.integrable, "where": self.failing_parts(),
                "max_integrability_violation": {"local": num(self.max_local), "holonomy": num(self.max_holonomy),
                                                "translation": num(self.max_translation)},
                "tolerances": dict(self.tolerances), "failing_vertices": int(self.failing_vertices.size),
                "failing_triangles": int(self.failing_faces.size), "genus": b.genus.tolist(),
                "boundary_loops": b.n_boundary_loops.tolist(), "loops": loops}


def check_integrability(z, topology, *, local_tolerance=LOCAL_TOLERANCE, holonomy_tolerance=HOLONOMY_TOLERANCE,
                        translation_tolerance=TRANSLATION_TOLERANCE):
    """Check all conditions of Theorem 3.2 for lengths and angles ``z`` (module docstring).

    Parameters
    ----------
    z : (2E,) array_like
    topology : MeshTopology
    local_tolerance, holonomy_tolerance, translation_tolerance : float
        Largest ``|tr I_v - 3|``, loop holonomy angle (rad) and relative loop gap counted as closing.

    Returns
    -------
    IntegrabilityCheck

    Examples
    --------
    >>> from lacore import MeshTopology, check_integrability
    >>> from lacore.samples.surfaces import developed_cone
    >>> faces, z, deficit = developed_cone()       # a cone frustum's lengths on an annulus, all angles 0
    >>> check = check_integrability(z, MeshTopology.from_faces(faces))
    >>> check.integrable, check.where()
    (False, 'around a hole')
    """
    for name, tol in (("local_tolerance", local_tolerance), ("holonomy_tolerance", holonomy_tolerance),
                      ("translation_tolerance", translation_tolerance)):
        if not isinstance(tol, (int, float, np.floating, np.integer)) or not (np.isfinite(tol) and tol >= 0):
            raise InputError(f"{name} must be a finite number >= 0, got {tol!r}")
    z = _z(z, topology)
    local = integrability_violation(z, topology)
    tables = _tables(topology)
    hol, tau, invalid = tables.evaluate(z)
    angle = np.linalg.norm(hol, axis=1)
    gap = np.linalg.norm(tau, axis=1)
    angle[invalid] = np.inf
    gap[invalid] = np.inf
    bad_faces = np.flatnonzero(~(triangle_inequality_map(z, topology) > 0).all(axis=1))
    bad_vertices = np.flatnonzero(~(local <= local_tolerance))
    bad_loops = np.flatnonzero(~((angle <= holonomy_tolerance) & (gap <= translation_tolerance)))
    integrable = not (bad_faces.size or bad_vertices.size or bad_loops.size)
    at_bad = np.zeros(len(angle), bool)
    if bad_vertices.size and len(angle):
        b = tables.basis
        bad_v = np.zeros(topology.n_vertices, bool)
        bad_v[bad_vertices] = True
        face_bad = bad_v[topology.faces].any(axis=1)
        at_bad[np.repeat(np.arange(b.n_loops), np.diff(b.dual_ptr))[face_bad[b.dual_faces]]] = True
        at_bad[np.repeat(np.arange(b.n_loops), np.diff(b.ptr))[face_bad[b.edge_faces]]] = True
    return IntegrabilityCheck(
        integrable=integrable, local=local, holonomy=hol, translation=tau, holonomy_angle=angle, translation_gap=gap,
        basis=tables.basis, failing_vertices=bad_vertices, failing_loops=bad_loops, failing_faces=bad_faces,
        loops_at_failing_vertices=at_bad,
        tolerances={"local": local_tolerance, "holonomy": holonomy_tolerance, "translation": translation_tolerance})
