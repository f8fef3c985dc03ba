#!/usr/bin/env python3
"""Make the coarse human body: groupwise quadric-error coarsening of several skinned poses (thesis 2.3).

The full body of ``shared/data/human`` (13,380 vertices) is posed by
:mod:`lacore.samples.human` (the rest pose plus ``--poses`` random poses from
``--seed``, the training spread) and coarsened with
:func:`lacore.multiresolution.coarsen` by half-edge collapses whose quadric
error is summed over all poses, so the coarse mesh suits every pose.  Coarse
vertices are a subset of the fine ones: skinning weights carry over by index.

Writes ``tests/data/human_coarse.npz``: the coarsening record
(:meth:`lacore.multiresolution.Coarsening.to_arrays`: kept vertices, coarse
faces, every collapse, so prolongation to the full body needs no recomputation)
and how it was made (``seed``, ``n_poses``, ``target_vertices``,
``base_obj_sha256``); prints one JSON object.

The collapse order is greedy: costs are compared rounded, so exact ties do not
depend on the CPU, but a cost within rounding of a rounding boundary, or a file
made by another version of the coarsening, gives another, equally good coarse
body.  ``--check`` therefore recomputes and compares what matters within
tolerances, not the bits: the same
counts and topology, collapse costs (total and largest) within
``COST_RTOL``, and the error of prolonging a held-out take from each coarse
body within ``PROLONGATION_RTOL`` of the stored one's.

usage: python scripts/make_coarse_human.py [--vertices 2500] [--poses 8] [--seed 7] [--check]
"""

import argparse
import json
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from lacore import MeshTopology  # noqa: E402
from lacore.io.atomic import save_npz_atomic  # noqa: E402
from lacore.multiresolution import Coarsening, Prolongation, coarsen  # noqa: E402
from lacore.samples.human import base_obj_sha256, coarse_body_file, load_human  # noqa: E402

#: Relative tolerance of the collapse costs (sum and largest) of a recomputed coarsening (measured across
#: kernels: 2.2e-4 for the sum, 1.6e-12 for the largest; against the stored file, made when equal costs were
#: ordered by their rounding: 9.4e-3 and 8.5e-3; a real regression of the coarsening moves them more).
COST_RTOL = 0.01
#: Relative tolerance of the mean prolongation error (held-out take) of a recomputed coarsening (measured 1.1e-5).
PROLONGATION_RTOL = 0.05


def prolongation_error_mm(coarsening, body, take):
    """Mean distance (mm) between a take's frames and their prolongation from the coarse vertices (rest-pose keys)."""
    p = Prolongation(coarsening, body.vertices)
    Y = np.array([p(x[coarsening.vertex_indices]) for x in take])
    return float(np.linalg.norm(Y - take, axis=2).mean() * 100.0)  # decimetres -> mm


def compare(stored, recomputed, body):
    """Measures of a recomputed coarsening against the stored one; ``(measures, ok)``."""
    take = body.take(4, seed=1)[0]
    topo = [MeshTopology.from_faces(c.faces, n_vertices=c.n_vertices) for c in (stored, recomputed)]
    costs = [(float(np.sum(c.costs)), float(np.max(c.costs))) for c in (stored, recomputed)]
    err = [prolongation_error_mm(c, body, take) for c in (stored, recomputed)]
    m = {"same_counts": stored.n_vertices == recomputed.n_vertices and len(stored.faces) == len(recomputed.faces),
         "same_topology": bool(topo[0].is_closed == topo[1].is_closed
                               and np.array_equal(topo[0].genus(), topo[1].genus())),
         "shared_vertices": float(np.isin(recomputed.vertex_indices, stored.vertex_indices).mean()),
         "cost_sum_relative_difference": abs(costs[1][0] / costs[0][0] - 1.0),
         "cost_max_relative_difference": abs(costs[1][1] / costs[0][1] - 1.0),
         "prolongation_error_mm": err,
         "prolongation_relative_difference": abs(err[1] / err[0] - 1.0)}
    ok = (m["same_counts"] and m["same_topology"] and m["cost_sum_relative_difference"] <= COST_RTOL
          and m["cost_max_relative_difference"] <= COST_RTOL
          and m["prolongation_relative_difference"] <= PROLONGATION_RTOL)
    return m, bool(ok)


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
    topo = MeshTopology.from_faces(result.faces, n_vertices=result.n_vertices)  # validates: manifold, oriented
    digest = base_obj_sha256()
    made = {"seed": np.array(args.seed), "n_poses": np.array(args.poses), "target_vertices": np.array(args.vertices),
            "base_obj_sha256": np.array(digest)}
    summary = {"vertices": int(result.n_vertices), "faces": int(len(result.faces)), "edges": int(topo.n_edges),
               "closed": bool(topo.is_closed), "genus": topo.genus().tolist(),
               "poses": args.poses + 1, "seed": args.seed, "coarsening_seconds": round(result.seconds, 3),
               "output": args.output}
    if args.check:
        stored = Coarsening.load(args.output)
        with np.load(args.output) as old:
            same_inputs = all(k in old.files and np.array_equal(old[k], v) for k, v in made.items())
        measures, ok = compare(stored, result, body)
        summary.update(measures, same_inputs=same_inputs, reproduced=bool(ok and same_inputs),
                       seconds=round(time.perf_counter() - t0, 3))
        print(json.dumps(summary))
        return 0 if summary["reproduced"] else 1
    summary["output"] = save_npz_atomic(args.output, compressed=True, **result.to_arrays(), **made)
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
