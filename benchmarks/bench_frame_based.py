"""Benchmark of the frame-based reconstruction (thesis 3.4.2, Table 3.1) and the least-squares relaxation.

Prints one JSON object.  For every mesh (the shared finger, 2046 vertices, and
the generated 5292-vertex ``sphere5k`` of :mod:`benchmarks.meshes`) and every
method it reports ``min`` and ``median`` over repeated runs, in milliseconds, of

* ``tree``: everything that depends on the target but not on the walk itself:
  for ``bfs`` building the BFS tree and the walk's index arrays (normally cached
  per topology, timed uncached here); for ``mst``/``spt`` the adaptive weights
  (3.30), the tree and the walk's index arrays (all redone for every target);
  for ``preassembled`` the one-off construction from ``n_samples`` samples;
  for ``lsq`` the first call on a topology (factorizing the position system);
* ``walk``: the reconstruction with the tree given (frames, positions); for
  ``lsq`` a call with the cached position factorization.

For ``bfs`` also ``tree_cached`` (looking the cached tree and walk indices up,
the per-call cost in practice) and ``call_default`` (a whole call
``frame_based_reconstruction(z, topology, reference_vertices=X)``: default root,
cached tree, placement in the reference frame).  ``weights`` times (3.30) alone.

Targets are non-admissible averages of two poses (finger0/finger1; the sphere
and a smoothly bent copy), like the thesis' experiments.  GOAST (the C++
reference implementation) on this machine, finger: BFS tree 0.08 ms + walk
0.39 ms; MST/SPT tree ~1.0 ms + walk 0.4 ms.

Run from the repository root: ``.venv/bin/python benchmarks/bench_frame_based.py``.
"""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
for p in (str(ROOT), str(ROOT / "benchmarks")):
    if p not in sys.path:
        sys.path.insert(0, p)

import trimesh  # noqa: E402
from bench_common import machine_info  # noqa: E402
from meshes import bent_tube, benchmark_mesh  # noqa: E402

from lacore.geometry.lengths_angles import lengths_and_angles  # noqa: E402
from lacore.reconstruction.frame_based import _walk_schedule, frame_based_reconstruction  # noqa: E402
from lacore.reconstruction.least_squares import least_squares_reconstruction  # noqa: E402
from lacore.reconstruction.spanning_trees import (adaptive_edge_weights, bfs_tree, default_root_faces,  # noqa: E402
                                                  minimal_spanning_tree, preassembled_tree, shortest_path_tree)
from lacore.geometry.topology import MeshTopology  # noqa: E402

GOAST_FINGER_MS = {"bfs": {"tree": 0.08, "walk": 0.39}, "mst": {"tree": 1.0, "walk": 0.4},
                   "spt": {"tree": 1.0, "walk": 0.4}}


def timed(fn, repeats):
    """Wall-clock and thread CPU time (ms): ``min``/``median`` and ``cpu_min``/``cpu_median``.

    The CPU time (``time.thread_time``) excludes the time the thread is preempted, so it is the more
    reliable number on a loaded machine (see ``machine.load_average``).
    """
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.thread_time()
        fn()
        cpu.append(time.thread_time() - c)
        wall.append(time.perf_counter() - t)
    return {"min": round(1e3 * min(wall), 4), "median": round(1e3 * float(np.median(wall)), 4),
            "cpu_min": round(1e3 * min(cpu), 4), "cpu_median": round(1e3 * float(np.median(cpu)), 4)}


def finger_case():
    shared = Path(os.environ.get("LACORE_SHARED_DATA", ROOT.parent / "shared" / "data"))
    meshes = shared / "meshes" if (shared / "meshes").is_dir() else shared
    a = trimesh.load(meshes / "finger" / "finger0.ply", process=False)
    b = trimesh.load(meshes / "finger" / "finger1.ply", process=False)
    return np.asarray(a.faces), np.asarray(a.vertices, float), np.asarray(b.vertices, float)


def sphere_case():
    """sphere5k and a smooth bend of its upper half (rotation about x growing with height)."""
    X, faces = benchmark_mesh("sphere5k")
    h = X[:, 2]
    s = np.clip((h - h.min()) / (h.max() - h.min()), 0.0, 1.0)
    ang = 0.9 * s * s * (3.0 - 2.0 * s)                   # smoothstep bend angle
    c, sn = np.cos(ang), np.sin(ang)
    Y = np.stack([X[:, 0], c * X[:, 1] - sn * X[:, 2], sn * X[:, 1] + c * X[:, 2]], 1)
    return faces, X, Y


