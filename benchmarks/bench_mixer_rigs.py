"""Benchmark of the shape mixer on keys as rigs have them: limited to a vertex group, relative to another key.

The figures of :mod:`bench_mixer` (build, ms per mix, RMS % of the diagonal and energy against converged full
Gauss-Newton of the same blend, ``z_0 + sum_k w_k m_k (z_k - z_rel(k))``) for the CC0 rigged body (13,380
vertices, :func:`lacore.samples.human.load_human`), with the public defaults:

* ``human13k_masked``: the keys of ``bench_mixer``'s ``human13k`` (left arm raised by 70 degrees, right knee bent by
  35, torso twisted: :data:`lacore.samples.human.POSE_KEYS`) with the torso's twist limited to the upper body by a
  ramp of vertex-group weights, 0 at the hips' joint rising to 1 at the chest's (``Spine1``), as a rigger paints
  a twist that leaves the legs;
* ``human13k_relative``: the arm raised, a corrective relative to it (the arm raised with the elbow bent by 40
  degrees: the corrective adds the bend) and the knee bent.  A corrective is driven by its key, so its weight is at
  most the arm's: the measured weights are ``bench_mixer``'s with the corrective's replaced by that fraction of the
  arm's (weights in ``[-0.5, 1.5]`` mapped to ``[0, 1]`` first).  A corrective above its key is the key's anti-pose
  plus the bend, where even converged Gauss-Newton folds faces; such weights are not measured.

References are computed once and cached like ``bench_mixer``'s (``--reference DIR``); each case is measured in a
process of its own.  Prints one JSON object; run with ``OPENBLAS_NUM_THREADS=1`` for one core.

usage: python benchmarks/bench_mixer_rigs.py [human13k_masked] [human13k_relative] [--references N] [--repeats R]
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

from bench_mixer import run  # noqa: E402

MESHES = ("human13k_masked", "human13k_relative")


def corrective_weights(W, n_in, corrective=1, key=0):
    """``W`` with the weight of key ``corrective`` replaced by a fraction of key ``key``'s: the fraction is the weight
    itself in ``[0, 1]`` (the first ``n_in`` rows) and ``(w + 0.5) / 2`` outside."""
    W = np.array(W, float)
    fraction = W[:, corrective].copy()
    fraction[n_in:] = (fraction[n_in:] + 0.5) / 2.0
    W[:, corrective] = fraction * W[:, key]
    return W


def rig_case(name):
    """``(keys, faces, blend, weights)`` of a case of :data:`MESHES` (:func:`bench_mixer.bench_mesh`)."""
    from lacore.samples.human import POSE_KEYS, dof_angles, load_human, pose_keys

    body = load_human()
    if name == "human13k_masked":
        _, keys = pose_keys(body)
        y = body.vertices[:, 1]
        hips, chest = (body.heads[body.bone_index(b)][1] for b in ("Hips", "Spine1"))
        masks = np.ones((len(keys) - 1, len(y)))
        masks[2] = np.clip((y - hips) / (chest - hips), 0.0, 1.0)  # the torso's twist
        return keys, body.faces, {"masks": masks}, None
    if name == "human13k_relative":
        arm, knee = POSE_KEYS[0][1], POSE_KEYS[1][1]
        bent = {**arm, ("LeftForeArm", "swing", "parent"): 40.0}
        keys = np.stack([body.vertices, *(body.pose(dof_angles(a)) for a in (arm, bent, knee))])
        return keys, body.faces, {"relative_to": np.array([0, 1, 0])}, corrective_weights
    raise KeyError(name)


def main(argv=None):
    run(argv, MESHES, __doc__.split("\n")[0],
        "shape mixer on rig keys (a vertex group, a relative key): build, ms per mix, RMS % of the diagonal against "
        "converged full Gauss-Newton, energy goal, memory", case=rig_case, script=__file__)


if __name__ == "__main__":
    main()
