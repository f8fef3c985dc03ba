"""A rigged human body posed by linear-blend skinning: seeded training sets and held-out takes.

Sample data, not shipped data: everything is read from ``shared/data/human``
(the CC0 MakeHuman base mesh "hm08", its 31-bone CMU-style skeleton and
skinning weights; see that folder's README) and generated reproducibly from a
seed.  Independent of the rest of lacore (NumPy/SciPy only) but for the
self-intersection test of clean poses and the shape model of :func:`human_model`.

* :func:`load_human` -- the ``body`` group of ``base.obj`` (vertices 0..13379;
  its 13,378 quads fan-triangulated ``(a, b, c), (a, c, d)``: 26,756 outward
  triangles), bone heads/tails (centres of the ``joint-*`` cube groups or means
  of listed vertices, as ``rig.cmu_mb.json`` says) and the ``(V, 31)`` sparse
  skinning weights.  ``coarse=True`` gives the coarse body (a subset of the
  vertices, see ``scripts/make_coarse_human.py``) once it has been made.
* :class:`HumanBody` -- posing: a pose is a vector of joint angles (one per
  entry of :data:`JOINT_DOFS`: anatomical swings and twists about axes fixed in
  the rest pose, with one-sided limits where anatomy has them: knees and
  elbows bend one way); :meth:`HumanBody.pose` composes the bone transforms
  down the hierarchy and skins all frames with one sparse product
  ``W (V, B) @ M (B, 12 T)``.
* :func:`open_body` -- the body with five openings (eyes, mouth, both wrists):
  a surface of genus 0 with five boundary loops, posable like the body.
* :meth:`HumanBody.random_poses` (training sets; ``clean=`` for poses whose skin does
  not pass through itself) and :meth:`HumanBody.take`
  (held-out motion: smooth joint curves reaching beyond the training range,
  plus a walk of the whole body), all from a seed.

Units are those of ``base.obj``: decimetres; ``+y`` is up, ``+z`` forward
(the face), ``+x`` the body's left.

Extension point (markers): marker placement for motion-capture fitting belongs in
a separate function taking a :class:`HumanBody` and posed vertices (e.g.
vertices or surface points chosen per bone via :attr:`HumanBody.vertex_bone`,
offset along :meth:`HumanBody.vertex_normals`); :meth:`HumanBody.take` returns the posed vertices and
the rigid root motion, which is all such a function needs.
"""

import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

__all__ = ["HumanBody", "load_human", "open_body", "coarse_human_coarsening", "human_model", "human_data_dir",
           "training_angles", "training_file", "base_obj_sha256", "JOINT_DOFS", "LIMBS", "N_BODY_VERTICES",
           "TRAINING_SPREAD", "POSE_KEYS", "dof_angles", "pose_keys", "limb_ends"]

#: Vertices of the ``body`` group of ``base.obj`` (the first ones of the file).
N_BODY_VERTICES = 13380

#: Fraction of every joint's range that training poses are drawn from (:meth:`HumanBody.random_angles`).
TRAINING_SPREAD = 0.8

#: Degrees of freedom of a pose: ``(bone, kind, toward, low, high)`` with angles in degrees.
#: ``kind="swing"`` rotates the bone about ``bone_direction x toward`` (positive angles move the
#: bone toward ``toward``); ``kind="twist"`` rotates it about its own direction.  ``toward`` is
#: ``"forward"`` (+z), ``"backward"``, ``"up"`` (+y), ``"outward"`` (away from the body's mid-plane),
#: ``"left"`` (+x) or ``"parent"`` (back onto the parent bone: the elbow's hinge).  Hips, LHipJoint and
#: RHipJoint carry no angles (the root motion is separate).
JOINT_DOFS = (
    ("LowerBack", "swing", "forward", -10, 20), ("LowerBack", "swing", "left", -10, 10),
    ("LowerBack", "twist", None, -10, 10),
    ("Spine", "swing", "forward", -10, 20), ("Spine", "swing", "left", -10, 10), ("Spine", "twist", None, -15, 15),
    ("Spine1", "swing", "forward", -5, 15), ("Spine1", "twist", None, -10, 10),
    ("Neck", "swing", "forward", -15, 25), ("Neck", "swing", "left", -15, 15),
    ("Head", "swing", "forward", -20, 25), ("Head", "twist", None, -40, 40),
    ("LeftShoulder", "swing", "up", -5, 20), ("LeftShoulder", "swing", "forward", -10, 15),
    ("RightShoulder", "swing", "up", -5, 20), ("RightShoulder", "swing", "forward", -10, 15),
    ("LeftArm", "swing", "forward", -30, 70), ("LeftArm", "swing", "up", -30, 70), ("LeftArm", "twist", None, -40, 40),
    ("RightArm", "swing", "forward", -30, 70), ("RightArm", "swing", "up", -30, 70),
    ("RightArm", "twist", None, -40, 40),
    ("LeftForeArm", "swing", "parent", 0, 110), ("LeftForeArm", "twist", None, -30, 30),
    ("RightForeArm", "swing", "parent", 0, 110), ("RightForeArm", "twist", None, -30, 30),
    ("LeftHand", "swing", "forward", -40, 50), ("RightHand", "swing", "forward", -40, 50),
    ("LeftFingerBase", "swing", "forward", 0, 25), ("RightFingerBase", "swing", "forward", 0, 25),
    ("LeftHandFinger1", "swing", "forward", 0, 30), ("RightHandFinger1", "swing", "forward", 0, 30),
    ("LThumb", "swing", "forward", 0, 20), ("RThumb", "swing", "forward", 0, 20),
    ("LeftUpLeg", "swing", "forward", -20, 75), ("LeftUpLeg", "swing", "outward", -10, 40),
    ("LeftUpLeg", "twist", None, -20, 20),
    ("RightUpLeg", "swing", "forward", -20, 75), ("RightUpLeg", "swing", "outward", -10, 40),
    ("RightUpLeg", "twist", None, -20, 20),
    ("LeftLeg", "swing", "backward", 0, 110), ("RightLeg", "swing", "backward", 0, 110),
    ("LeftFoot", "swing", "up", -30, 20), ("RightFoot", "swing", "up", -30, 20),
    ("LeftToeBase", "swing", "up", -10, 30), ("RightToeBase", "swing", "up", -10, 30),
)

