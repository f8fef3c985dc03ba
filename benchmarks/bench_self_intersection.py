"""Speed of the self-intersection search (lacore.geometry.self_intersection) on the CC0 body.

Prints ONE JSON object: per mesh (the coarse body, 2,500 vertices, and the full body,
13,380 vertices; each at rest and in the first of its seeded training poses, whose bent
elbows and knees pass through themselves), the faces, the intersecting pairs found and
the milliseconds per call (median over ``--repeat`` calls; CPU: ``time.process_time``,
wall: ``time.perf_counter``): ``cpu_ms``/``wall_ms`` with the faces as an array (the
connectivity part of the search computed in every call), ``topology_cpu_ms``/
``topology_wall_ms`` with a :class:`~lacore.geometry.topology.MeshTopology` (that part
cached: the cost per frame of a take), plus the machine.  ``lacore.markers.fit_take``
runs the search once per frame on the coarse mesh.

Usage::

    python benchmarks/bench_self_intersection.py [--repeat N]
"""

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from bench_common import machine_info

from lacore.geometry.self_intersection import self_intersections
from lacore.geometry.topology import MeshTopology
from lacore.result import json_value
from lacore.samples.human import coarse_human_coarsening, load_human


def medians(vertices, faces, repeat):
    """Median CPU and wall milliseconds of ``repeat`` calls (after one warm-up call), and the pairs."""
    pairs = self_intersections(vertices, faces, check=False)
    cpu, wall = [], []
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        self_intersections(vertices, faces, check=False)
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
    return pairs, 1000 * float(np.median(cpu)), 1000 * float(np.median(wall))


def timed(vertices, faces, repeat):
    pairs, cpu, wall = medians(vertices, faces, repeat)
    topo_pairs, topo_cpu, topo_wall = medians(vertices, MeshTopology.from_faces(faces), repeat)
    assert np.array_equal(pairs, topo_pairs)
    return {"vertices": int(len(vertices)), "faces": int(len(faces)), "pairs": int(len(pairs)),
            "cpu_ms": cpu, "wall_ms": wall, "topology_cpu_ms": topo_cpu, "topology_wall_ms": topo_wall}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=15, help="calls per mesh (default 15)")
    args = parser.parse_args()
    full, coarse = load_human(), load_human(coarse=True)
    pose = full.random_poses(1, seed=0)[0][0]
    keep = coarse_human_coarsening().vertex_indices
    meshes = {"coarse_rest": (coarse.vertices, coarse.faces), "coarse_posed": (pose[keep], coarse.faces),
              "full_rest": (full.vertices, full.faces), "full_posed": (pose, full.faces)}
    out = {"benchmark": "self_intersection", "repeat": args.repeat,
           "meshes": {name: timed(V, F, args.repeat) for name, (V, F) in meshes.items()}}
    out["machine"] = machine_info()
    print(json.dumps(json_value(out)))


if __name__ == "__main__":
    main()
