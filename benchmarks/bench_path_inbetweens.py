#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: in-betweens of two keys by the reduced model of their path (``lacore.shapes.mixing.path_inbetweens``)
against the full projection.

Meshes and keys of ``bench_mixer.py`` (``bar50k``: the 50k box bar, keys rest, bent 90 degrees, twisted 90 degrees;
``body50k``: the MakeHuman body subdivided, 53k vertices, bent / twisted 60 degrees; ``human13k``: the CC0 body with
its arm, knee and torso pose keys).  For every pair (the basis and each other key): ``--count`` evenly spaced
in-betweens by the path (``path_seconds``, ``path_cpu_seconds``: everything from the keys, the set-up and the
factorizations included; ``factorizations``, the probes' ``estimates``, the largest ``indicator``), by Fast (lacore's
default projection, ``fast_seconds``) and by converged Gauss-Newton (``gn_seconds``; ``interpolate(method="gn")``),
and the RMS vertex distance of every path in-between to Gauss-Newton's over the bounding-box diagonal
(``rms_of_diagonal``, max and all; ``indicator_covers_error``: at most the indicator wherever the in-between was
not polished; ``polished_count``).  Every computation starts cold (a new topology: no cached set-up).

Prints one JSON object.  usage:
python benchmarks/bench_path_inbetweens.py [bar50k] [body50k] [human13k] [--count 10] [--no-fast] [--json FILE]
"""

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

from bench_common import emit, machine_info  # noqa: E402
from bench_mixer import mesh_keys  # noqa: E402

from lacore import MeshTopology, interpolate  # noqa: E402
from lacore.shapes.mixing.path import path_inbetweens  # noqa: E402

MESHES = ("bar50k", "body50k", "human13k")


def _timed(fn):
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, round(time.perf_counter() - t, 3), round(time.process_time() - c, 3)


def bench_pair(A, B, F, count, fast):
    factors = np.arange(1, count + 1) / (count + 1)
    res, wall, cpu = _timed(lambda: path_inbetweens(A, B, MeshTopology.from_faces(F, n_vertices=len(A)), factors))
    out = {"path_seconds": wall, "path_cpu_seconds": cpu, "factorizations": res.factorizations,
           "reduced_size": res.reduced_size, "estimates": res.estimates, "polished": res.polished,
           "indicator_max": float(res.indicator.max()),
           "path_stage_cpu_seconds": {k: round(v, 3) for k, v in res.cpu_seconds.items()}}
    if fast:
        _, out["fast_seconds"], out["fast_cpu_seconds"] = _timed(
            lambda: interpolate([A, B], MeshTopology.from_faces(F, n_vertices=len(A)), factors))
    gn, out["gn_seconds"], out["gn_cpu_seconds"] = _timed(
        lambda: interpolate([A, B], MeshTopology.from_faces(F, n_vertices=len(A)), factors, method="gn"))
    diag = float(np.linalg.norm(np.ptp(A, axis=0)))
    rms = np.sqrt(((res.vertices - gn.vertices) ** 2).sum(axis=2).mean(axis=1)) / diag
    out["rms_of_diagonal_max"] = float(rms.max())
    out["rms_of_diagonal"] = [float(r) for r in rms]
    reduced = res.indicator > 0                        # the others are keys or polished (converged Gauss-Newton)
    out["polished_count"] = int(np.count_nonzero(~reduced))
    out["indicator_covers_error"] = bool(np.all(rms[reduced] <= res.indicator[reduced]))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="*", default=list(MESHES), help=f"of {', '.join(MESHES)}")
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--no-fast", action="store_true", help="skip the Fast projection")
    parser.add_argument("--json", default=None, help="also write the result to this file")
    args = parser.parse_args(argv)
    out = {"benchmark": "path_inbetweens", "count": args.count,
           "machine": machine_info(threads={k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS",
                                                                           "OMP_NUM_THREADS")}),
           "meshes": {}}
    for name in args.meshes:
        keys, F = mesh_keys(name)
        entry = {"vertices": int(keys.shape[1]), "pairs": {}}
        for k in range(1, len(keys)):
            entry["pairs"][f"0-{k}"] = bench_pair(keys[0], keys[k], F, args.count, not args.no_fast)
            print(f"[bench_path_inbetweens] {name} 0-{k}: {entry['pairs'][f'0-{k}']}", file=sys.stderr, flush=True)
        out["meshes"][name] = entry
    emit(out, args.json)


if __name__ == "__main__":
    main()