#: Bones of each limb (for region statistics, e.g. the locality of shape-model modes).
LIMBS = {
    "left_arm": ("LeftArm", "LeftForeArm", "LeftHand", "LeftFingerBase", "LeftHandFinger1", "LThumb"),
    "right_arm": ("RightArm", "RightForeArm", "RightHand", "RightFingerBase", "RightHandFinger1", "RThumb"),
    "left_leg": ("LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase"),
    "right_leg": ("RightUpLeg", "RightLeg", "RightFoot", "RightToeBase"),
    "trunk_head": ("Hips", "LHipJoint", "RHipJoint", "LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head",
                   "LeftShoulder", "RightShoulder"),
}

#: Shape keys of the shape-mixer examples (:func:`pose_keys`): each a name and its joint angles in degrees,
#: ``{(bone, kind, toward): degrees}`` (:data:`JOINT_DOFS`' first three entries; the other angles 0).
POSE_KEYS = (
    ("ArmRaised", {("LeftArm", "swing", "up"): 70.0}),
    ("KneeBent", {("RightLeg", "swing", "backward"): 35.0}),
    ("TorsoTwisted", {("LowerBack", "twist", None): 10.0, ("Spine", "twist", None): 15.0,
                      ("Spine1", "twist", None): 10.0}),
)

_DIRECTIONS = {"forward": (0.0, 0.0, 1.0), "backward": (0.0, 0.0, -1.0), "up": (0.0, 1.0, 0.0),
               "left": (1.0, 0.0, 0.0)}


def human_data_dir(path=None):
    """The ``human`` data folder: ``path``, else ``$LACORE_SHARED_DATA/human``, else ``<repo>/../shared/data/human``.

    ``path`` (or the environment variable) may name the ``data`` folder, its
    ``meshes`` folder or the ``human`` folder itself.
    """
    if path is None:
        env = os.environ.get("LACORE_SHARED_DATA")
        path = Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared" / "data"
    path = Path(path)
    if path.name == "meshes":
        path = path.parent
    if path.name != "human":
        path = path / "human"
    if not (path / "base.obj").is_file():
        raise FileNotFoundError(f"human body data not found: {path / 'base.obj'} (set LACORE_SHARED_DATA or pass "
                                "path=)")
    return path


def dof_angles(degrees):
    """Joint angles of one pose from the few that are not zero.

    Parameters
    ----------
    degrees : dict
        ``{(bone, kind, toward): angle in degrees}``, keys as the first three entries of :data:`JOINT_DOFS`.

    Returns
    -------
    (P,) ndarray
        Radians, in the order of :data:`JOINT_DOFS` (0 for the angles not given), for :meth:`HumanBody.pose`.

    Examples
    --------
    >>> a = dof_angles({("LeftArm", "swing", "up"): 70.0})
    >>> a.shape == (len(JOINT_DOFS),), round(float(np.degrees(a.sum())), 6)
    (True, 70.0)
    """
    index = {d[:3]: i for i, d in enumerate(JOINT_DOFS)}
    angles = np.zeros(len(JOINT_DOFS))
    for dof, deg in degrees.items():
        if dof not in index:
            raise ValueError(f"{dof} is not a joint angle of the body: use (bone, kind, toward) of JOINT_DOFS")
        angles[index[dof]] = np.radians(deg)
    return angles


def pose_keys(body, poses=POSE_KEYS):
    """Shape keys of ``body``: its rest pose followed by one posed mesh per entry of ``poses``.

    Parameters
    ----------
    body : HumanBody
    poses : sequence of (str, dict)
        Names and joint angles in degrees (:func:`dof_angles`); default :data:`POSE_KEYS` (left arm raised by 70
        degrees, right knee bent by 35, torso twisted by 35 over three joints).

    Returns
    -------
    names : list of str
        ``"Basis"`` and the poses' names.
    keys : (K, V, 3) ndarray
        The rest vertices and the posed ones (linear-blend skinning), decimetres.

    Examples
    --------
    >>> names, keys = pose_keys(load_human())  # doctest: +SKIP
    >>> names, keys.shape  # doctest: +SKIP
    (['Basis', 'ArmRaised', 'KneeBent', 'TorsoTwisted'], (4, 13380, 3))
    """
    names = ["Basis", *(name for name, _ in poses)]
    posed = [body.pose(dof_angles(degrees)) for _, degrees in poses]
    return names, np.stack([body.vertices, *posed])


