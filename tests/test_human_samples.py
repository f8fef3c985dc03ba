"""lacore.samples.human: the skinned CC0 body, its seeded training poses and held-out takes."""

import numpy as np
import pytest
from conftest import shared_data_dir

from lacore import MeshTopology
from lacore.samples.human import (JOINT_DOFS, LIMBS, N_BODY_VERTICES, POSE_KEYS, TRAINING_SPREAD, base_obj_sha256,
                                  dof_angles, human_data_dir, load_human, pose_keys, training_angles, training_file)


@pytest.fixture(scope="module")
def body():
    return load_human(shared_data_dir())


def test_body_mesh_skeleton_and_weights(body):
    assert body.vertices.shape == (N_BODY_VERTICES, 3) and body.faces.shape == (26756, 3)
    topo = MeshTopology.from_faces(body.faces, n_vertices=body.n_vertices)
    assert topo.is_closed and topo.genus().tolist() == [0]
    X, F = body.vertices, body.faces
    volume = np.einsum("ij,ij->", X[F[:, 0]], np.cross(X[F[:, 1]], X[F[:, 2]])) / 6
    assert volume > 50  # outward (dm^3; measured 54.9)
    assert len(body.bones) == 31 and body.parents[0] == -1
    assert all(body.parents[b] < b for b in range(1, 31))  # parents first
    np.testing.assert_allclose(np.asarray(body.weights.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert {b for limb in LIMBS.values() for b in limb} == set(body.bones)
    # the skeleton sits inside the body: pelvis between the hips, head above the neck
    assert body.heads[body.bone_index("Head")][1] > body.heads[body.bone_index("Neck")][1] > \
        body.heads[body.bone_index("Hips")][1]
    assert human_data_dir(shared_data_dir() / "meshes") == human_data_dir(shared_data_dir())


def test_posing_is_linear_blend_skinning(body):
    rest = body.pose(np.zeros(body.n_dofs))
    assert np.abs(rest - body.vertices).max() < 1e-12
    angles = body.random_angles(2, seed=3)
    X = body.pose(angles)
    R, t = body.bone_transforms(angles)
    v = np.array([0, 5000, 9000, 13000])
    W = body.weights[v].toarray()
    expected = np.einsum("vb,tbij,vj->tvi", W, R, body.vertices[v]) + np.einsum("vb,tbi->tvi", W, t)
    assert np.abs(X[:, v] - expected).max() < 1e-12
    assert np.allclose(np.linalg.det(R), 1.0) and np.abs(R @ R.transpose(0, 1, 3, 2) - np.eye(3)).max() < 1e-12
    # connected bones stay connected: the posed tail of a parent is the posed head of its child
    heads = body.joint_positions(angles)
    for b in range(1, len(body.bones)):
        p = body.parents[b]
        if np.allclose(body.tails[p], body.heads[b]):
            tail = np.einsum("tij,j->ti", R[:, p], body.tails[p]) + t[:, p]
            assert np.abs(tail - heads[:, b]).max() < 1e-12


def test_joints_bend_the_anatomical_way(body):
    i = [k for k, d in enumerate(JOINT_DOFS) if d[0] == "LeftLeg"][0]
    a = np.zeros(body.n_dofs)
    a[i] = np.radians(90)
    foot = body.bone_index("LeftFoot")
    rest, bent = body.joint_positions(np.zeros(body.n_dofs))[foot], body.joint_positions(a)[foot]
    assert bent[2] < rest[2] - 2 and bent[1] > rest[1] + 2  # knee: the foot goes back and up (dm)
    i = [k for k, d in enumerate(JOINT_DOFS) if d[0] == "RightForeArm" and d[1] == "swing"][0]
    a = np.zeros(body.n_dofs)
    a[i] = np.radians(90)
    hand = body.bone_index("RightHand")
    rest, bent = body.joint_positions(np.zeros(body.n_dofs))[hand], body.joint_positions(a)[hand]
    shoulder = body.joint_positions(a)[body.bone_index("RightArm")]
    assert np.linalg.norm(bent - shoulder) < np.linalg.norm(rest - shoulder) - 1.0  # elbow: the hand comes closer
    assert bent[1] > rest[1] + 1.5  # and up
    hinges = [k for k, d in enumerate(JOINT_DOFS) if d[0] in ("LeftLeg", "RightForeArm") and d[1] == "swing"]
    assert np.all(body.lower[hinges] == 0)  # one-sided


def test_pose_keys_move_only_their_limbs(body):
    names, keys = pose_keys(body)
    assert names == ["Basis", "ArmRaised", "KneeBent", "TorsoTwisted"] and keys.shape == (4, N_BODY_VERTICES, 3)
    assert np.array_equal(keys[0], body.vertices)
    moved = np.linalg.norm(keys[1:] - keys[0], axis=2)  # (3, V) dm
    bone = np.array(body.bones)[body.vertex_bone]
    left_arm = np.isin(bone, LIMBS["left_arm"])
    # the raised arm lifts the left hand by several decimetres, leaves the legs; the knee moves the right foot only
    assert moved[0][bone == "LeftHand"].min() > 3.0 and moved[0][np.isin(bone, LIMBS["left_leg"])].max() < 1e-12
    assert moved[1][bone == "RightFoot"].min() > 1.0 and moved[1][left_arm].max() < 1e-12
    assert moved[2][bone == "RightFoot"].max() < 1e-12 and moved[2][bone == "Head"].min() > 0.05
    a = dof_angles(POSE_KEYS[0][1])
    assert np.count_nonzero(a) == 1 and np.isclose(np.degrees(a.max()), 70.0)
    with pytest.raises(ValueError, match="not a joint angle"):
        dof_angles({("LeftArm", "swing", "sideways"): 10.0})


def test_training_sets_and_takes_are_seeded(body):
    X1, A1 = body.random_poses(4, seed=11)
    X2, A2 = body.random_poses(4, seed=11)
    np.testing.assert_array_equal(X1, X2)
    assert not np.allclose(body.random_angles(4, seed=12), A1)
    lo, hi = body._limits(0.8)
    assert np.all((A1 >= lo) & (A1 <= hi))
    T = 60
    X, angles, root_R, root_t = body.take(T, seed=5)
    assert X.shape == (T, N_BODY_VERTICES, 3) and angles.shape == (T, body.n_dofs)
    np.testing.assert_array_equal(body.take(T, seed=5)[1], angles)
    assert np.all((angles >= body.lower - 1e-12) & (angles <= body.upper + 1e-12))
    outside = (angles < lo - 1e-9) | (angles > hi + 1e-9)
    assert 0.1 < outside.mean() < 0.3  # partly outside the training range (measured 0.19)
    # smooth: |d angle / d frame| <= 2 pi f_max a_max / (T - 1) with f_max = 2 cycles, a_max = 1.2 half-ranges
    bound = 2 * np.pi * 2 * 1.2 * np.max(0.5 * (hi - lo)) / (T - 1)
    assert np.abs(np.diff(angles, axis=0)).max() <= bound
    travelled = np.linalg.norm(root_t[-1, [0, 2]] - root_t[0, [0, 2]])
    assert 12 < travelled < 20  # a 20 dm walk along a quarter-turn arc (chord 18)
    # the body moves with the root: pelvis follows the path
    pelvis = body.joint_positions(angles, root_R, root_t)[:, 0]
    np.testing.assert_allclose(pelvis - pelvis[0], root_t - root_t[0], atol=1e-12)


def test_vertex_normals_point_outward(body):
    X = body.pose(body.random_angles(2, seed=9))
    N = body.vertex_normals(X)
    assert N.shape == X.shape
    np.testing.assert_allclose(np.linalg.norm(N, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(body.vertex_normals(X[1]), N[1], atol=1e-15)
    # outward: moving every vertex a little along its normal increases the enclosed volume
    F = body.faces

    def volume(Y):
        return np.einsum("ij,ij->", Y[F[:, 0]], np.cross(Y[F[:, 1]], Y[F[:, 2]])) / 6

    assert volume(X[0] + 0.01 * N[0]) - volume(X[0]) > 1.0  # measured 1.58 dm^3 = 0.01 dm x 160 dm^2 of skin


def _new_pairs(body, X):
    """Face pairs of a pose passing through each other that the rest pose does not have."""
    from lacore.geometry.self_intersection import self_intersections
    rest = {tuple(p) for p in self_intersections(body.vertices, body.faces)}
    return [p for p in map(tuple, self_intersections(X, body.faces)) if p not in rest]


def test_skinning_folds_the_chin_and_the_elbow(body):
    # linear-blend skinning passes the skin through itself beyond moderate angles: the head turned 25 degrees
    # folds the skin under the chin, the elbow bent 90 degrees folds it inside the crease; 10 degrees of either do not
    idx = {d[:2] + ((d[2],) if d[1] == "swing" else ()): k for k, d in enumerate(JOINT_DOFS)}
    for key, bone, small, large in ((("Head", "twist"), "Head", 10, 25),
                                    (("LeftForeArm", "swing", "parent"), "LeftForeArm", 10, 90)):
        a = np.zeros((2, body.n_dofs))
        a[:, idx[key]] = np.radians([small, large])
        X = body.pose(a)
        assert body.crossing_bones(X[0]) == set()
        crossing = {body.bones[b] for b in body.crossing_bones(X[1])}
        assert bone in crossing, crossing   # measured: head twist 25 -> 24 pairs, elbow 90 -> 56 pairs


def test_clean_random_poses_do_not_pass_through_themselves(body):
    coarse = load_human(shared_data_dir(), coarse=True)
    n = 6
    raw = body.random_angles(n, seed=7)
    angles = body.random_angles(n, seed=7, clean=(coarse,))
    np.testing.assert_array_equal(body.random_angles(n, seed=7, clean=(coarse,)), angles)   # seeded
    X, A = body.random_poses(n, seed=7, clean=(coarse,))
    np.testing.assert_array_equal(A, angles)
    lo, hi = body._limits(0.8)
    assert np.all((angles >= lo) & (angles <= hi))
    # the plain draw passes through itself (measured: all 6 poses, 40-190 face pairs each); the clean one nowhere,
    # on the full mesh and on the coarse one, beyond the pairs of the rest pose (none full, 11 coarse: lips, nostrils)
    assert sum(bool(body.crossing_bones(Y)) for Y in body.pose(raw)) >= 4
    for Y in X:
        assert _new_pairs(body, Y) == []
        assert _new_pairs(coarse, Y[coarse.vertex_ids]) == []
    # only the joints of folding bones were redrawn: the first draw's other angles stay
    assert 0.3 < np.mean(raw == angles) < 1.0


def test_stored_training_angles_are_the_clean_draw(body):
    """human_model's training angles are read from tests/data/human_training.npz (made by
    scripts/make_human_training.py): the inputs it records are this base.obj's and the default draw's, its poses
    pass through themselves nowhere on either mesh, and other inputs are drawn, not read."""
    coarse = load_human(shared_data_dir(), coarse=True)
    with np.load(training_file()) as d:
        assert int(d["n_poses"]) == 30 and int(d["seed"]) == 0 and float(d["spread"]) == TRAINING_SPREAD
        assert str(d["base_obj_sha256"]) == base_obj_sha256(shared_data_dir())
        stored = np.array(d["angles"])
    angles = training_angles(30, 0, shared_data_dir())
    np.testing.assert_array_equal(angles, stored)
    assert angles.shape == (30, len(JOINT_DOFS))
    lo, hi = body._limits(TRAINING_SPREAD)
    assert np.all((angles >= lo) & (angles <= hi))
    # the stored poses are clean with this CPU's kernels (the plain draw of seed 0 is not: measured 30 of 30 fold)
    assert all(body.crossing_bones(Y, (coarse,)) == set() for Y in body.pose(angles))
    assert np.mean(body.random_angles(30, seed=0) == angles) < 1.0
    # other inputs are drawn
    np.testing.assert_array_equal(training_angles(2, 5, shared_data_dir()),
                                  body.random_angles(2, seed=5, clean=(coarse,)))
