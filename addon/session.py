# SPDX-License-Identifier: GPL-3.0-or-later
"""Session cache: what depends only on a mesh and its shape keys, kept between operator runs.

One mechanism, content-addressed (so undo, which re-allocates datablocks, and key renames
do not invalidate it, and any edit does):

* **topology** (:class:`lacore.geometry.topology.MeshTopology`, which owns lacore's per-connectivity
  cache: Gauss-Newton pattern, fill-reducing ordering, symbolic factorization, reconstruction
  contexts) keyed by :func:`topology_hash` of the fixed fan triangulation;
* **z** of every shape key (lengths and angles, thesis eq. 2.1) keyed by (topology hash,
  :func:`coords_hash` of the key's coordinates); on a miss the encoding stored in the mesh by
  Encode is used when its hashes match, else z is computed;
* **set-up objects** built from the keys (the multiresolution hierarchy), keyed by topology and
  key hashes;
* **results**: placed in-betweens keyed by (topology hash, key hashes, keyframes, spline or
  linear, method, time), so a redo-panel change re-computes only the frames that changed.

Editing a key changes its coordinate hash (a miss: recomputed); editing the connectivity
changes the topology hash.  :data:`STATS` counts hits and misses (tests, status text).
No bpy here: the caller reads the Blender data (:func:`read_mesh` takes the object).
"""

import hashlib
import threading
from collections import Counter, OrderedDict
from dataclasses import dataclass

import numpy as np

from ..lacore.errors import MeshError
from ..lacore.geometry.lengths_angles import check_nondegenerate, lengths_and_angles
from ..lacore.geometry.topology import MeshTopology, check_vertices
from . import mesh_access, storage

__all__ = ["STATS", "MeshData", "coords_hash", "topology_hash", "read_mesh", "key_z", "cached_result",
           "store_result", "cached_object", "clear", "clear_results", "sizes"]

#: Hit / miss counters: ``topology_hit``, ``topology_miss``, ``z_hit``, ``z_stored`` (taken from the
#: mesh's stored encoding), ``z_miss``, ``result_hit``, ``result_miss``.
STATS = Counter()

_TOPOLOGIES = OrderedDict()  # topology hash -> MeshTopology
_MAX_TOPOLOGIES = 1          # a 50k-vertex topology with its factorization holds ~0.5 GB
_Z = OrderedDict()           # (topology hash, coords hash) -> (2E,) float64 (read-only)
_MAX_Z = 64
_RESULTS = OrderedDict()     # (topology hash, job key, time) -> ((V, 3) float64 read-only, failure note or None)
_MAX_RESULT_BYTES = 256 * 2 ** 20
_LOCK = threading.RLock()    # the modal runs compute frames in a worker thread
_OBJECTS = OrderedDict()     # (topology hash, ..., what) -> set-up object (e.g. a multiresolution hierarchy)
_MAX_OBJECTS = 1


def coords_hash(X):
    """Hex digest of the float64 coordinates ``X`` (identical coordinates <=> identical hash)."""
    return hashlib.blake2b(np.ascontiguousarray(X, np.float64).tobytes(), digest_size=16).hexdigest()


def topology_hash(faces, edges, n_vertices):
    """Hex digest of a triangulation's connectivity (vertex count, triangles, edge order)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(np.int64(n_vertices).tobytes())
    h.update(np.ascontiguousarray(faces, np.int64).tobytes())
    h.update(b"|")
    h.update(np.ascontiguousarray(edges, np.int64).tobytes())
    return h.hexdigest()


@dataclass
class MeshData:
    """A mesh object's shape keys, read once: ``coords`` (K, V, 3) float64 in key-list order; ``triangulation``
    (:class:`.mesh_access.Triangulation`) the fan triangles ``topology`` is made of (None for shapes given as arrays),
    so that errors name Blender's faces."""

    mesh: object
    names: list
    coords: np.ndarray
    topology: MeshTopology
    topology_hash: str
    key_hashes: list
    triangulation: object = None

    def index(self, name):
        return self.names.index(name)


def _lru_put(table, key, value, limit):
    with _LOCK:
        table[key] = value
        table.move_to_end(key)
        while len(table) > limit:
            table.popitem(last=False)