def limb_ends(body, limb):
    """Two vertices spanning a limb of :data:`LIMBS` at rest, to measure its length in a pose.

    Parameters
    ----------
    body : HumanBody
    limb : str
        A key of :data:`LIMBS` (``"left_arm"``, ``"right_leg"`` ...).

    Returns
    -------
    root, tip : int
        The vertex nearest to the head of the limb's first bone (the shoulder or hip joint) and the vertex of the
        limb (largest skinning weight on one of its bones) farthest from it: a fingertip or the tip of the toes.

    Examples
    --------
    >>> body = load_human()  # doctest: +SKIP
    >>> root, tip = limb_ends(body, "left_arm")  # doctest: +SKIP
    >>> round(float(np.linalg.norm(body.vertices[tip] - body.vertices[root])), 2)  # decimetres  # doctest: +SKIP
    5.93
    """
    head = body.heads[body.bone_index(LIMBS[limb][0])]
    members = np.flatnonzero(np.isin(np.asarray(body.bones)[body.vertex_bone], LIMBS[limb]))
    tip = members[np.argmax(np.linalg.norm(body.vertices[members] - head, axis=1))]
    root = np.argmin(np.linalg.norm(body.vertices - head, axis=1))
    return int(root), int(tip)


def _read_obj(path):
    """Vertices (all), body quads and the vertex sets of the ``joint-*`` groups of ``base.obj``."""
    vertices, body, groups = [], [], {}
    group = None
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.startswith("v "):
                vertices.append(line.split()[1:4])
            elif line.startswith("g "):
                group = line.split()[1]
            elif line.startswith("f "):
                idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
                if group == "body":
                    body.append(idx)
                elif group is not None and group.startswith("joint-"):
                    groups.setdefault(group, set()).update(idx)
    return np.array(vertices, float), np.array(body, np.int64), {k: np.array(sorted(v)) for k, v in groups.items()}


def _joint_position(spec, vertices, groups):
    if spec["strategy"] == "CUBE" and spec.get("cube_name") in groups:
        return vertices[groups[spec["cube_name"]]].mean(axis=0)
    if spec["strategy"] == "MEAN" and spec.get("vertex_indices"):
        return vertices[np.asarray(spec["vertex_indices"])].mean(axis=0)
    raise ValueError(f"cannot locate joint {spec!r} in base.obj")


