#!/usr/bin/env python3
"""Benchmark: encoding (topology, lengths & angles, integrability) of the shared meshes.

Prints a table and writes one JSON object per mesh to stdout's last lines.
usage: python benchmarks/bench_encode.py [--repeat 5]
"""

import argparse
import json
import os
import statistics
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from bench_common import machine_info, shared_meshes_dir  # noqa: E402

from lacore.cli import encode_mesh  # noqa: E402
from lacore.io.meshes import load_mesh  # noqa: E402

MESHES = ["sphere/unitSphere1.ply", "plate/plate121.ply", "sphere/defSphere0.ply", "plate/plate4SD.ply",
          "finger/finger0.ply"]


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    rows = []
    for rel in MESHES:
        X, faces = load_mesh(os.path.join(shared_meshes_dir(), rel))
        runs = [encode_mesh(X, faces)[3] for _ in range(args.repeat)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        rows.append({"mesh": rel, "vertices": len(X), "faces": len(faces),
                     **{f"{k}_ms": 1e3 * v for k, v in med.items()}})
    print(json.dumps({"benchmark": "encode (topology + z + integrability, median ms)", "machine": machine_info(),
                      "repeats": args.repeat, "meshes": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
