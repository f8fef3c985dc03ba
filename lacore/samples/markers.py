"""A standard 41-marker full-body set on the sample human, and simulated motion-capture observations.

Sample data for the marker-fitting tests and benchmark (:mod:`lacore.markers.fitting`):

* :data:`MARKER_SET` -- 41 named landmarks in the spirit of the CMU / Plug-in Gait
  full-body set (4 head, 5 torso, 4 pelvis, 7 per arm, 7 per leg), each given
  by a point on a bone (``head + s (tail - head)`` in the rest pose) and a
  direction (``+x`` left, ``+y`` up, ``+z`` forward);
* :func:`place_markers` -- landmark -> nearest surface point: from the bone point
  the ray along the direction leaves the body; the marker sits on the surface
  point (of the faces skinned to the landmark's bones) nearest to the point 2
  dm out along that ray, lifted ``offset`` along the face normal;
* :func:`observe_markers` -- marker positions over a take: the bound surface
  points of the true poses (normal offset included), Gaussian noise and
  occlusions in runs of a few frames.

Units are the body's: decimetres (8 mm offset = 0.08, 0.5 mm noise = 0.005).
"""

import numpy as np

from ..markers.binding import MarkerBinding, closest_surface_points, surface_points

__all__ = ["MARKER_SET", "place_markers", "observe_markers"]


def _mirror(entries):
    """Left and right copies of limb markers: bone ``B`` -> ``LeftB`` / ``RightB``, direction mirrored in x."""
    out = []
    for name, bones, s, d in entries:
        out.append(("L" + name, tuple("Left" + b for b in bones), s, d))
        out.append(("R" + name, tuple("Right" + b for b in bones), s, (-d[0], d[1], d[2])))
    return out


#: ``(name, bones, s, direction)``: the landmark lies on the first bone at ``s`` (0 head, 1 tail); the surface
#: point is searched on faces skinned to ``bones``.
MARKER_SET = tuple(
    [("LFHD", ("Head",), 0.55, (0.5, 0.0, 1.0)), ("RFHD", ("Head",), 0.55, (-0.5, 0.0, 1.0)),
     ("LBHD", ("Head",), 0.55, (0.5, 0.0, -1.0)), ("RBHD", ("Head",), 0.55, (-0.5, 0.0, -1.0)),
     ("C7", ("Neck", "Spine1"), 0.0, (0.0, 0.3, -1.0)), ("T10", ("Spine", "LowerBack"), 0.5, (0.0, 0.0, -1.0)),
     ("CLAV", ("Spine1", "Neck"), 0.95, (0.0, 0.2, 1.0)), ("STRN", ("Spine1", "Spine"), 0.2, (0.0, 0.0, 1.0)),
     ("RBAK", ("RightShoulder", "Spine1"), 0.5, (0.0, 0.0, -1.0)),
     ("LFWT", ("LHipJoint", "Hips", "LowerBack", "LeftUpLeg"), 0.8, (0.3, 0.3, 1.0)),
     ("RFWT", ("RHipJoint", "Hips", "LowerBack", "RightUpLeg"), 0.8, (-0.3, 0.3, 1.0)),
     ("LBWT", ("LHipJoint", "Hips", "LowerBack", "LeftUpLeg"), 0.8, (0.3, 0.3, -1.0)),
     ("RBWT", ("RHipJoint", "Hips", "LowerBack", "RightUpLeg"), 0.8, (-0.3, 0.3, -1.0))]
    + _mirror([
        ("SHO", ("Shoulder", "Arm"), 0.95, (0.2, 1.0, 0.0)),
        ("UPA", ("Arm",), 0.5, (1.0, 0.6, -0.3)),
        ("ELB", ("Arm", "ForeArm"), 1.0, (0.3, 0.0, -1.0)),
        ("FRM", ("ForeArm",), 0.5, (1.0, 0.3, 0.0)),
        ("WRA", ("ForeArm", "Hand"), 1.0, (0.0, 1.0, 0.0)),
        ("WRB", ("ForeArm", "Hand"), 1.0, (0.0, -1.0, 0.0)),
        ("FIN", ("Hand", "FingerBase"), 1.0, (0.2, 1.0, 0.0)),
        ("THI", ("UpLeg",), 0.5, (1.0, 0.0, 0.2)),
        ("KNE", ("UpLeg", "Leg"), 1.0, (1.0, 0.0, 0.0)),
        ("SHN", ("Leg",), 0.5, (0.3, 0.0, 1.0)),
        ("ANK", ("Leg", "Foot"), 1.0, (1.0, 0.0, 0.0)),
        ("HEE", ("Foot", "Leg"), 0.0, (0.0, -0.2, -1.0)),
        ("TOE", ("ToeBase", "Foot"), 0.5, (0.0, 1.0, 0.3)),
        ("MT5", ("Foot",), 0.8, (1.0, 0.0, 0.0)),
    ]))


def place_markers(body, offset=0.08, vertices=None):
    """Bind the markers of :data:`MARKER_SET` to a :class:`~lacore.samples.human.HumanBody`.

    Parameters
    ----------
    body : HumanBody
        Full or coarse body (its faces, rest vertices, bones and ``vertex_bone``).
    offset : float
        Normal offset of every marker (decimetres; default 0.08 = 8 mm).
    vertices : (V, 3) array_like, optional
        Pose to place on (default the rest pose).

    Returns
    -------
    names : list of str
        ``M = 41`` marker names.
    binding : MarkerBinding
    """
    X = body.vertices if vertices is None else np.asarray(vertices, float)
    F = body.faces
    index = {b: i for i, b in enumerate(body.bones)}
    face_bone = body.vertex_bone[F]                            # (F, 3)
    names, faces, bary = [], [], []
    for name, bones, s, d in MARKER_SET:
        b0 = index[bones[0]]
        p = body.heads[b0] + s * (body.tails[b0] - body.heads[b0])
        d = np.asarray(d, float) / np.linalg.norm(d)
        ids = [index[b] for b in bones]
        cand = np.flatnonzero(np.isin(face_bone, ids).all(1))
        _, f, bc = closest_surface_points(X, F[cand], (p + 2.0 * d)[None])
        names.append(name)
        faces.append(cand[f[0]])
        bary.append(bc[0])
    return names, MarkerBinding.from_surface(np.array(faces), np.array(bary), np.full(len(faces), float(offset)))


def observe_markers(vertices, faces, binding, noise=0.005, occlusion=0.1, run_lengths=(2, 8), seed=0):
    """Simulated marker positions ``(T, M, 3)`` of poses ``vertices (T, V, 3)``, NaN where occluded.

    Each marker's true position is its bound surface point (normal offset along
    the posed face normal) plus isotropic Gaussian noise of standard deviation
    ``noise``.  Occlusions come in runs of ``run_lengths[0]..run_lengths[1]``
    frames at random starts, about ``occlusion`` of all samples.
    """
    rng = np.random.default_rng(seed)
    x = surface_points(np.asarray(vertices, float), faces, binding)
    x = x + noise * rng.standard_normal(x.shape)
    T, M = x.shape[:2]
    lo, hi = run_lengths
    mean_len = 0.5 * (lo + hi)
    n_runs = int(round(occlusion * T / mean_len))
    hidden = np.zeros((T, M), bool)
    for m in range(M):
        for _ in range(n_runs):
            length = rng.integers(lo, hi + 1)
            start = rng.integers(0, max(1, T - length + 1))
            hidden[start:start + length, m] = True
    x[hidden] = np.nan
    return x