class HumanBody:
    """The skinned human body: rest mesh, skeleton, weights and posing.

    Attributes
    ----------
    vertices : (V, 3) ndarray
        Rest pose (A-pose), decimetres.
    faces : (F, 3) int64 ndarray
        Outward-oriented triangles.
    vertex_ids : (V,) int64 ndarray
        Index of each vertex in ``base.obj`` (``arange(13380)`` for the full body,
        the kept subset for the coarse body).
    bones : tuple of str
        Bone names in topological order (parents first).
    parents : (B,) int64 ndarray
        Parent index of each bone (-1 for the root ``Hips``).
    heads, tails : (B, 3) ndarray
        Rest positions of the bone heads (rotation centres) and tails.
    weights : (V, B) scipy.sparse.csr_matrix
        Skinning weights, rows sum to 1.
    vertex_bone : (V,) int64 ndarray
        Bone of largest weight per vertex.
    dofs : tuple
        :data:`JOINT_DOFS`.
    lower, upper : (P,) ndarray
        Joint limits in radians.
    """

    def __init__(self, vertices, faces, vertex_ids, bones, parents, heads, tails, weights):
        self.vertices = vertices
        self.faces = faces
        self.vertex_ids = vertex_ids
        self.bones = tuple(bones)
        self.parents = parents
        self.heads = heads
        self.tails = tails
        self.weights = weights
        self.vertex_bone = np.asarray(weights.argmax(axis=1)).ravel()
        self.dofs = JOINT_DOFS
        self.lower = np.radians([d[3] for d in JOINT_DOFS])
        self.upper = np.radians([d[4] for d in JOINT_DOFS])
        index = {b: i for i, b in enumerate(self.bones)}
        self._dof_bone = np.array([index[d[0]] for d in JOINT_DOFS])
        self._dof_axis = np.array([self._axis(index[d[0]], d[1], d[2]) for d in JOINT_DOFS])

    @property
    def n_vertices(self):
        return len(self.vertices)

    @property
    def n_dofs(self):
        """``P``, the number of joint angles of a pose."""
        return len(JOINT_DOFS)

    def bone_index(self, name):
        return self.bones.index(name)

    def _axis(self, b, kind, toward):
        d = self.tails[b] - self.heads[b]
        d = d / np.linalg.norm(d)
        if kind == "twist":
            return d
        if toward == "outward":
            side = np.sign(self.heads[b][0]) or 1.0
            t = np.array([side, 0.0, 0.0])
        elif toward == "parent":  # a hinge folding the bone back onto its parent (elbow)
            p = self.parents[b]
            t = self.heads[p] - self.tails[p]
        else:
            t = np.array(_DIRECTIONS[toward])
        a = np.cross(d, t)
        n = np.linalg.norm(a)
        if n < 1e-6:
            raise ValueError(f"bone {self.bones[b]} points along {toward}: no swing axis")
        return a / n

    # ------------------------------------------------------------------ posing
    def bone_transforms(self, angles, root_rotation=None, root_translation=None):
        """World transforms of all bones for ``T`` poses.

        Parameters
        ----------
        angles : (P,) or (T, P) array_like
            Joint angles in radians (order of :data:`JOINT_DOFS`).
        root_rotation : (3, 3) or (T, 3, 3) array_like, optional
            Rotation of the whole body about the rest pelvis (``Hips`` head).
        root_translation : (3,) or (T, 3) array_like, optional

        Returns
        -------
        R : (T, B, 3, 3) ndarray
        t : (T, B, 3) ndarray
            Bone ``b`` maps a rest point ``x`` to ``R[:, b] @ x + t[:, b]``.
        """
        a = np.atleast_2d(np.asarray(angles, float))
        T, B = len(a), len(self.bones)
        if a.shape[1] != self.n_dofs:
            raise ValueError(f"a pose has {self.n_dofs} joint angles, got {a.shape[1]}")
        # local rotations: product of the dof rotations of each bone, in JOINT_DOFS order
        local = np.broadcast_to(np.eye(3), (T, B, 3, 3)).copy()
        rot = Rotation.from_rotvec((a[:, :, None] * self._dof_axis[None]).reshape(-1, 3)).as_matrix()
        rot = rot.reshape(T, self.n_dofs, 3, 3)
        for k, b in enumerate(self._dof_bone):  # P = 47 small products, vectorized over frames
            local[:, b] = rot[:, k] @ local[:, b]
        R = np.empty((T, B, 3, 3))
        t = np.empty((T, B, 3))
        root_R = np.broadcast_to(np.eye(3) if root_rotation is None else np.asarray(root_rotation, float),
                                 (T, 3, 3))
        root_t = np.broadcast_to(np.zeros(3) if root_translation is None else np.asarray(root_translation, float),
                                 (T, 3))
        h0 = self.heads[0]
        for b in range(B):  # parents first
            h = self.heads[b]
            # rotate about the rest head: x -> L (x - h) + h, then the parent's transform
            Lb = local[:, b]
            tb = h - Lb @ h
            p = self.parents[b]
            if p < 0:
                PR, Pt = root_R, root_t + h0 - root_R @ h0
            else:
                PR, Pt = R[:, p], t[:, p]
            R[:, b] = PR @ Lb
            t[:, b] = np.einsum("tij,tj->ti", PR, tb) + Pt
        return R, t

    def pose(self, angles, root_rotation=None, root_translation=None):
        """Skinned vertices ``(V, 3)`` (one pose) or ``(T, V, 3)`` by linear-blend skinning.

        ``x_v' = sum_b w_vb (R_b x_v + t_b)``: all frames in one sparse product
        of the weights ``(V, B)`` with the stacked affine maps ``(B, 12 T)``.
        """
        single = np.ndim(angles) == 1
        R, t = self.bone_transforms(angles, root_rotation, root_translation)
        T, B = R.shape[:2]
        M = np.concatenate([R, t[..., None]], axis=-1)  # (T, B, 3, 4)
        M = M.transpose(1, 0, 2, 3).reshape(B, T * 12)
        blended = np.asarray(self.weights @ M).reshape(-1, T, 3, 4)  # (V, T, 3, 4)
        X = np.einsum("vtij,vj->tvi", blended[..., :3], self.vertices) + blended[..., 3].transpose(1, 0, 2)
        return X[0] if single else X

    def joint_positions(self, angles, root_rotation=None, root_translation=None):
        """Posed bone heads ``(T, B, 3)`` (or ``(B, 3)`` for one pose)."""
        single = np.ndim(angles) == 1
        R, t = self.bone_transforms(angles, root_rotation, root_translation)
        P = np.einsum("tbij,bj->tbi", R, self.heads) + t
        return P[0] if single else P

    def vertex_normals(self, vertices):
        """Unit area-weighted vertex normals of posed vertices ``(V, 3)`` or ``(T, V, 3)`` (outward).

        For placing markers on the skin, offset along the normal.
        """
        X = np.asarray(vertices, float)
        F = self.faces
        n = np.cross(X[..., F[:, 1], :] - X[..., F[:, 0], :], X[..., F[:, 2], :] - X[..., F[:, 0], :])
        S = sp.csr_matrix((np.ones(3 * len(F)), (F.T.ravel(), np.tile(np.arange(len(F)), 3))),
                          shape=(self.n_vertices, len(F)))
        if X.ndim == 2:
            out = S @ n
        else:
            out = np.stack([S @ ni for ni in n])
        return out / np.linalg.norm(out, axis=-1, keepdims=True)

    # ------------------------------------------------------------------ random poses and takes
    def random_angles(self, n, seed=0, spread=TRAINING_SPREAD, clean=False):
        """``(n, P)`` joint angles drawn uniformly in the middle ``spread`` fraction of every joint's range.

        One-sided joints (knees, elbows, fingers: lower limit 0) stay on their
        side; ``spread=1`` uses the full range.

        Parameters
        ----------
        n : int
        seed : int
        spread : float
        clean : bool or sequence of HumanBody
            Poses whose skinned surface does not pass through itself.  Linear-blend
            skinning folds the skin at large angles (inside a bent elbow or knee, under
            the chin when the head turns beyond about 17 degrees, between the fingers):
            after the draw, the poses are skinned and every pose with a pair of faces
            passing through each other (:func:`lacore.geometry.self_intersection.self_intersections`,
            less the pairs the rest pose already has) gets new angles for the joints of
            the bones of those faces (the whole pose when none of them has a joint), until
            no pose has one.  ``True`` checks this body's mesh; a sequence of bodies
            (restrictions of this one, :meth:`restrict`, e.g. the coarse body) checks
            their meshes too.  The joints' distribution is then the uniform one less
            the poses that pass through themselves.  The first draw is the one of
            ``clean=False``; the same ``seed`` gives the same poses.

        Returns
        -------
        (n, P) ndarray
            Radians, in the order of :data:`JOINT_DOFS`.

        Examples
        --------
        >>> from lacore.samples.human import load_human
        >>> body = load_human()                                     # doctest: +SKIP
        >>> angles = body.random_angles(30, seed=0, clean=True)      # doctest: +SKIP
        """
        rng = np.random.default_rng(seed)
        lo, hi = self._limits(spread)
        angles = lo + (hi - lo) * rng.random((int(n), self.n_dofs))
        if clean is not False:
            self._redraw_crossings(angles, rng, lo, hi, () if clean is True else tuple(clean))
        return angles

    def crossing_bones(self, vertices, bodies=()):
        """Bones of the faces passing through each other in a posed body and not in the rest pose.

        Parameters
        ----------
        vertices : (V, 3) array_like
            A pose of this body.
        bodies : sequence of HumanBody
            Restrictions of this body (:meth:`restrict`) whose meshes are checked too.

        Returns
        -------
        set of int
            Indices into :attr:`bones` of the dominant bones (:attr:`vertex_bone`) of the
            corners of every new pair of :func:`lacore.geometry.self_intersection.self_intersections`;
            empty when the pose passes through itself nowhere the rest pose does not.
        """
        out = set()
        X = np.asarray(vertices, float)
        for topology, subset, rest_keys, face_bones in self._crossing_checks(tuple(bodies)):
            out.update(_new_crossings(X if subset is None else X[subset], topology, rest_keys, face_bones))
        return out

    def _crossing_checks(self, bodies):
        """Per mesh checked (this body's and ``bodies``'): topology, vertex subset, rest pairs, face bones."""
        from ..geometry.self_intersection import self_intersections
        from ..geometry.topology import MeshTopology

        where = np.full(int(self.vertex_ids.max()) + 1, -1, np.int64)
        where[self.vertex_ids] = np.arange(self.n_vertices)
        checks = []
        for body in (self,) + bodies:
            subset = None if body is self else where[body.vertex_ids]
            if subset is not None and (subset < 0).any():
                raise ValueError("clean: a body to check is not a restriction of this one")
            topology = MeshTopology.from_faces(body.faces, n_vertices=body.n_vertices, allow_unreferenced=True)
            rest = self_intersections(body.vertices, topology, check=False)
            checks.append((topology, subset, rest[:, 0] * len(body.faces) + rest[:, 1], body.vertex_bone[body.faces]))
        return checks

    def _redraw_crossings(self, angles, rng, lo, hi, bodies, max_rounds=200):
        """Redraw, in place, the joints of the bones where a pose of ``angles`` passes through itself."""
        checks = self._crossing_checks(bodies)
        todo = np.arange(len(angles))
        for _ in range(max_rounds):
            if not len(todo):
                return
            X = self.pose(angles[todo])
            again = []
            for i, k in enumerate(todo):
                bones = set()
                for topology, subset, rest_keys, face_bones in checks:
                    bones.update(_new_crossings(X[i] if subset is None else X[i][subset], topology, rest_keys,
                                                face_bones))
                if not bones:
                    continue
                redraw = np.isin(self._dof_bone, list(bones))
                if not redraw.any():
                    redraw[:] = True
                angles[k, redraw] = lo[redraw] + (hi[redraw] - lo[redraw]) * rng.random(int(redraw.sum()))
                again.append(k)
            todo = np.array(again, np.int64)
        if len(todo):
            raise RuntimeError(f"random_angles(clean=...): {len(todo)} pose(s) still pass through themselves after "
                               f"{max_rounds} redraws: use a smaller spread")

    def _limits(self, spread):
        lo, hi = self.lower, self.upper
        one_sided = lo == 0
        mid = np.where(one_sided, 0.0, 0.5 * (lo + hi))
        half = np.where(one_sided, hi, 0.5 * (hi - lo)) * spread
        return np.where(one_sided, 0.0, mid - half), np.where(one_sided, half, mid + half)

    def random_poses(self, n, seed=0, spread=TRAINING_SPREAD, clean=False):
        """A training set: ``(n, V, 3)`` skinned vertices of :meth:`random_angles` and the angles ``(n, P)``.

        ``clean``: poses that do not pass through themselves (see :meth:`random_angles`).
        """
        angles = self.random_angles(n, seed, spread, clean)
        return self.pose(angles), angles

    def take_angles(self, n_frames, seed=0, spread=1.2, cycles=(0.5, 2.0)):
        """Smooth joint curves ``(T, P)`` for a held-out take.

        Every angle follows ``c + a sin(2 pi f s + phi)`` (``s`` from 0 to 1 over
        the take, ``f`` drawn from ``cycles``) with amplitude ``a`` reaching
        ``spread`` times the half-range of the training poses
        (:meth:`random_angles` with its default ``spread=0.8``), so parts of the
        take lie outside the training range; the result is clipped to the
        joint limits.
        """
        rng = np.random.default_rng(seed)
        lo, hi = self._limits(0.8)
        c = 0.5 * (lo + hi)
        amp = 0.5 * (hi - lo) * spread * rng.uniform(0.8, 1.0, self.n_dofs)
        f = rng.uniform(cycles[0], cycles[1], self.n_dofs)
        phi = rng.uniform(0, 2 * np.pi, self.n_dofs)
        s = np.linspace(0.0, 1.0, int(n_frames))[:, None]
        a = c + amp * np.sin(2 * np.pi * f * s + phi)
        return np.clip(a, self.lower, self.upper)

    def take(self, n_frames, seed=0, spread=1.2, walk_distance=20.0, turn=np.pi / 2):
        """A held-out take: smooth motion plus a walk of the whole body.

        The body walks ``walk_distance`` decimetres along a curve turning by
        ``turn`` radians about the vertical, with a small vertical bob.

        Returns
        -------
        vertices : (T, V, 3) ndarray
        angles : (T, P) ndarray
        root_rotation : (T, 3, 3) ndarray
        root_translation : (T, 3) ndarray
        """
        angles = self.take_angles(n_frames, seed, spread)
        s = np.linspace(0.0, 1.0, int(n_frames))
        yaw = turn * s
        root_R = Rotation.from_rotvec(np.outer(yaw, [0.0, 1.0, 0.0])).as_matrix()
        # path: forward along the current heading
        heading = np.column_stack([np.sin(yaw), np.zeros_like(s), np.cos(yaw)])
        ds = np.diff(s, prepend=0.0) * walk_distance
        root_t = np.cumsum(heading * ds[:, None], axis=0)
        root_t[:, 1] = 0.2 * np.sin(2 * np.pi * 4 * s)
        return self.pose(angles, root_R, root_t), angles, root_R, root_t

    def restrict(self, keep, faces):
        """The body on a vertex subset ``keep`` (indices into this body) with new ``faces``; weights carry over."""
        keep = np.asarray(keep, np.int64)
        return HumanBody(self.vertices[keep], np.asarray(faces, np.int64), self.vertex_ids[keep], self.bones,
                         self.parents, self.heads, self.tails, self.weights[keep])


