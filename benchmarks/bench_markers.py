#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: reading a 5,000-frame, 50-marker C3D take with lacore.markers.io.

A seeded synthetic take (100 Hz, occlusion gaps of 5-40 frames) is written as C3D in float and in
16-bit integer storage (``lacore.markers.io.write_c3d``), then read (best of ``--repeat``) by

* ``lacore``: :func:`lacore.markers.io.read_markers` (one vectorized pass over the data section);
* ``c3d_read_frames``: the ``c3d`` package's per-frame ``Reader.read_frames`` stacked into an
  array (the reference the tests compare against).

Also checks that both give the same positions, and times the same take as TRC text
(``write_trc`` / ``read_markers``).  Prints one JSON object.

usage: python benchmarks/bench_markers.py [--frames 5000] [--markers 50] [--repeat 5]
"""

import argparse
import json
import os
import sys
import tempfile
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import numpy as np  # noqa: E402
from bench_common import machine_info  # noqa: E402

from lacore.markers.io import MarkerTake, read_markers, write_c3d, write_trc  # noqa: E402


def synthetic_take(frames, markers, seed=7, rate=100.0):
    """Smooth trajectories around random points, 6 occlusion gaps of 5..40 frames per marker."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None] / rate
    pos = rng.uniform(-1, 1, (1, markers, 3)) + 0.2 * np.sin(2 * np.pi * rng.uniform(0.2, 2, (1, markers, 3)) * t)
    for m in range(markers):
        for start in rng.integers(0, max(1, frames - 40), 6):
            pos[start:start + rng.integers(5, 40), m] = np.nan
    return MarkerTake(labels=[f"M{m:02d}" for m in range(markers)], positions=pos, rate=rate, source="generated")


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def read_with_package(path):
    import c3d

    with open(path, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.array([p for _, p, _ in c3d.Reader(fh).read_frames()])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=5000)
    parser.add_argument("--markers", type=int, default=50)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    take = synthetic_take(args.frames, args.markers)
    result = {"frames": args.frames, "markers": args.markers,
              "occluded_fraction": round(float((~take.visible).mean()), 4), "storage": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for storage in ("float", "integer"):
            path = os.path.join(tmp, f"take_{storage}.c3d")
            t = time.perf_counter()
            write_c3d(path, take, units="mm", integer=storage == "integer")
            write_s = time.perf_counter() - t
            lacore_s, ours = best(lambda path=path: read_markers(path), args.repeat)
            package_s, ref = best(lambda path=path: read_with_package(path), args.repeat)
            invalid = ref[:, :, 3] < 0
            same_mask = bool(np.array_equal(~ours.visible, invalid))
            diff = float(np.abs(ours.positions[~invalid] - ref[:, :, :3][~invalid] * 1e-3).max())
            result["storage"][storage] = {"file_bytes": os.path.getsize(path), "write_seconds": round(write_s, 4),
                                          "lacore_read_seconds": round(lacore_s, 4),
                                          "c3d_read_frames_seconds": round(package_s, 4),
                                          "speed_up": round(package_s / lacore_s, 1),
                                          "same_occlusion": same_mask, "max_abs_difference_m": diff}
        path = os.path.join(tmp, "take.trc")
        t = time.perf_counter()
        write_trc(path, take, units="mm")
        write_s = time.perf_counter() - t
        trc_s, trc = best(lambda path=path: read_markers(path), args.repeat)
        result["trc"] = {"file_bytes": os.path.getsize(path), "write_seconds": round(write_s, 3),
                         "read_seconds": round(trc_s, 3), "same_occlusion": bool(np.array_equal(trc.visible,
                                                                                              take.visible)),
                         "max_abs_difference_m": float(np.nanmax(np.abs(trc.positions - take.positions)))}
    result["machine"] = machine_info()
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
