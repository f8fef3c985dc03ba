#!/usr/bin/env python3
"""Make the training record of the sample body's shape model: the clean joint angles of its training poses.

:func:`lacore.samples.human.human_model` trains on poses drawn by
:meth:`lacore.samples.human.HumanBody.random_angles` with ``clean=(coarse body,)``:
poses whose skin passes through itself, on the full or the coarse mesh, get some joints
redrawn.  Whether a skinned pose passes through itself is a geometric test; for a pair
of faces that nearly touch, its answer can depend on the CPU's rounding, and a
different answer redraws a joint and changes every later pose of the set.  So the
angles are stored, like the coarse body.

Writes ``tests/data/human_training.npz`` (``angles (n_poses, P)`` radians, ``seed``,
``n_poses``, ``spread``, ``base_obj_sha256``) and prints one JSON object.  ``--check``
draws again and compares instead of writing: ``reproduced`` when this CPU draws the
same angles (within ``ANGLE_ATOL``), ``stored_clean`` when the stored poses pass
through themselves nowhere the rest pose does not, on either mesh, with this CPU's
kernels; it fails (exit status 1) when the record was made from other inputs or its
poses are not clean here (another draw alone is no failure: that is why it is stored).

usage: python scripts/make_human_training.py [--poses 30] [--seed 0] [--check]
"""

import argparse
import json
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from lacore.io.atomic import save_npz_atomic  # noqa: E402
from lacore.samples.human import TRAINING_SPREAD, base_obj_sha256, load_human, training_file  # noqa: E402

#: Largest difference (radians) between stored and redrawn angles that counts as the same draw.
ANGLE_ATOL = 1e-12


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=30, help="training poses (default 30, human_model's)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the draw (default 0, human_model's)")
    ap.add_argument("--output", default=str(training_file()))
    ap.add_argument("--check", action="store_true", help="compare with the existing file instead of writing")
    args = ap.parse_args()
    t0 = time.perf_counter()
    body, coarse = load_human(), load_human(coarse=True)
    angles = body.random_angles(args.poses, seed=args.seed, spread=TRAINING_SPREAD, clean=(coarse,))
    made = {"seed": np.array(args.seed), "n_poses": np.array(args.poses), "spread": np.array(TRAINING_SPREAD),
            "base_obj_sha256": np.array(base_obj_sha256())}
    summary = {"poses": args.poses, "seed": args.seed, "spread": TRAINING_SPREAD, "output": args.output}
    if args.check:
        with np.load(args.output) as d:
            stored = np.array(d["angles"], float)
            same_inputs = all(k in d.files and np.array_equal(d[k], v) for k, v in made.items())
        X = body.pose(stored)
        crossing = [sorted(body.crossing_bones(x, (coarse,))) for x in X]
        summary.update(same_inputs=bool(same_inputs),
                       largest_angle_difference=float(np.abs(stored - angles).max()) if stored.shape == angles.shape
                       else None,
                       stored_clean=not any(crossing), poses_crossing=[i for i, c in enumerate(crossing) if c])
        summary["reproduced"] = bool(same_inputs and summary["largest_angle_difference"] is not None
                                     and summary["largest_angle_difference"] <= ANGLE_ATOL)
        summary["seconds"] = round(time.perf_counter() - t0, 3)
        print(json.dumps(summary))
        return 0 if same_inputs and summary["stored_clean"] else 1
    summary["output"] = save_npz_atomic(args.output, compressed=True, angles=angles, **made)
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
