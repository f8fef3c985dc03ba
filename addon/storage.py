# SPDX-License-Identifier: GPL-3.0-or-later
"""Persistent storage of encodings as ID properties on the Mesh datablock.

Layout of ``mesh["lengths_angles"]`` (an ID property group, saved in the .blend)::

    format_version   int     (FORMAT_VERSION)
    n_vertices       int
    n_mesh_edges     int     first rows of ``edges`` that are Blender's mesh.edges
    faces            int32 array, flattened (F, 3) fixed fan triangulation
    edges            int32 array, flattened (E, 2) as oriented by lacore
    keys             group: shape-key name -> group
        z                               float64 array (2E,) = (lengths, angles)
        max_integrability_violation     float
        key_index                       int (position in the key list when encoded)

ID properties cannot be attached to shape-key blocks, hence the Mesh.
"""

import numpy as np

__all__ = ["PROP", "FORMAT_VERSION", "write_encoding", "read_encoding", "key_status", "clear_encoding"]

PROP = "lengths_angles"
FORMAT_VERSION = 1


def write_encoding(mesh, *, faces, edges, n_mesh_edges, names, z, violations):
    """Replace ``mesh[PROP]`` by a new encoding (all inputs already computed and valid)."""
    z = np.asarray(z, dtype=np.float64)
    keys = {
        name: {
            "z": np.ascontiguousarray(z[k]),
            "max_integrability_violation": float(violations[k]),
            "key_index": k,
        }
        for k, name in enumerate(names)
    }
    mesh[PROP] = {
        "format_version": FORMAT_VERSION,
        "n_vertices": len(mesh.vertices),
        "n_mesh_edges": int(n_mesh_edges),
        "faces": np.ascontiguousarray(faces, dtype=np.int32).ravel(),
        "edges": np.ascontiguousarray(edges, dtype=np.int32).ravel(),
        "keys": keys,
    }


def clear_encoding(mesh):
    if PROP in mesh:
        del mesh[PROP]


def read_encoding(mesh):
    """The stored encoding as plain Python/NumPy data, or ``None`` if there is none.

    Returns a dict with ``faces`` (F, 3) int64, ``edges`` (E, 2) int64,
    ``n_vertices``, ``n_mesh_edges``, ``format_version`` and ``keys``:
    name -> {``z`` (2E,) float64, ``max_integrability_violation``, ``key_index``}.
    """
    group = mesh.get(PROP)
    if group is None:
        return None
    keys = {}
    for name, item in group["keys"].items():
        keys[name] = {
            "z": np.array(item["z"], dtype=np.float64),
            "max_integrability_violation": float(item["max_integrability_violation"]),
            "key_index": int(item["key_index"]),
        }
    return {
        "format_version": int(group["format_version"]),
        "n_vertices": int(group["n_vertices"]),
        "n_mesh_edges": int(group["n_mesh_edges"]),
        "faces": np.array(group["faces"], dtype=np.int64).reshape(-1, 3),
        "edges": np.array(group["edges"], dtype=np.int64).reshape(-1, 2),
        "keys": keys,
    }


def key_status(mesh):
    """Per shape key ``(name, encoded, max_violation or None)`` for the UI.

    A key counts as encoded if an encoding for its name exists and the mesh
    still has the vertex and edge counts it was encoded with.
    """
    names = [] if mesh.shape_keys is None else [kb.name for kb in mesh.shape_keys.key_blocks]
    group = mesh.get(PROP)
    valid = (group is not None and group.get("n_vertices") == len(mesh.vertices)
             and group.get("n_mesh_edges") == len(mesh.edges))
    stored = group["keys"] if valid else {}
    rows = []
    for name in names:
        item = stored.get(name)
        rows.append((name, item is not None, None if item is None else float(item["max_integrability_violation"])))
    return rows
