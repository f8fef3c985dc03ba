"""The per-mesh cache (lacore.cache.DerivedCache): one key namespace, read-only arrays, clearing."""

import sys

import numpy as np
import pytest
import trimesh
from conftest import shared_mesh

from lacore.cache import DerivedCache, carve, scratch
from lacore.shapes.interpolation import interpolate
from lacore.geometry.topology import MeshTopology


def test_derived_cache_computes_once_and_freezes_arrays():
    cache, calls = DerivedCache(), []

    def compute():
        calls.append(1)
        return np.arange(4.0)

    a = cache.get(("tests.cache", "ramp"), compute)
    assert cache.get(("tests.cache", "ramp"), compute) is a and calls == [1]
    with pytest.raises(ValueError, match="read-only"):
        a[0] = 1.0
    assert cache.peek(("tests.cache", "other")) is None and ("tests.cache", "ramp") in cache
    with pytest.raises(TypeError, match="owner module, name"):
        cache.get("ramp", compute)
    cache.put(("other.module", "x", 3), 5)
    assert cache.keys("other.module") == [("other.module", "x", 3)]
    cache.clear("tests.cache")
    assert len(cache) == 1 and cache.keys() == [("other.module", "x", 3)]
    cache.discard(("other.module", "x", 3))
    assert len(cache) == 0


def test_scratch_buffers_are_reused_and_carved():
    topo = MeshTopology.from_faces([[0, 1, 2]])
    buf = scratch(topo, "t", 10)
    assert scratch(topo, "t", 6).base is buf.base and scratch(topo, "t", 6).size == 6
    a, b = carve(buf, (2, 3), (4,))
    assert a.shape == (2, 3) and b.shape == (4,) and a.flags.c_contiguous
    a[:] = 1.0
    b[:] = 2.0
    assert buf.tolist() == [1.0] * 6 + [2.0] * 4


def test_every_lacore_entry_is_keyed_by_its_owner_module():
    """After an interpolation every per-mesh entry lives under (module, name, ...) of a lacore module."""
    meshes = [trimesh.load(shared_mesh(f"plate/plate121_rolled{s}.ply"), process=False) for s in "AB"]
    topo = MeshTopology.from_faces(np.asarray(meshes[0].faces), n_vertices=len(meshes[0].vertices))
    shapes = [np.asarray(m.vertices, float) for m in meshes]
    interpolate(shapes, topo, [0.5], method="hybrid", hybrid_start="tree")
    owners = {k[0] for k in topo.cache.keys()}
    assert {"lacore.geometry.topology", "lacore.geometry.lengths_angles", "lacore.reconstruction.assembly",
            "lacore.reconstruction.context", "lacore.reconstruction.spanning_trees"} <= owners
    assert all(o in sys.modules and o.startswith("lacore.") for o in owners), owners
    topo.cache.clear("lacore.reconstruction.context")
    assert not topo.cache.keys("lacore.reconstruction.context")
