#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: 10 lengths-and-angles in-betweens of a ~50k-vertex mesh in Blender (bpy), end to end.

The mesh is a box bar (quads, 400 x 30 x 30 cells on its sides: 49,802 vertices) with a
straight ``Basis`` and ``Bend180`` = Blender's Simple Deform BEND (180 degrees) applied as a
shape key.  Timed:

* ``operator_seconds``: ``bpy.ops.lengths_angles.interpolate`` (count = 10) as a user runs it,
  the first time on this connectivity (pays the one-time set-up: Gauss-Newton sparsity pattern,
  fill-reducing ordering, symbolic factorization);
* ``redo_seconds``: the operator again with the same options (a redo-panel re-run: every frame
  comes from the session cache, addon/session.py);
* ``steps_*``: the modal path's units of work with the operator's own runner
  (``inbetween_run``): validation, one ``tick()`` per in-between, ``finish()`` (checks +
  writing the keys).  In the UI the ticks run in the worker thread while Blender keeps
  responding; the main thread blocks only for validation and finish.  The computed frames are
  dropped from the session cache first (the topology, the keys' lengths and angles and, for
  MULTIRES, the coarse hierarchy stay cached).  With ``--no-profile`` the ticks run in a worker
  thread as in the UI, and ``steps_main_thread_longest_wait_seconds`` is, per frame, the longest
  time the main thread (waking every 5 ms) waited for Python's lock: how long Blender's
  Python-drawn UI can stall meanwhile.  Otherwise the ticks run under cProfile.

Prints one JSON object: seconds per stage and method, machine info, and (with
``--profile``, default on) the functions taking most of the compute time (cProfile,
cumulative, lacore/scipy/numpy functions).

