"""Benchmark of the shape mixer by the number of keys: build, ms per mix, accuracy and memory with 4 to 6 keys.

The figures of :mod:`bench_mixer` (build, ms per mix, RMS % of the diagonal and energy against converged full
Gauss-Newton, the mixer's size and the build's peak memory growth, each case in a process of its own) for the CC0
rigged body (13,380 vertices, :func:`lacore.samples.human.load_human`) with the public defaults and more pose keys
than ``bench_mixer``'s ``human13k`` (its three, :data:`lacore.samples.human.POSE_KEYS`, then the right arm raised,
the left knee bent and the head turned: :data:`MORE_POSES`):

* ``human13k_k5``, ``human13k_k6``, ``human13k_k7``: the basis and the first 4, 5 and 6 poses.

Every slider moves at once at the measured weights (:func:`bench_mixer.reference_weights`), the hardest case;
:attr:`lacore.MixerOptions.max_keys` (6) is the largest measured.  References are computed once and cached like
``bench_mixer``'s (``--reference DIR``).  Prints one JSON object; run with ``OPENBLAS_NUM_THREADS=1`` for one core.

usage: python benchmarks/bench_mixer_keys.py [human13k_k5] [human13k_k6] [human13k_k7] [--references N]
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

from bench_mixer import run  # noqa: E402

MESHES = ("human13k_k5", "human13k_k6", "human13k_k7")

#: Poses after :data:`lacore.samples.human.POSE_KEYS`, in the order they join (names and joint angles in degrees).
MORE_POSES = (
    ("RightArmRaised", {("RightArm", "swing", "up"): 70.0}),
    ("LeftKneeBent", {("LeftLeg", "swing", "backward"): 60.0}),
    ("HeadTurned", {("Head", "twist", None): 40.0}),
)


def keys_case(name):
    """``(keys, faces, blend, weights)`` of a case of :data:`MESHES` (:func:`bench_mixer.bench_mesh`)."""
    from lacore.samples.human import POSE_KEYS, load_human, pose_keys

    n = int(name.rsplit("_k", 1)[1]) - 1
    body = load_human()
    _, keys = pose_keys(body, (POSE_KEYS + MORE_POSES)[:n])
    return keys, body.faces, {}, None


def main(argv=None):
    run(argv, MESHES, __doc__.split("\n")[0],
        "shape mixer by the number of keys: build, ms per mix, RMS % of the diagonal against converged full "
        "Gauss-Newton, energy goal, memory", case=keys_case, script=__file__)


if __name__ == "__main__":
    main()
