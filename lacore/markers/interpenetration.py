"""Where a fitted take passes through itself and its markers do not: :func:`new_self_intersections`.

A fit should not push the surface through itself (an arm into the chest, the back of
the knee through the calf) unless the performer's body is in contact there, which the
markers show: two markers closer to each other than the sum of their offsets sit on
skin pressed together (a hand on the thigh).  Per frame:

1. the face pairs of :func:`lacore.geometry.self_intersection.self_intersections`,
   less those the rest mesh (the model's reference) already has, crossing or touching
   (:func:`lacore.geometry.proximity.touching_faces`, within :data:`REST_CONTACT_GAP`
   mean edge lengths): *new* pairs.  Faces touching at rest are in contact by design,
   and a coarse level of a mesh has more of them than the mesh (its chords across the
   eyelids come within 0.08 mm of the eyeballs on a 2,500-vertex coarsening of the CC0
   body, 0.0024 mean edge lengths, where the full body keeps a gap): keeping them apart is
   not the fit's job;
2. a new pair is a *contact* when each of its faces has a corner within
   :data:`CONTACT_RADIUS` of the model's size of the skin point of one of two visible
   markers closer than the sum of their offsets; the others are *unexplained*.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from ..geometry.proximity import touching_faces
from ..geometry.self_intersection import self_intersections
from ..geometry.topology import MeshTopology

__all__ = ["new_self_intersections", "SelfIntersections", "IntersectionCheck", "CONTACT_RADIUS", "REST_CONTACT_GAP"]

#: A face "near" a marker: within this fraction of the rest mesh's bounding-box diagonal of its skin point.
CONTACT_RADIUS = 0.05

#: Faces of the rest mesh closer than this many mean edge lengths (and sharing no vertex) touch at rest.
REST_CONTACT_GAP = 0.01


@dataclass
class SelfIntersections:
    """Outcome of :func:`new_self_intersections` for ``T`` frames.

    Attributes
    ----------
    pairs : list of (P_t, 2) int64 ndarray
        Per frame, the new face pairs the markers do not explain.
    contact_pairs : list of (C_t, 2) int64 ndarray
        Per frame, the new face pairs at two markers in contact.
    counts, contact_counts : (T,) int ndarray
        Their numbers.
    nearest_marker : list of (P_t,) int ndarray
        Per unexplained pair, the marker whose skin point is nearest to it (for reports),
        -1 when none is within ``4 * contact_radius`` (a region without markers).
    rest_pairs : (R, 2) int64 ndarray
        The pairs crossing or touching in the rest mesh (never reported), sorted.
    """

    pairs: list
    contact_pairs: list
    counts: np.ndarray
    contact_counts: np.ndarray
    nearest_marker: list
    rest_pairs: np.ndarray

    @property
    def frames(self):
        """Indices (into the ``T`` frames) of the frames with an unexplained pair."""
        return np.flatnonzero(self.counts)


def new_self_intersections(vertices, faces, binding, markers, rest_vertices, *, contact_radius=CONTACT_RADIUS):
    """Per frame, the face pairs passing through each other that the rest mesh and the markers do not.

    Parameters
    ----------
    vertices : (T, V, 3) array_like
        Fitted frames.
    faces : (F, 3) array_like of int or MeshTopology
    binding : lacore.markers.MarkerBinding
        The ``M`` markers on ``faces`` (skin point and offset).
    markers : (T, M, 3) array_like
        Marker positions in the unit of ``vertices`` (NaN where occluded).
    rest_vertices : (V, 3) array_like
        The rest mesh (e.g. the model's reference): its own pairs, crossing or touching, are not reported.
    contact_radius : float
        Fraction of the rest mesh's bounding-box diagonal within which a face (one of its
        corners) is near a marker's skin point (scale-free).

    Returns
    -------
    SelfIntersections

    Examples
    --------
    A flat strip folded so that its last face passes through its first; with no marker
    contact the pair is unexplained:

    >>> import numpy as np
    >>> from lacore.markers import MarkerBinding
    >>> from lacore.markers.interpenetration import new_self_intersections
    >>> rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [5, 0, 0], [5, 1, 0], [6, 0, 0]])
    >>> faces = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6]])
    >>> moved = rest.copy()
    >>> moved[4:] = [[0.2, 0.2, -1], [0.2, 0.2, 1], [0.6, 0.2, 0]]   # the third face pierces the first
    >>> binding = MarkerBinding.from_vertices([0, 6], faces)
    >>> markers = np.full((1, 2, 3), np.nan)
    >>> res = new_self_intersections(moved[None], faces, binding, markers, rest)
    >>> res.pairs[0], res.counts
    (array([[0, 2]]), array([1]))
    """
    X = np.asarray(vertices, float)
    Y = np.asarray(markers, float)
    check = IntersectionCheck(faces, binding, rest_vertices, contact_radius=contact_radius)
    per_frame = [check(X[t], Y[t]) for t in range(len(X))]
    pairs, contacts, nearest = ([f[k] for f in per_frame] for k in range(3))
    counts = np.array([len(p) for p in pairs], np.int64)
    contact_counts = np.array([len(p) for p in contacts], np.int64)
    return SelfIntersections(pairs, contacts, counts, contact_counts, nearest, check.rest_pairs)


class IntersectionCheck:
    """The per-frame test of :func:`new_self_intersections` for one mesh, binding and rest mesh.

    The rest mesh's own pairs are found once; calling the check on a frame ``(X (V, 3),
    y (M, 3))`` returns ``(pairs, contact_pairs, nearest_marker)`` of that frame, as the
    fields of :class:`SelfIntersections` (:class:`lacore.markers.fitting.FrameSolver` uses
    it between Gauss-Newton rounds).
    """

    def __init__(self, faces, binding, rest_vertices, *, contact_radius=CONTACT_RADIUS):
        R = np.asarray(rest_vertices, float)
        mesh = faces
        if not isinstance(mesh, MeshTopology):      # the search's connectivity part once for all frames
            try:
                mesh = MeshTopology.from_faces(faces, n_vertices=len(R), allow_unreferenced=True)
            except MeshError:
                mesh = np.asarray(faces, np.int64)
        F = mesh.faces if isinstance(mesh, MeshTopology) else mesh
        self.faces, self.binding, self._mesh = F, binding, mesh
        edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        mean_edge = float(np.linalg.norm(R[edges[:, 0]] - R[edges[:, 1]], axis=1).mean()) if len(F) else 0.0
        gap = REST_CONTACT_GAP * mean_edge
        rest = np.concatenate([self_intersections(R, mesh), touching_faces(R, F, gap)])
        self.rest_pairs = np.unique(rest, axis=0) if len(rest) else np.zeros((0, 2), np.int64)
        self._rest_keys = self.rest_pairs[:, 0] * len(F) + self.rest_pairs[:, 1]
        self.radius = contact_radius * float(np.linalg.norm(np.ptp(R, axis=0)))
        self._corners = binding.corner_vertices(F)
        self._offsets = np.abs(np.asarray(binding.offsets, float))

    def __call__(self, X, y):
        F, binding, radius, n_faces = self.faces, self.binding, self.radius, len(self.faces)
        P = self_intersections(X, self._mesh, check=False)
        P = P[~np.isin(P[:, 0] * n_faces + P[:, 1], self._rest_keys)]
        if not len(P):
            return P, P, np.zeros(0, np.int64)
        skin = np.einsum("mk,mkc->mc", binding.barycentric, X[self._corners])          # (M, 3)
        corner = X[F]                                                                  # (F, 3, 3)
        da = np.linalg.norm(corner[P[:, 0], :, None] - skin, axis=3).min(axis=1)       # (P, M): nearest corner
        db = np.linalg.norm(corner[P[:, 1], :, None] - skin, axis=3).min(axis=1)
        gap = np.linalg.norm(y[:, None] - y[None], axis=2)                             # NaN if occluded
        offsets = self._offsets
        with np.errstate(invalid="ignore"):
            touch = gap < offsets[:, None] + offsets[None]
        np.fill_diagonal(touch, False)
        near_a, near_b = da < radius, db < radius
        # a contact: markers m1 near face a and m2 near face b with touch[m1, m2]
        explained = np.einsum("pm,mn,pn->p", near_a.astype(float), touch.astype(float), near_b.astype(float)) > 0
        dmin = np.minimum(da, db)[~explained]
        m = np.argmin(dmin, axis=1)
        return P[~explained], P[explained], np.where(dmin[np.arange(len(m)), m] <= 4 * radius, m, -1)
