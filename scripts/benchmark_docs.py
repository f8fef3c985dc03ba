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
        rows.append([label, f"{case['vertices']:,}", len(case["t"]), _g(cli["total_seconds"]),
                     _g(fast["total_seconds"]), _g(gn["total_seconds"]), _g(fast["max_energy_excess"]),
                     _g(fast["max_rms_over_diagonal"])])
    head = ["motion", "vertices", "in-betweens", "`lacore interpolate` s", "Fast (library) s", "Gauss-Newton s",
            "Fast's energy above GN (max, relative)", "Fast vs GN, RMS / diagonal (max)"]
    return (table(head, rows) + "\n\n" + machine_line(record)
            + " Fast is the default projection; `lacore interpolate`'s time includes reading and writing the"
              " PLY files.")


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


#: the README's blocks: ``<!-- bench:NAME -->``
README_BLOCKS = {"inbetweens": inbetweens, "core-maps": core_maps}
#: docs/benchmarks.md's summary tables (the README's, then more)
SUMMARY = {"In-betweens: the defaults against Gauss-Newton": inbetweens,
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
