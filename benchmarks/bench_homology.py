#!/usr/bin/env python3
"""Benchmark: the global integrability conditions (Theorem 3.2 around holes and handles).

Per mesh: the homology basis once per topology (cold: a fresh topology each
run, its boundary loops, components and genus included), the z-independent
evaluation tables, then paired runs (alternating, medians) of the local check
``integrability_violation`` and the global residuals ``global_integrability_map``
(holonomy and translation of every loop), their ratio, both Jacobians and the
whole verdict ``check_integrability``.  Goals: basis <= 50 ms at 50k vertices,
global residuals <= 10 % of the local check.  Every figure is the median wall
time; ``cpu`` repeats the main ones in process CPU time (``time.process_time``),
which a machine shared with other jobs inflates less.

usage: python benchmarks/bench_homology.py [--repeat 7] [--meshes name ...]
Prints one JSON object.
"""

import argparse
import json
import os
import statistics
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from bench_common import machine_info  # noqa: E402
from meshes import bent_tube, deformed_sphere  # noqa: E402

from lacore.geometry.lengths_angles import lengths_and_angles  # noqa: E402
from lacore.geometry.topology import MeshTopology  # noqa: E402
from lacore.integrability import (check_integrability, global_integrability_jacobian,  # noqa: E402
                                  global_integrability_map, homology_basis)
from lacore.integrability.global_conditions import _tables  # noqa: E402
from lacore.integrability.local import euler_integrability_jacobian, integrability_violation  # noqa: E402
from lacore.samples.surfaces import pretzel, pretzel_with_holes  # noqa: E402


def body_open():
    from lacore.samples.human import open_body
    b = open_body()
    return b.vertices, b.faces


MESHES = {
    "sphere50k": (lambda: deformed_sphere(70), "deformed geodesic sphere: closed, genus 0 (no loops)"),
    "tube50k": (lambda: bent_tube(200, 250), "bent tube 200 x 250: an annulus (one hole loop)"),
    "torus50k": (lambda: pretzel(1, cells=55), "lacore.samples.surfaces.pretzel(1, cells=55): a torus"),
    "pretzel3_holes50k": (lambda: pretzel_with_holes(3, 3, cells=37),
                          "pretzel_with_holes(3, 3, cells=37): genus 3, three holes cut (one cut twice)"),
    "body_open": (body_open, "lacore.samples.human.open_body(): eyes, mouth and wrists open (genus 0, 5 holes)"),
}


def median_ms(values):
    return round(1e3 * statistics.median(values), 3)


def bench(name, repeat):
    build, description = MESHES[name]
    X, F = build()
    topo_times, derived_times, basis_times, table_times, basis_cpu, topo_cpu = [], [], [], [], [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        topo = MeshTopology.from_faces(F, n_vertices=len(X))
        t1, c1 = time.perf_counter(), time.process_time()
        topo.boundary_loops()
        topo.face_components()
        topo.genus()
        t2, c2 = time.perf_counter(), time.process_time()
        basis = homology_basis(topo)
        t3, c3 = time.perf_counter(), time.process_time()
        _tables(topo)
        t4 = time.perf_counter()
        topo_times.append(t1 - t0)
        derived_times.append(t2 - t1)
        basis_times.append(t3 - t2)
        table_times.append(t4 - t3)
        topo_cpu.append(c1 - c0)
        basis_cpu.append(c3 - c2)
    cold = []                                               # basis with the topology's derived data not yet computed
    for _ in range(max(3, repeat // 2)):
        fresh = MeshTopology.from_faces(F, n_vertices=len(X))
        t0 = time.perf_counter()
        homology_basis(fresh)
        cold.append(time.perf_counter() - t0)
    z = lengths_and_angles(X, topo)
    integrability_violation(z, topo)
    global_integrability_map(z, topo)
    local, glob, ratios, local_cpu, glob_cpu, ratios_cpu = [], [], [], [], [], []
    for _ in range(5 * repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        integrability_violation(z, topo)
        t1, c1 = time.perf_counter(), time.process_time()
        global_integrability_map(z, topo)
        t2, c2 = time.perf_counter(), time.process_time()
        local.append(t1 - t0)
        glob.append(t2 - t1)
        ratios.append((t2 - t1) / (t1 - t0))
        local_cpu.append(c1 - c0)
        glob_cpu.append(c2 - c1)
        ratios_cpu.append((c2 - c1) / max(c1 - c0, 1e-9))
    jl, jg, chk = [], [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        euler_integrability_jacobian(z, topo)
        t1 = time.perf_counter()
        global_integrability_jacobian(z, topo)
        t2 = time.perf_counter()
        check = check_integrability(z, topo)
        t3 = time.perf_counter()
        jl.append(t1 - t0)
        jg.append(t2 - t1)
        chk.append(t3 - t2)
    return {
        "description": description, "vertices": len(X), "faces": len(F), "genus": basis.genus.tolist(),
        "boundary_loops": basis.n_boundary_loops.tolist(), "loops": basis.n_loops,
        "loop_edges": int(basis.ptr[-1]), "corridor_crossings": int(basis.dual_ptr[-1]),
        "max_residual": {"holonomy_rad": check.max_holonomy, "translation_relative": check.max_translation,
                         "local_trace": check.max_local},
        "topology_ms": median_ms(topo_times), "topology_derived_ms": median_ms(derived_times),
        "basis_ms": median_ms(basis_times), "basis_cold_ms": median_ms(cold), "tables_ms": median_ms(table_times),
        "local_check_ms": median_ms(local), "global_residuals_ms": median_ms(glob),
        "global_over_local": round(statistics.median(ratios), 4),
        "local_jacobian_ms": median_ms(jl), "global_jacobian_ms": median_ms(jg),
        "check_integrability_ms": median_ms(chk),
        "cpu": {"topology_ms": median_ms(topo_cpu), "basis_ms": median_ms(basis_cpu),
                "local_check_ms": median_ms(local_cpu), "global_residuals_ms": median_ms(glob_cpu),
                "global_over_local": round(statistics.median(ratios_cpu), 4)},
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--meshes", nargs="+", choices=sorted(MESHES), default=list(MESHES))
    args = parser.parse_args(argv)
    results = {name: bench(name, args.repeat) for name in args.meshes}
    print(json.dumps({"benchmark": "homology basis and global integrability residuals (median ms)",
                      "goals": {"basis_ms_at_50k": 50, "global_over_local": 0.10},
                      "machine": machine_info(), "repeats": args.repeat, "meshes": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
