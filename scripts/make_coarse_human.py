#!/usr/bin/env python3
"""Make the coarse human body: groupwise quadric-error coarsening of several skinned poses (thesis 2.3).

The full body of ``shared/data/human`` (13,380 vertices) is posed by
:mod:`lacore.samples.human` (the rest pose plus ``--poses`` random poses from
``--seed``, the training spread) and coarsened with
:func:`lacore.multiresolution.coarsen` by half-edge collapses whose quadric
error is summed over all poses, so the coarse mesh suits every pose.  Coarse
vertices are a subset of the fine ones: skinning weights carry over by index.

Writes ``tests/data/human_coarse.npz`` (``kept_vertices`` = fine vertex ids,
``faces`` in coarse indexing, and how they were made: ``seed``, ``n_poses``,
``target_vertices``, ``base_obj_sha256``) and the coarsening record (``coarsening_*``, see
:meth:`lacore.multiresolution.Coarsening.to_arrays`), and prints one JSON object.  The
result is deterministic: re-running with the same arguments reproduces the file
(``--check`` compares instead of writing).

usage: python scripts/make_coarse_human.py [--vertices 2500] [--poses 8] [--seed 7] [--check]
"""

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from lacore import MeshTopology  # noqa: E402
from lacore.multiresolution import coarsen  # noqa: E402
from lacore.samples.human import coarse_body_file, human_data_dir, load_human  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=2500, help="target coarse vertex count (default 2500)")
    ap.add_argument("--poses", type=int, default=8, help="random poses besides the rest pose (default 8)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--output", default=str(coarse_body_file()))
    ap.add_argument("--check", action="store_true", help="compare with the existing file instead of writing")
    args = ap.parse_args()
    t0 = time.perf_counter()
    body = load_human()
    poses, _ = body.random_poses(args.poses, seed=args.seed)
    shapes = np.concatenate([body.vertices[None], poses])
    result = coarsen(shapes, body.faces, args.vertices)
    kept = np.asarray(result.vertex_indices, np.int64)
    faces = np.asarray(result.faces, np.int64)
    topo = MeshTopology.from_faces(faces, n_vertices=len(kept))  # validates: manifold, oriented
    digest = hashlib.sha256((human_data_dir() / "base.obj").read_bytes()).hexdigest()
    data = {"kept_vertices": kept, "faces": faces, "seed": np.array(args.seed), "n_poses": np.array(args.poses),
            "target_vertices": np.array(args.vertices), "base_obj_sha256": np.array(digest)}
    data.update(result.to_arrays("coarsening_"))  # the record prolongation needs: stored, never recomputed
    summary = {"vertices": int(len(kept)), "faces": int(len(faces)), "edges": int(topo.n_edges),
               "closed": bool(topo.is_closed), "genus": topo.genus().tolist(),
               "poses": args.poses + 1, "seed": args.seed, "coarsening_seconds": round(result.seconds, 3),
               "seconds": round(time.perf_counter() - t0, 3), "output": args.output}
    if args.check:
        with np.load(args.output) as old:
            same = all(np.array_equal(old[k], v) for k, v in data.items())
        summary["reproduced"] = bool(same)
        print(json.dumps(summary))
        return 0 if same else 1
    folder = os.path.dirname(os.path.abspath(args.output))
    fd, tmp = tempfile.mkstemp(suffix=".npz", dir=folder)
    with os.fdopen(fd, "wb") as fh:
        np.savez_compressed(fh, **data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, args.output)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
