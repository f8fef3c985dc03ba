"""Benchmark of the core maps of lacore against the C++ reference implementation (GOAST).

Times, on one thread, the five core evaluations

* ``lengths_and_angles``             X -> z
* ``lengths_and_angles_jacobian``    dZ/dX (sparse)
* ``euler_integrability_map``        z -> Euler angles of the ring holonomies
* ``euler_integrability_jacobian``   its Jacobian (sparse)
* ``integrability_violation``        |tr I_v - 3| per vertex

on the skeleton finger (2046 vertices, shared data), a ~5k-vertex and a
~100k-vertex deformed geodesic sphere (:mod:`benchmarks.meshes`, generated
deterministically), and prints ONE JSON object: machine information, per mesh
the minimum and median wall time and the minimum thread CPU time in
milliseconds over repeated calls (after a first call that builds the cached
index patterns, reported separately as ``first_call_ms``), and the ratios to
the GOAST timings measured on this machine (one thread, 5.2k-vertex cactus;
compared with the 5292-vertex sphere).

Run from the repository root::

    .venv/bin/python benchmarks/bench_core.py [--quick]

``--quick`` skips the 100k-vertex mesh.  The whole run takes well under a
minute.  The load average at start and end is recorded: timings on a busy
machine are not comparable.
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")          # one thread, as the GOAST reference (before numpy is imported)

import gc  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
for _p in (ROOT, ROOT / "benchmarks"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from bench_common import cpu_model  # noqa: E402
from meshes import benchmark_mesh  # noqa: E402

from lacore.integrability.local import (  # noqa: E402
    euler_integrability_jacobian, euler_integrability_map, integrability_violation)
from lacore.geometry.lengths_angles import lengths_and_angles, lengths_and_angles_jacobian  # noqa: E402
from lacore.geometry.topology import MeshTopology  # noqa: E402

#: GOAST (C++, one thread, this machine) on the 5.2k-vertex cactus, milliseconds.
GOAST_MS = {
    "lengths_and_angles": 0.64,
    "lengths_and_angles_jacobian": None,       # not measured
    "euler_integrability_map": 1.8,
    "euler_integrability_jacobian": 10.9,
    "integrability_violation": None,           # not measured
}
GOAST_MESH = {"name": "cactus", "vertices": 5261}
COMPARE_MESH = "sphere5k"

FUNCTIONS = list(GOAST_MS)



def load_finger():
    """The shared finger mesh (2046 vertices); ``None`` if the shared data is not found."""
    import trimesh

    env = os.environ.get("LACORE_SHARED_DATA")
    base = Path(env) if env else ROOT.parent / "shared" / "data"
    if base.name != "meshes":
        base = base / "meshes"
    path = base / "finger" / "finger0.ply"
    if not path.is_file():
        return None
    m = trimesh.load(path, process=False)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def time_calls(fn, budget_s, min_runs=5, max_runs=300):
    """Call ``fn`` repeatedly (garbage collector off) for about ``budget_s`` seconds.

    Returns ``{"min_ms", "median_ms", "cpu_min_ms", "runs"}``: wall-clock minimum
    and median, and the minimum CPU time of the calling thread (less sensitive
    to other processes competing for the cores; the difference to ``min_ms``
    shows how busy the machine was).
    """
    wall, cpu = [], []
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        start = time.perf_counter()
        while len(wall) < max_runs and (len(wall) < min_runs or time.perf_counter() - start < budget_s):
            c0, t0 = time.thread_time(), time.perf_counter()
            fn()
            wall.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
    finally:
        if gc_was_enabled:
            gc.enable()
    wall = np.array(wall) * 1e3
    return {"min_ms": round(float(wall.min()), 4), "median_ms": round(float(np.median(wall)), 4),
            "cpu_min_ms": round(float(min(cpu)) * 1e3, 4), "runs": len(wall)}


def bench_mesh(X, faces, budget_s):
    """Setup and timings of the five core functions on one mesh."""
    t0 = time.perf_counter()
    topo = MeshTopology.from_faces(faces, n_vertices=len(X))
    setup_ms = (time.perf_counter() - t0) * 1e3
    z = lengths_and_angles(X, topo)
    calls = {
        "lengths_and_angles": lambda: lengths_and_angles(X, topo),
        "lengths_and_angles_jacobian": lambda: lengths_and_angles_jacobian(X, topo),
        "euler_integrability_map": lambda: euler_integrability_map(z, topo),
        "euler_integrability_jacobian": lambda: euler_integrability_jacobian(z, topo),
        "integrability_violation": lambda: integrability_violation(z, topo),
    }
    first, timings = {}, {}
    for name, fn in calls.items():
        t0 = time.perf_counter()
        fn()
        first[name] = round((time.perf_counter() - t0) * 1e3, 3)
    for name, fn in calls.items():
        timings[name] = time_calls(fn, budget_s)
    return {"vertices": int(len(X)), "edges": int(topo.n_edges), "faces": int(topo.n_faces),
            "interior_vertices": int(len(topo.interior_vertices)), "topology_ms": round(setup_ms, 2),
            "first_call_ms": first, "timings": timings}


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    quick = "--quick" in argv
    result = {"machine": {"platform": platform.platform(), "cpu": cpu_model(), "cpu_count": os.cpu_count(),
                          "python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
                          "threads": {v: os.environ.get(v) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")},
                          "loadavg_start": [round(x, 2) for x in os.getloadavg()]},
              "goast_reference_ms": {"mesh": GOAST_MESH, "threads": 1, **GOAST_MS},
              "meshes": {}}
    cases = []
    finger = load_finger()
    if finger is not None:
        cases.append(("finger", "shared/data/meshes/finger/finger0.ply", finger, 0.5))
    cases.append(("sphere5k", "benchmarks.meshes.deformed_sphere(23)", benchmark_mesh("sphere5k"), 0.8))
    if not quick:
        cases.append(("sphere100k", "benchmarks.meshes.deformed_sphere(100)", benchmark_mesh("sphere100k"), 2.0))
    for name, source, (X, faces), budget in cases:
        entry = bench_mesh(X, faces, budget)
        result["meshes"][name] = {"source": source, **entry}
    cmp = result["meshes"][COMPARE_MESH]
    scale = GOAST_MESH["vertices"] / cmp["vertices"]
    result["ratio_to_goast"] = {
        "mesh": COMPARE_MESH,
        "note": "min wall time of lacore / GOAST time; the vertex-count difference (5292 vs 5261) is scaled out",
        **{f: (round(cmp["timings"][f]["min_ms"] * scale / g, 3) if g else None) for f, g in GOAST_MS.items()},
    }
    result["machine"]["loadavg_end"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