def _new_crossings(X, topology, rest_keys, face_bones):
    """Dominant bones of the faces of the pairs of ``X`` passing through each other that the rest pose lacks."""
    from ..geometry.self_intersection import self_intersections

    pairs = self_intersections(X, topology, check=False)
    pairs = pairs[~np.isin(pairs[:, 0] * len(face_bones) + pairs[:, 1], rest_keys)]
    return np.unique(face_bones[pairs.ravel()]).tolist()


@functools.lru_cache(maxsize=4)
def _load_full(folder):
    folder = Path(folder)
    vertices, quads, groups = _read_obj(folder / "base.obj")
    rig = json.loads((folder / "rig.cmu_mb.json").read_text(encoding="utf-8"))
    weights = json.loads((folder / "weights.cmu_mb.json").read_text(encoding="utf-8"))["weights"]
    # bones in topological order (parents first), ties by name
    names, order = sorted(rig), []
    placed = set()
    while len(order) < len(names):
        for n in names:
            p = rig[n]["parent"]
            if n not in placed and (not p or p in placed):
                order.append(n)
                placed.add(n)
    index = {n: i for i, n in enumerate(order)}
    parents = np.array([index[rig[n]["parent"]] if rig[n]["parent"] else -1 for n in order], np.int64)
    heads = np.array([_joint_position(rig[n]["head"], vertices, groups) for n in order])
    tails = np.array([_joint_position(rig[n]["tail"], vertices, groups) for n in order])
    rows, cols, vals = [], [], []
    for n, pairs in weights.items():
        pairs = np.asarray(pairs, float).reshape(-1, 2)
        v = pairs[:, 0].astype(np.int64)
        use = v < N_BODY_VERTICES
        rows.append(v[use])
        cols.append(np.full(use.sum(), index[n]))
        vals.append(pairs[use, 1])
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(N_BODY_VERTICES, len(order)))
    W = sp.diags(1.0 / np.asarray(W.sum(axis=1)).ravel()) @ W  # sums are 1 up to the file's rounding
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return HumanBody(vertices[:N_BODY_VERTICES].copy(), faces, np.arange(N_BODY_VERTICES), order, parents, heads,
                     tails, W.tocsr())