def bench_mesh(faces, Xa, Xb, repeats, tree_repeats):
    topo = MeshTopology.from_faces(faces, n_vertices=len(Xa))
    za, zb = lengths_and_angles(Xa, topo), lengths_and_angles(Xb, topo)
    z = 0.5 * (za + zb)
    roots = default_root_faces(topo, vertices=Xa)
    key = ("lacore.reconstruction.spanning_trees", "bfs_tree", tuple(roots.tolist()))
    out = {"vertices": topo.n_vertices, "edges": topo.n_edges, "faces": topo.n_faces}

    def build_bfs():
        topo.cache.discard(key)
        _walk_schedule(bfs_tree(topo, roots), topo)

    def build_adaptive(fn):
        def run():
            _walk_schedule(fn(topo, roots, adaptive_edge_weights(z, topo)), topo)
        return run

    samples = np.array([(1 - t) * za + t * zb for t in np.linspace(0.0, 1.0, 5)])

    def build_pre():
        _walk_schedule(preassembled_tree(samples, topo, roots, kind="mst"), topo)

    builders = {"bfs": build_bfs, "mst": build_adaptive(minimal_spanning_tree),
                "spt": build_adaptive(shortest_path_tree), "preassembled": build_pre}
    trees = {"bfs": bfs_tree(topo, roots), "mst": minimal_spanning_tree(topo, roots, adaptive_edge_weights(z, topo)),
             "spt": shortest_path_tree(topo, roots, adaptive_edge_weights(z, topo)),
             "preassembled": preassembled_tree(samples, topo, roots, kind="mst")}
    for name, tree in trees.items():
        frame_based_reconstruction(z, topo, tree=tree)             # warm the walk's index cache
        out[name] = {
            "tree_ms": timed(builders[name], tree_repeats if name != "preassembled" else max(3, tree_repeats // 5)),
            "walk_ms": timed(lambda t=tree: frame_based_reconstruction(z, topo, tree=t), repeats),
            "max_depth": tree.max_depth,
        }
    out["bfs"]["tree_cached_ms"] = timed(lambda: _walk_schedule(bfs_tree(topo, roots), topo), repeats)
    out["bfs"]["call_default_ms"] = timed(lambda: frame_based_reconstruction(z, topo, reference_vertices=Xa), repeats)
    out["weights_ms"] = timed(lambda: adaptive_edge_weights(z, topo), tree_repeats)

    def lsq_first():
        topo.cache.discard(("lacore.reconstruction.least_squares", "factors"))
        least_squares_reconstruction(z, topo, reference_vertices=Xa)

    out["lsq"] = {"tree_ms": timed(lsq_first, 3),
                  "walk_ms": timed(lambda: least_squares_reconstruction(z, topo, reference_vertices=Xa), 5)}
    return out


def lsq_tube50k(repeats=3):
    """Least-squares relaxation per call (ms) on a 50080-vertex bent tube (160 x 313), bend -> twist average.

    The second pose twists the bent tube about the z axis (angle growing linearly to 1.2 rad with height);
    the target is the average of both poses' lengths and angles.  ``first_ms``: first call (symbolic and
    numeric factorizations); ``call_ms``: later calls (the frame system (3.31) is refactorized every call).
    """
    X, faces = bent_tube(160, 313)
    s = (X[:, 2] - X[:, 2].min()) / np.ptp(X[:, 2])
    c, sn = np.cos(1.2 * s), np.sin(1.2 * s)
    Y = np.stack([c * X[:, 0] - sn * X[:, 1], sn * X[:, 0] + c * X[:, 1], X[:, 2]], 1)
    topo = MeshTopology.from_faces(faces, n_vertices=len(X))
    z = 0.5 * (lengths_and_angles(X, topo) + lengths_and_angles(Y, topo))
    first = timed(lambda: least_squares_reconstruction(z, topo, reference_vertices=X), 1)
    return {"vertices": topo.n_vertices, "faces": topo.n_faces, "first_ms": first,
            "call_ms": timed(lambda: least_squares_reconstruction(z, topo, reference_vertices=X), repeats)}


def speed_probe():
    """A fixed NumPy workload (ms; 100 complex products of 4096-vectors) to compare runs on a shared machine."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=4096) + 1j * rng.normal(size=4096)
    b = a[::-1].copy()

    def work():
        for _ in range(100):
            a * b
    return timed(work, 20)



def main():
    result = {"benchmark": "frame_based_reconstruction", "unit": "ms", "machine": machine_info(),
              "goast_finger_reference_ms": GOAST_FINGER_MS, "meshes": {}}
    result["machine"]["speed_probe_ms"] = speed_probe()
    result["meshes"]["finger"] = bench_mesh(*finger_case(), repeats=200, tree_repeats=40)
    result["meshes"]["sphere5k"] = bench_mesh(*sphere_case(), repeats=60, tree_repeats=15)
    result["meshes"]["tube50k_lsq"] = lsq_tube50k()
    result["machine"]["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    result["machine"]["speed_probe_end_ms"] = speed_probe()
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