def read_mesh(obj, what="processed"):
    """Validated :class:`MeshData` of a mesh object with shape keys (topology from the cache if unchanged).

    Raises :class:`mesh_access.MeshAccessError` / :class:`lacore.errors.MeshError` for unusable input.
    """
    mesh = mesh_access.require_mesh_object(obj)
    if obj.mode == 'EDIT':
        obj.update_from_editmode()  # make edit-mode changes visible in the mesh data
    names, coords = mesh_access.read_shape_keys(mesh)
    tri = mesh_access.triangulate(mesh)
    thash = topology_hash(tri.faces, tri.edges, tri.n_vertices)
    with _LOCK:
        topology = _TOPOLOGIES.get(thash)
    if topology is None:
        STATS["topology_miss"] += 1
        try:
            topology = MeshTopology.from_faces(tri.faces, edges=tri.edges, n_vertices=tri.n_vertices)
        except MeshError as exc:
            raise mesh_access.topology_error(mesh, what, exc) from exc
        _lru_put(_TOPOLOGIES, thash, topology, _MAX_TOPOLOGIES)
    else:
        STATS["topology_hit"] += 1
        _lru_put(_TOPOLOGIES, thash, topology, _MAX_TOPOLOGIES)
    return MeshData(mesh=mesh, names=names, coords=coords, topology=topology, topology_hash=thash,
                    key_hashes=[coords_hash(X) for X in coords], triangulation=tri)


def key_z(data, name):
    """Lengths and angles ``(2E,)`` of the shape key ``name`` of ``data`` (:class:`MeshData`), cached.

    Order of look-up: this session's cache, the encoding stored in the mesh (if it was made from
    these very coordinates and this connectivity), else computed (and checked: no NaN, no
    degenerate triangle; for a mesh, :func:`.mesh_access.require_nondegenerate_keys` names the mesh, the key and
    Blender's faces).
    """
    k = data.index(name)
    key = (data.topology_hash, data.key_hashes[k])
    with _LOCK:
        z = _Z.get(key)
        if z is not None:
            STATS["z_hit"] += 1
            _Z.move_to_end(key)
            return z
    z = _stored_z(data, name)
    if z is not None:
        STATS["z_stored"] += 1
    else:
        STATS["z_miss"] += 1
        if data.triangulation is not None:
            X = data.coords[k]
            mesh_access.require_nondegenerate_keys(data.mesh, data.triangulation, [name], [X], data.topology)
        else:
            X = check_vertices(data.coords[k], data.topology.n_vertices, name=f"Shape key '{name}'")
            try:
                check_nondegenerate(X, data.topology)
            except MeshError as exc:
                raise MeshError(f"Shape key '{name}': {exc}") from exc
        z = lengths_and_angles(X, data.topology)
    z = np.array(z, np.float64)
    z.setflags(write=False)
    _lru_put(_Z, key, z, _MAX_Z)
    return z


def _stored_z(data, name):
    if data.mesh is None:  # shapes given as arrays (operators_interpolate.inbetween_shapes)
        return None
    group = data.mesh.get(storage.PROP)
    if group is None or group.get("topology_hash", "") != data.topology_hash:
        return None
    item = group["keys"].get(name)
    if item is None or item.get("coords_hash", "") != data.key_hashes[data.index(name)]:
        return None
    z = np.array(item["z"], np.float64)
    return z if z.shape == (2 * data.topology.n_edges,) else None


def cached_object(key, build):
    """A set-up object under ``key`` (built by ``build()`` on a miss; the last one is kept)."""
    with _LOCK:
        value = _OBJECTS.get(key)
        STATS["object_hit" if value is not None else "object_miss"] += 1
    if value is None:
        value = build()
    _lru_put(_OBJECTS, key, value, _MAX_OBJECTS)
    return value


def cached_result(key):
    """A stored ``((V, 3) result, failure note or None)`` under ``key`` (hashable, starting with the
    topology hash), or None."""
    with _LOCK:
        X = _RESULTS.get(key)
        STATS["result_hit" if X is not None else "result_miss"] += 1
        if X is not None:
            _RESULTS.move_to_end(key)
        return X


def has_result(key):
    """Whether a result is stored under ``key`` (planning: neither counted in :data:`STATS` nor refreshed)."""
    with _LOCK:
        return key in _RESULTS


def store_result(key, X, note=None):
    X = np.array(X, np.float64)
    X.setflags(write=False)
    with _LOCK:
        _RESULTS[key] = (X, note)
        _RESULTS.move_to_end(key)
        while sum(v[0].nbytes for v in _RESULTS.values()) > _MAX_RESULT_BYTES and len(_RESULTS) > 1:
            _RESULTS.popitem(last=False)


def clear_results():
    """Forget the computed frames only (benchmarks: recompute with the set-up cached)."""
    with _LOCK:
        _RESULTS.clear()


def clear():
    """Forget everything cached in this session (the stored encodings in .blend files stay)."""
    with _LOCK:
        _TOPOLOGIES.clear()
        _Z.clear()
        _RESULTS.clear()
        _OBJECTS.clear()


def sizes():
    """Number of cached topologies, key encodings and results."""
    return {"topologies": len(_TOPOLOGIES), "z": len(_Z), "results": len(_RESULTS)}