def coarse_body_file():
    """Path of the committed coarse-body record, ``tests/data/human_coarse.npz``.

    It holds the :class:`~lacore.multiresolution.Coarsening` of the body
    (:meth:`~lacore.multiresolution.Coarsening.to_arrays`: kept vertices,
    coarse faces and every collapse, so prolongation to the full body works
    on any machine) and how it was made (``seed``, ``n_poses``,
    ``target_vertices``, ``base_obj_sha256``).
    """
    return Path(__file__).resolve().parents[2] / "tests" / "data" / "human_coarse.npz"


@functools.lru_cache(maxsize=2)
def coarse_human_coarsening(path=None):
    """The :class:`~lacore.multiresolution.Coarsening` of the coarse body (needed to prolong to the full one).

    Read from :func:`coarse_body_file` (stored, not recomputed: a greedy
    coarsening recomputed on another CPU can pick other, equally good
    collapses) and checked against the full body's faces.

    Raises
    ------
    FileNotFoundError
        No record (run ``scripts/make_coarse_human.py``).
    InputError
        The record is unreadable, or was made from another base mesh.
    """
    from ..errors import MeshError
    from ..multiresolution import Coarsening

    body = _load_full(str(human_data_dir(path)))
    f = coarse_body_file()
    if not f.is_file():
        raise FileNotFoundError(f"{f} not found: run scripts/make_coarse_human.py")
    c = Coarsening.load(f)
    if c.n_fine_vertices != body.n_vertices or not np.array_equal(c.fine_faces, body.faces):
        raise MeshError(f"{f} was made from another base mesh than {human_data_dir(path) / 'base.obj'}: "
                        "run scripts/make_coarse_human.py")
    return c