With more than one process (``--processes``, default 0 = the operators' Auto) the operator's
synchronous run (``operator_seconds``) computes the in-betweens nearer to ``Basis`` itself and a
worker process those nearer to ``Bend180``; the modal path (``steps_*``), as the modal operator,
computes every chain in a worker process (``frames_computed_in_blender_process``: 0), so a tick is
the wait for the next frame and Blender's Python stays free.

usage: python benchmarks/bench_blender_interpolate.py [--segments 400 30 30] [--count 10]
                                                      [--methods FAST [GAUSS_NEWTON] [PATH]] [--no-profile]
                                                      [--processes N]
"""

import argparse
import cProfile
import io
import json
import math
import os
import platform
import pstats
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def machine_info(bpy):
    import numpy
    import scipy

    info = {"python": platform.python_version(), "platform": platform.platform(), "machine": platform.machine(),
            "processor": platform.processor(), "cpu_count": os.cpu_count(), "numpy": numpy.__version__,
            "scipy": scipy.__version__, "blender": bpy.app.version_string}
    try:
        with open("/proc/cpuinfo") as fh:
            model = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), None)
        info["cpu_model"] = model
    except OSError:
        pass
    try:
        import cvxopt

        info["cvxopt (CHOLMOD)"] = cvxopt.__version__
    except ImportError:
        info["cvxopt (CHOLMOD)"] = None
    return info


def profile_top(fn, n=18):
    """Run ``fn`` under cProfile; the ``n`` functions with most cumulative time."""
    prof = cProfile.Profile()
    prof.enable()
    out = fn()
    prof.disable()
    stream = io.StringIO()
    stats = pstats.Stats(prof, stream=stream)
    rows = []
    for (file, line, name), (_cc, nc, tt, ct, _callers) in stats.stats.items():
        short = file.split("site-packages/")[-1].split(REPO + os.sep)[-1]
        rows.append({"function": f"{short}:{line}({name})", "calls": nc, "cumulative_s": round(ct, 3),
                     "own_s": round(tt, 3)})
    rows.sort(key=lambda r: -r["cumulative_s"])
    own = sorted(rows, key=lambda r: -r["own_s"])[:n]
    return out, rows[:n], own


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--segments", type=int, nargs=3, default=(400, 30, 30))
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--methods", nargs="+", default=["FAST"],
                        choices=["PREVIEW", "FAST", "GAUSS_NEWTON", "PATH", "MULTIRES"])
    parser.add_argument("--no-profile", action="store_true")
    parser.add_argument("--processes", type=int, default=0,
                        help="the operators' Processes (default 0 = Auto: one per core for >= 20k vertices)")
    parser.add_argument("--json", default=None, help="also write the result to this file")
    args = parser.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="lengths_angles_bench_"))
    import bpy
    import numpy as np

    sys.path.insert(0, os.path.join(REPO, "scripts"))
    import blend_sample_cases as cases
    from addon_dev import load_addon

    pkg = load_addon()
    ops = pkg.addon.operators_interpolate
    session = pkg.addon.session
    bpy.ops.wm.read_homefile(use_empty=True)
    t = time.perf_counter()
    obj = cases.bent_bar("Bar", 180.0, segments=tuple(args.segments))
    build = time.perf_counter() - t
    V = len(obj.data.vertices)
    factors = [i / (args.count + 1) for i in range(1, args.count + 1)]
    result = {"mesh": {"vertices": V, "quads": len(obj.data.polygons), "triangles": 2 * len(obj.data.polygons),
                       "segments": list(args.segments), "build_seconds": round(build, 3)},
              "inbetweens": args.count, "machine": machine_info(bpy), "methods": {}}

    for method in args.methods:
        entry = {}
        # 1. end to end, as a user runs it (the first run on this connectivity pays the set-up)
        bpy.ops.wm.read_homefile(use_empty=True)
        obj = cases.bent_bar("Bar", 180.0, segments=tuple(args.segments))

        def run_operator(obj=obj, method=method):
            t = time.perf_counter()
            if method in {item[0] for item in ops.METHOD_ITEMS}:
                with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
                    assert bpy.ops.lengths_angles.interpolate(key_from="Basis", key_to="Bend180", factors="",
                                                              count=args.count, method=method,
                                                              processes=args.processes) == {'FINISHED'}
            else:  # not offered in the UI (MULTIRES): the operator's own runner, synchronously
                runner = ops.inbetween_run(obj, "Basis", "Bend180", factors, method, workers=args.processes)
                runner.run()
                runner.finish()
            return round(time.perf_counter() - t, 3)

        entry["operator_seconds"] = run_operator()
        entry["operator_run"] = "first run on this connectivity" if not result["methods"] else "set-up cached"
        # 2. a redo-panel re-run with the same options: everything from the session cache
        entry["redo_seconds"] = run_operator()
        # 3. the modal path's units of work: validation, one timer tick per in-between (the longest tick is
        #    the longest time Blender does not respond), finish (checks + writing); computed frames dropped
        #    from the session cache first, the topology and the keys' lengths and angles stay cached
        session.clear_results()
        t0 = time.perf_counter()
        runner = ops.inbetween_run(obj, "Basis", "Bend180", factors, method, workers=args.processes)
        runner.job.all_in_workers = True  # as the modal operator (runs.RunOperator._begin_modal)
        t1 = time.perf_counter()
        ticks = []

        gaps = []

        def drive(runner=runner, ticks=ticks):
            while not runner.finished:
                t = time.perf_counter()
                runner.tick()
                ticks.append(round(time.perf_counter() - t, 3))

        def drive_in_worker(runner=runner, ticks=ticks, gaps=gaps):
            """As the modal operator: each tick in a worker thread; the main thread wakes every 5 ms (as
            Blender's event loop needs Python's lock for its Python-drawn UI) and records its longest wait."""
            with ThreadPoolExecutor(max_workers=1) as worker:
                while not runner.finished:
                    t = last = time.perf_counter()
                    future, gap = worker.submit(runner.tick), 0.0
                    while not future.done():
                        time.sleep(0.005)
                        now = time.perf_counter()
                        gap, last = max(gap, now - last), now
                    future.result()
                    ticks.append(round(time.perf_counter() - t, 3))
                    gaps.append(round(gap, 3))

        if args.no_profile:
            drive_in_worker()
            entry["steps_main_thread_longest_wait_seconds"] = gaps
        else:
            _, top, own = profile_top(drive)
            entry["profile_cumulative"] = top
            entry["profile_own_time"] = own
        t2 = time.perf_counter()
        shapes = list(runner.job.results)
        runner.finish()
        t3 = time.perf_counter()
        entry.update({"steps_validate_seconds": round(t1 - t0, 3), "steps_tick_seconds": ticks,
                      "steps_longest_tick_seconds": max(ticks), "steps_finish_seconds": round(t3 - t2, 3),
                      "steps_total_seconds": round(t3 - t0, 3),
                      "steps_seconds_per_inbetween": round((t2 - t1) / args.count, 3),
                      "profiled": not args.no_profile, "processes": runner.job.processes,
                      "frames_computed_in_blender_process": runner.job.local_frames})
        A = cases.key_coords(obj, "Basis")
        k = len(factors) // 2  # quality check: the k-th in-between vs Blender's bend by the same fraction
        Rk = cases.simple_deform_coords(obj, "BEND", math.radians(180.0 * factors[k]))
        entry["quality"] = {"t": round(factors[k], 4), "reference": f"Simple Deform BEND {180 * factors[k]:.2f} deg",
                            **cases.blend_metrics(shapes[k], Rk, A, cases.mesh_edges(obj))}
        assert all(np.all(np.isfinite(X)) for X in shapes)
        result["methods"][method] = entry
        print(f"[bench] {method}: {json.dumps({k: v for k, v in entry.items() if 'profile' not in k})}",
              file=sys.stderr, flush=True)
    text = json.dumps(result, indent=1)
    if args.json:
        with open(args.json, "w") as fh:
            fh.write(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
