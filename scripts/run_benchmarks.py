#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Run the benchmark scripts and store what they print: ``docs/benchmarks/<name>.json`` (``.quick.json``).

Every script in ``benchmarks/`` prints one JSON object (with the ``machine`` it ran on).  This runner
runs each with the arguments of :data:`BENCHMARKS` (the *full* run, or its ``--quick`` variant where the
script has one), takes the JSON object from its output and stores it with the command, the date and
the wall time of the run.  ``scripts/benchmark_docs.py`` renders ``docs/benchmarks.md`` and the marked
blocks of the README from these files; nothing measured is typed by hand.

``make bench`` runs every full benchmark (long: the 50k-vertex cases take many minutes), ``make
bench-quick`` the quick variants, and both then rewrite the docs.  One benchmark::

    python scripts/run_benchmarks.py --only bench_core --quick
    python scripts/run_benchmarks.py --only bench_marker_fitting --extra=--save --extra=fit.npz

``--extra`` arguments go to the script but not into the stored command: use them only for options that do
not change the results (``--save FILE`` writes the fitted take for ``scripts/render_marker_fit.py``).
The ``bench_blender_*`` scripts need bpy and SciPy in one Python: ``--blender-python`` (bpy 5.2's venv)
with ``--blender-pythonpath`` (where that Python finds SciPy & co.).

Every script runs with one BLAS thread (:data:`ONE_THREAD`, unless the caller's environment sets those
variables): the goals are stated for one core, and a BLAS that starts a thread per core makes the figures
depend on the machine's core count and on its other jobs.  Each result's ``machine`` block records them.
"""

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
STORE = os.path.join(REPO, "docs", "benchmarks")


#: The environment every benchmark runs in unless the caller sets these variables: one BLAS/OpenMP thread.
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@dataclass(frozen=True)
class Benchmark:
    """How one script is run: full arguments, ``--quick`` arguments (None: the script has no quick variant)."""

    full: tuple = ()
    quick: tuple | None = None
    blender: bool = False      # needs bpy (run with --blender-python)
    json_option: bool = False  # writes its JSON with --json FILE (its stdout holds Blender's log too)
    long: bool = False         # the full run takes many minutes (50k-vertex meshes)


_CONTINUATION_ROWS = ("--rows", "gauss_newton", "fast", "cli_default", "path")
_CONTINUATION_QUICK = ("--quick", "--rows", "gauss_newton", "fast", "fast_2_workers", "cli_default", "--no-single")

#: every benchmark script, by name (``benchmarks/<name>.py``)
BENCHMARKS = {
    "bench_core": Benchmark(quick=("--quick",)),
    "bench_encode": Benchmark(),
    "bench_frame_based": Benchmark(),
    "bench_gauss_newton": Benchmark(full=("--repeat", "3"), quick=("--quick",)),
    "bench_homology": Benchmark(),
    "bench_interpolation": Benchmark(quick=("--quick",), long=True),
    "bench_continuation": Benchmark(full=_CONTINUATION_ROWS + ("--no-single",), quick=_CONTINUATION_QUICK, long=True),
    "bench_multires": Benchmark(quick=("--quick",), long=True),
    "bench_ordering": Benchmark(quick=("--quick",), long=True),
    "bench_sparse_fallback": Benchmark(),
    "bench_shape_model": Benchmark(quick=("--quick",)),
    "bench_markers": Benchmark(),
    "bench_mixer": Benchmark(quick=("bar5k", "body13k", "--references", "2"), long=True),
    "bench_mixer_rigs": Benchmark(quick=("--references", "2")),
    "bench_mixer_keys": Benchmark(quick=("human13k_k5", "--references", "2"), long=True),
    "bench_path_inbetweens": Benchmark(quick=("human13k", "--no-fast"), long=True),
    "bench_fit_takes": Benchmark(quick=("--takes", "Walk1.c3d", "--frames", "30"), long=True),
    "bench_self_intersection": Benchmark(),
    "bench_marker_fitting": Benchmark(full=("--frames", "150", "--validation-frames", "40", "--prolong")),
    "bench_blender_markers": Benchmark(blender=True),
    "bench_blender_fit": Benchmark(full=("--repeat", "3"), blender=True),
    "bench_blender_runs": Benchmark(blender=True, json_option=True),
    "bench_blender_interpolate": Benchmark(full=("--methods", "FAST", "--no-profile"), blender=True,
                                           json_option=True, long=True),
    "bench_blender_live_mix": Benchmark(blender=True, json_option=True, long=True),
    "bench_blender_mixer_inbetweens": Benchmark(full=("bar50k",), blender=True, json_option=True, long=True),
    "bench_blender_calibrate": Benchmark(blender=True, long=True),
}


def command(name, quick=False):
    """The command line stored with (and shown for) a run, e.g. ``python benchmarks/bench_core.py --quick``."""
    bench = BENCHMARKS[name]
    args = bench.quick if quick else bench.full
    if args is None:
        raise ValueError(f"{name} has no --quick variant")
    return " ".join(["python", f"benchmarks/{name}.py", *args])


def stored_path(name, quick=False, store=STORE):
    """``docs/benchmarks/<name>.json`` (full run) or ``<name>.quick.json``."""
    return os.path.join(store, f"{name}{'.quick' if quick else ''}.json")


def last_json_object(text):
    """The last JSON object in ``text`` that runs to its end (a script's output after any log lines)."""
    decoder = json.JSONDecoder()
    starts = [i for i, c in enumerate(text) if c == "{" and (i == 0 or text[i - 1] == "\n")]
    for start in reversed(starts):
        try:
            value, end = decoder.raw_decode(text, start)
        except json.JSONDecodeError:
            continue
        if isinstance(value, dict) and not text[end:].strip():
            return value
    raise ValueError("no JSON object at the end of the output")


def public_platform(text):
    """``platform.platform()`` without the kernel release (``Linux-6.1.0-...-x86_64-with-glibc2.36`` ->
    ``Linux-x86_64-with-glibc2.36``): the operating system, architecture and C library say what matters."""
    head, _, libc = text.partition("-with-")
    parts = head.split("-")
    arch = next((p for p in reversed(parts) if p in ("x86_64", "aarch64", "arm64", "AMD64", "i686")), None)
    if arch is None or parts[0] not in ("Linux", "Darwin", "Windows", "macOS"):
        return text
    return "-".join([parts[0], arch]) + (f"-with-{libc}" if libc else "")


def _scrub(value):
    """Every ``platform`` entry of a result through :func:`public_platform`."""
    if isinstance(value, dict):
        return {k: public_platform(v) if k == "platform" and isinstance(v, str) else _scrub(v)
                for k, v in value.items()}
    if isinstance(value, list):
        return [_scrub(v) for v in value]
    return value


def run_one(name, quick, python, blender_python, blender_pythonpath, extra=(), store=STORE):
    """Run one benchmark, store its JSON; returns the stored path."""
    bench = BENCHMARKS[name]
    args = list(bench.quick if quick else bench.full) + list(extra)
    interpreter = blender_python if bench.blender else python
    env = {**ONE_THREAD, **os.environ}
    if bench.blender and blender_pythonpath:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (blender_pythonpath, env.get("PYTHONPATH")) if p)
    with tempfile.TemporaryDirectory(prefix="lacore_bench_") as tmp:
        if bench.blender:
            env.setdefault("BLENDER_USER_RESOURCES", os.path.join(tmp, "blender_user"))
        out_json = os.path.join(tmp, "result.json")
        if bench.json_option:
            args += ["--json", out_json]
        started = datetime.datetime.now(datetime.UTC)
        t = time.perf_counter()
        print(f"== {command(name, quick)}", flush=True)
        proc = subprocess.run([interpreter, os.path.join(REPO, "benchmarks", f"{name}.py"), *args], cwd=REPO,
                              env=env, stdout=subprocess.PIPE, text=True)
        seconds = time.perf_counter() - t
        if proc.returncode != 0:
            raise SystemExit(f"run_benchmarks: {name} failed (exit {proc.returncode}); nothing stored")
        if bench.json_option:
            with open(out_json) as fh:
                result = json.load(fh)
        else:
            result = last_json_object(proc.stdout)
    record = {"benchmark": name, "variant": "quick" if quick else "full", "command": command(name, quick),
              "date": started.strftime("%Y-%m-%d %H:%M UTC"), "wall_seconds": round(seconds, 1),
              "result": _scrub(result)}
    os.makedirs(store, exist_ok=True)
    path = stored_path(name, quick, store)
    tmp_path = path + ".tmp"
    with open(tmp_path, "w") as fh:
        json.dump(record, fh, indent=1, sort_keys=False)
        fh.write("\n")
    os.replace(tmp_path, path)
    print(f"   stored {os.path.relpath(path, REPO)} ({seconds:.0f} s)", flush=True)
    return path


def main(argv=None):
    parser = argparse.ArgumentParser(description="Run the benchmarks and store their JSON in docs/benchmarks/.")
    parser.add_argument("--quick", action="store_true",
                        help="the --quick variants (benchmarks without one are skipped)")
    parser.add_argument("--only", nargs="+", choices=sorted(BENCHMARKS), help="these benchmarks (default: all)")
    parser.add_argument("--skip-long", action="store_true", help="skip the full runs that take many minutes")
    parser.add_argument("--python", default=sys.executable, help="interpreter of the lacore benchmarks")
    parser.add_argument("--blender-python", default=None, help="interpreter with bpy for bench_blender_*")
    parser.add_argument("--blender-pythonpath", default=None, help="PYTHONPATH of --blender-python (SciPy & co.)")
    parser.add_argument("--extra", action="append", default=[],
                        help="one more argument for the script, not stored (e.g. --extra=--save --extra=F.npz)")
    args = parser.parse_args(argv)
    names = args.only or list(BENCHMARKS)
    for name in names:
        bench = BENCHMARKS[name]
        if args.quick and bench.quick is None:
            if args.only:
                print(f"== {name}: no --quick variant, skipped")
            continue
        if not args.quick and bench.long and args.skip_long:
            print(f"== {name}: long, skipped ({command(name)})")
            continue
        if bench.blender and not args.blender_python:
            raise SystemExit(f"run_benchmarks: {name} needs --blender-python (a Python with bpy)")
        run_one(name, args.quick, args.python, args.blender_python, args.blender_pythonpath, args.extra)
    return 0


if __name__ == "__main__":
    sys.exit(main())