def training_file():
    """Path of the committed training record of :func:`human_model`, ``tests/data/human_training.npz``.

    It holds the clean joint angles (``angles``, ``(n_poses, P)`` radians) that
    :meth:`HumanBody.random_angles` draws with ``clean=(coarse body,)`` and the draw's
    inputs (``seed``, ``n_poses``, ``spread``, ``base_obj_sha256``); made and checked by
    ``scripts/make_human_training.py``.
    """
    return Path(__file__).resolve().parents[2] / "tests" / "data" / "human_training.npz"


def training_angles(n_poses=30, seed=0, path=None):
    """The clean joint angles ``(n_poses, P)`` of :func:`human_model`'s training poses.

    Read from :func:`training_file` when it was made with these inputs from this
    ``base.obj``, else drawn (:meth:`HumanBody.random_angles` with ``clean=(coarse
    body,)``).  Stored because the draw is decided by a geometric test (does a skinned
    pose pass through itself?) whose answer for a nearly touching pair of faces can
    depend on the CPU's rounding; a different answer redraws a joint and changes every
    later pose of the set.

    Parameters
    ----------
    n_poses, seed : int
    path : str or path-like, optional
        Data folder, see :func:`human_data_dir`.

    Returns
    -------
    (n_poses, P) ndarray
        Radians, in the order of :data:`JOINT_DOFS`.

    Examples
    --------
    >>> from lacore.samples.human import training_angles
    >>> training_angles(30, seed=0).shape                # doctest: +SKIP
    (30, 47)
    """
    f = training_file()
    if f.is_file():
        with np.load(f) as d:
            if (int(d["n_poses"]) == int(n_poses) and int(d["seed"]) == int(seed)
                    and float(d["spread"]) == TRAINING_SPREAD and str(d["base_obj_sha256"]) == base_obj_sha256(path)):
                return np.array(d["angles"], float)
    coarse = load_human(path, coarse=True)
    return load_human(path).random_angles(int(n_poses), seed=int(seed), spread=TRAINING_SPREAD, clean=(coarse,))


@functools.lru_cache(maxsize=2)
def _base_obj_sha256(folder):
    return hashlib.sha256((Path(folder) / "base.obj").read_bytes()).hexdigest()


def base_obj_sha256(path=None):
    """SHA-256 of the data folder's ``base.obj`` (hex): what stored records of the body were made from."""
    return _base_obj_sha256(str(human_data_dir(path)))


def human_model(n_poses=30, seed=0, path=None, clean=True):
    """A shape model of the coarse body trained on ``n_poses`` random poses, carrying its fine level.

    The poses are :meth:`HumanBody.random_poses` of the full body; with ``clean`` (the
    default) none passes through itself, on the full mesh or on the coarse one, so the
    model learns no fold of the skin (their angles are stored, :func:`training_angles`);
    ``clean=False`` gives the plain draw.

    The model (:class:`lacore.models.ShapeModel`, ambient tangent, rest pose as
    reference) declares its unit (decimetres: ``length_unit = 0.1``) and axes (``+y``
    up, ``+z`` forward) and holds a :class:`lacore.models.FineLevel` (the stored
    coarsening, the rest pose and the training poses as keys), so
    :func:`lacore.markers.fit_take` returns full-resolution poses.  A few seconds CPU (the clean angles are read,
    not drawn); cached per process (treat the result as read-only).

    Examples
    --------
    >>> from lacore.samples.human import human_model
    >>> model = human_model(n_poses=30)                 # doctest: +SKIP
    >>> model.length_unit, model.up_axis, model.fine_level.n_fine_vertices  # doctest: +SKIP
    (0.1, 'y', 13380)
    """
    return _human_model(int(n_poses), int(seed), None if path is None else str(path), bool(clean))


@functools.lru_cache(maxsize=2)
def _human_model(n_poses, seed, path, clean=True):
    from ..models import FineLevel, ShapeModel

    full = load_human(path)
    coarse = load_human(path, coarse=True)
    c = coarse_human_coarsening(path)
    angles = training_angles(n_poses, seed, path) if clean else full.random_angles(n_poses, seed, TRAINING_SPREAD)
    fine_poses = full.pose(angles)
    model = ShapeModel.fit(fine_poses[:, c.vertex_indices], coarse.faces, reference_vertices=coarse.vertices)
    model.fine_level = FineLevel.build(c, full.vertices, fine_poses, model.training_coefficients)
    model.length_unit, model.up_axis, model.forward_axis = 0.1, "y", "z"
    return model


def load_human(path=None, coarse=False):
    """The human body of ``shared/data/human`` (see :func:`human_data_dir` for ``path``).

    Parameters
    ----------
    path : str or path-like, optional
    coarse : bool
        The coarse body (a vertex subset of the full one with its own faces,
        made by ``scripts/make_coarse_human.py`` and stored in
        :func:`coarse_body_file`).

    Returns
    -------
    HumanBody
    """
    body = _load_full(str(human_data_dir(path)))
    if not coarse:
        return body
    c = coarse_human_coarsening(path)
    return body.restrict(c.vertex_indices, c.faces)


@functools.lru_cache(maxsize=2)
def _joint_centres(folder):
    """Centres of the ``joint-*`` cube groups of ``base.obj`` (eyelids, mouth, ... are not bones)."""
    vertices, _, groups = _read_obj(Path(folder) / "base.obj")
    return {name: vertices[idx].mean(axis=0) for name, idx in groups.items()}


def open_body(body=None, radius=0.07, path=None):
    """The full body with five openings: both eyes, the mouth and both wrists (the hands cut off).

    A surface of genus 0 with five boundary loops (about 10k vertices), for
    the conditions of Theorem 3.2 around holes.  The eye openings are centred
    at the body vertex nearest to the middle of the eyelid joints, the mouth at
    the front-most vertex of the mid-plane at the height of the mouth joint
    (all within ``radius``, decimetres); the hands are cut by the plane through
    the wrist (the ``LeftHand``/``RightHand`` bone head) normal to the forearm.
    Faces left at pinched vertices are dropped as well (:func:`lacore.samples.surfaces.open_holes`).

    Parameters
    ----------
    body : HumanBody, optional
        The full body (default :func:`load_human`).
    radius : float
    path : str or path-like, optional
        Data folder, see :func:`human_data_dir`.

    Returns
    -------
    HumanBody
        The opened body (:meth:`HumanBody.restrict`): posable like the full one.
    """
    from .surfaces import open_holes

    body = load_human(path) if body is None else body
    if len(body.vertices) != N_BODY_VERTICES:
        raise ValueError("open_body needs the full body (load_human(coarse=False))")
    centres = _joint_centres(str(human_data_dir(path)))
    X = body.vertices
    holes = []
    for side in ("l", "r"):
        lids = 0.5 * (centres[f"joint-{side}-upperlid"] + centres[f"joint-{side}-lowerlid"])
        holes.append(X[np.argmin(np.linalg.norm(X - lids, axis=1))])
    mouth = centres["joint-mouth"]
    mid = np.flatnonzero((np.abs(X[:, 0] - mouth[0]) < 0.05) & (np.abs(X[:, 1] - mouth[1]) < 0.03))
    holes.append(X[mid[np.argmax(X[mid, 2])]])
    keep = np.ones(len(body.faces), bool)
    index = {name: i for i, name in enumerate(body.bones)}
    for hand, forearm in (("LeftHand", "LeftForeArm"), ("RightHand", "RightForeArm")):
        wrist = body.heads[index[hand]]
        axis = wrist - body.heads[index[forearm]]
        axis /= np.linalg.norm(axis)
        cut = ((X - wrist) @ axis > -0.1) & (np.linalg.norm(X - wrist, axis=1) < 1.5)
        keep &= ~cut[body.faces].any(axis=1)
    _, faces, kept = open_holes(X, body.faces[keep], holes, radius)
    return body.restrict(kept, faces)
