# SPDX-License-Identifier: GPL-3.0-or-later
"""Persistent storage of encodings as ID properties on the Mesh datablock.

Layout of ``mesh["lengths_angles"]`` (an ID property group, saved in the .blend)::

    format_version   int     (FORMAT_VERSION)
    n_vertices       int
    n_mesh_edges     int     first rows of ``edges`` that are Blender's mesh.edges
    n_polygons       int     len(mesh.polygons) when encoded
    topology_hash    str     :func:`..session.topology_hash` of (faces, edges)
    faces            int32 array, flattened (F, 3) fixed fan triangulation
    edges            int32 array, flattened (E, 2) as oriented by lacore
    keys             group: shape-key name -> group
        z                               float64 array (2E,) = (lengths, angles)
        max_integrability_violation     float (largest |tr I_v - 3| at a vertex)
        integrable                      int 1 / 0: all of Theorem 3.2 (vertices, holes, handles); absent in
                                        encodings made before the global conditions were checked
        integrability                   str: lacore's IntegrabilityCheck.describe()
        integrability_where             str: "" or where it fails ("at a vertex, around a hole", ...)
        key_index                       int (position in the key list when encoded)
        coords_hash                     str :func:`..session.coords_hash` of the key's coordinates

The interpolation operators reuse a stored ``z`` when the topology hash and the
key's coordinate hash still match (:func:`..session.key_z`), so what is stored is used.

ID properties cannot be attached to shape-key blocks, hence the Mesh.

Payloads (the live mixer's and the shape model's ``.npz``, megabytes) are NOT ID properties of the mesh:
Blender copies a mesh's custom properties into every evaluated copy and every undo step.  A payload is
stored base64-encoded in a text datablock (fake user: kept without users; first line
``"<header> <token>"``), and the mesh holds a small record ``{"text": name, "text_id": the text, "token":
token, ...}`` (:func:`store_payload`, :func:`load_payload`, :func:`release_payload`).  ``text_id`` points at
the text, so appending or linking the mesh from another .blend brings the text along (renamed if the name is
taken); records without it (earlier versions) name the text.  A duplicated mesh shares its original's text
until one of them is rebuilt or removed; a text is removed with its last record, and a payload text no mesh
refers to any more (its mesh deleted, or joined into another) is removed when the file is loaded again
(:func:`release_orphans`).
"""

import base64
import binascii
import os
import tempfile
import uuid

import bpy
import numpy as np

from ..lacore.errors import InputError
from ..lacore.integrability.checks import LOCAL_TOLERANCE

__all__ = ["store_payload", "load_payload", "release_payload", "release_orphans", "payload_header", "PayloadError",
           "PROP", "FORMAT_VERSION", "INTEGRABLE_TOLERANCE", "is_integrable", "write_encoding", "read_encoding",
           "key_status", "clear_encoding", "encoding_mismatch"]

PROP = "lengths_angles"
FORMAT_VERSION = 1
#: Largest per-vertex violation ``|tr I_v - 3|`` counted as closing (lacore.integrability.checks.LOCAL_TOLERANCE):
#: round-off of lengths and angles measured on a real shape gives ~1e-30 .. 1e-14.
INTEGRABLE_TOLERANCE = LOCAL_TOLERANCE


class PayloadError(InputError):
    """A stored payload whose text datablock is missing, was edited or does not decode."""


_LINE = 65536  # base64 characters per line of a payload's text
_HEADERS = set()  # the headers of the add-on's kinds of payload texts (:func:`payload_header`)


def payload_header(header):
    """Declare ``header`` as the first words of a kind of payload text (the live mixer's, the shape model's ...),
    for :func:`release_orphans`; returns it."""
    _HEADERS.add(header)
    return header


def _record_text(record):
    """The text datablock a payload record (ID property group or dict) refers to, or None: its ``text_id``
    pointer, else (records of earlier versions) the local text named ``text``."""
    text = record.get("text_id")
    if isinstance(text, bpy.types.Text):
        return text
    return bpy.data.texts.get(str(record.get("text", "")))


def _references(text):
    """Meshes with a payload record (a top-level ID property group) referring to the text datablock ``text``."""
    out = []
    for mesh in bpy.data.meshes:
        for prop in mesh.keys():
            value = mesh[prop]
            if hasattr(value, "to_dict") and ("text_id" in value or "text" in value) and _record_text(value) == text:
                out.append(mesh)
                break
    return out


def _new_text(data, header, name):
    token = uuid.uuid4().hex
    text = bpy.data.texts.new(name)
    text.use_fake_user = True
    encoded = base64.b64encode(bytes(data)).decode("ascii")
    text.from_string("\n".join([f"{header} {token}", *(encoded[i:i + _LINE] for i in range(0, len(encoded), _LINE))]))
    return text, token


def store_payload(mesh, prop, data, *, header, name, record=None):
    """Store ``data`` (bytes) for ``mesh``: a new text datablock ``name`` (Blender adds ``.001`` if taken) and
    ``mesh[prop] = {**record, "text": <its name>, "token": <a new token>}``; a payload ``mesh[prop]`` had before
    is released (:func:`release_payload`) and the new text takes its name.  Returns the token."""
    old = mesh.get(prop)
    old = None if old is None else old.to_dict()
    text, token = _new_text(data, header, name)
    mesh[prop] = {**(record or {}), "text": text.name, "text_id": text, "token": token}
    if old is not None and ("text" in old or "text_id" in old):
        release_payload(old)
        text.name = name
        mesh[prop]["text"] = text.name
    return token


def saved_bytes(save, filename):
    """The bytes ``save(path)`` (a lacore object's ``save`` method) writes to ``filename`` (ending ``.npz``) in a
    temporary folder, for :func:`store_payload`."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, filename)
        save(path)
        with open(path, "rb") as fh:
            return fh.read()


def load_payload(record, header):
    """The bytes stored for ``record`` (a mesh's payload record); :class:`PayloadError` if its text is missing,
    is another payload's or was edited."""
    text = _record_text(record)
    name = str(record.get("text", "")) if text is None else text.name
    head, _, body = ("" if text is None else text.as_string()).partition("\n")
    if head != f"{header} {record.get('token', '')}":
        raise PayloadError(f"the text '{name}' holding it is missing or was edited")
    try:
        return base64.b64decode(body.replace("\n", ""), validate=True)
    except (binascii.Error, ValueError) as exc:
        raise PayloadError(f"the text '{name}' holding it was edited ({exc})") from None


def release_payload(record):
    """Remove the text of ``record`` (a payload record already deleted from its mesh, as a dict) unless another
    mesh (a duplicate) still refers to it."""
    text = _record_text(record)
    if text is not None and text.library is None and not _references(text):
        bpy.data.texts.remove(text)


def release_orphans(headers=None):
    """Remove the local payload texts that no mesh refers to (first line ``"<header> <token>"``, ``header`` one
    of ``headers``, default the ones declared by :func:`payload_header`), point the records of earlier
    versions (a text name only) at their text and give the records the names of their texts (an appended
    text is renamed if its name is taken); returns the names of the texts removed.

    Run when a file is loaded: a deleted mesh is not saved, its payload text is (Blender keeps texts).
    """
    for mesh in bpy.data.meshes:
        if mesh.library is not None:
            continue
        for prop in mesh.keys():
            value = mesh[prop]
            if not (hasattr(value, "to_dict") and "text" in value and "token" in value):
                continue
            text = value.get("text_id")
            if isinstance(text, bpy.types.Text):
                if text.name != value["text"]:  # renamed when appended next to a text of its name
                    value["text"] = text.name
                continue
            text = bpy.data.texts.get(str(value["text"]))
            if text is not None and len(text.lines) and text.lines[0].body.endswith(f" {value['token']}"):
                value["text_id"] = text
    headers = tuple(_HEADERS if headers is None else headers)
    removed = []
    for text in list(bpy.data.texts):
        if text.library is not None or not len(text.lines):
            continue
        head = text.lines[0].body
        if any(head.startswith(f"{h} ") for h in headers) and not _references(text):
            removed.append(text.name)
            bpy.data.texts.remove(text)
    return removed


def is_integrable(violation, integrable=None):
    """Whether a key counts as "integrable": the stored verdict on all of Theorem 3.2 if there is one, else
    (encodings made before it was stored) its largest vertex violation (:data:`INTEGRABLE_TOLERANCE`)."""
    if integrable is not None:
        return bool(integrable)
    return float(violation) <= INTEGRABLE_TOLERANCE


def write_encoding(mesh, *, faces, edges, n_mesh_edges, names, z, violations, coords_hashes=None,
                   topology_hash="", integrability=None):
    """Replace ``mesh[PROP]`` by a new encoding (all inputs already computed and valid).

    ``integrability``: per key, ``(integrable, describe, where)`` of lacore's
    :class:`~lacore.integrability.checks.IntegrabilityCheck`.
    """
    z = np.asarray(z, dtype=np.float64)
    keys = {
        name: {
            "z": np.ascontiguousarray(z[k]),
            "max_integrability_violation": float(violations[k]),
            "key_index": k,
            "coords_hash": "" if coords_hashes is None else str(coords_hashes[k]),
        }
        for k, name in enumerate(names)
    }
    for k, name in enumerate(names if integrability is not None else ()):
        integrable, text, where = integrability[k]
        keys[name].update(integrable=int(bool(integrable)), integrability=str(text), integrability_where=str(where))
    mesh[PROP] = {
        "format_version": FORMAT_VERSION,
        "n_vertices": len(mesh.vertices),
        "n_mesh_edges": int(n_mesh_edges),
        "n_polygons": len(mesh.polygons),
        "topology_hash": str(topology_hash),
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
    name -> {``z`` (2E,) float64, ``max_integrability_violation``, ``key_index``, ``integrable`` (bool, or None
    for encodings without it), ``integrability`` and ``integrability_where`` (str)}.
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
            **_integrability(item),
        }
    return {
        "format_version": int(group["format_version"]),
        "n_vertices": int(group["n_vertices"]),
        "n_mesh_edges": int(group["n_mesh_edges"]),
        "faces": np.array(group["faces"], dtype=np.int64).reshape(-1, 3),
        "edges": np.array(group["edges"], dtype=np.int64).reshape(-1, 2),
        "keys": keys,
    }


def encoding_mismatch(mesh):
    """What changed in ``mesh`` since it was encoded (e.g. ``"vertices 8 -> 9, edges 12 -> 13"``), or None."""
    group = mesh.get(PROP)
    if group is None:
        return None
    now = {"vertices": len(mesh.vertices), "edges": len(mesh.edges), "faces": len(mesh.polygons)}
    then = {"vertices": group.get("n_vertices"), "edges": group.get("n_mesh_edges"), "faces": group.get("n_polygons")}
    changed = [f"{what} {then[what]} -> {now[what]}" for what in now
               if then[what] is not None and int(then[what]) != now[what]]
    return ", ".join(changed) if changed else None


def _integrability(item):
    """The stored verdict of a key: ``integrable`` (None if not stored), ``integrability``, ``integrability_where``."""
    integrable = item.get("integrable")
    return {"integrable": None if integrable is None else bool(integrable),
            "integrability": str(item.get("integrability", "")),
            "integrability_where": str(item.get("integrability_where", ""))}


def key_status(mesh):
    """Per shape key ``(name, encoded, max_violation or None, integrability or None)`` for the UI.

    ``integrability`` is the dict of :func:`_integrability` (the stored verdict on all of Theorem 3.2).

    A key counts as encoded if an encoding for its name exists and the mesh
    still has the vertex and edge counts it was encoded with.
    """
    names = [] if mesh.shape_keys is None else [kb.name for kb in mesh.shape_keys.key_blocks]
    group = mesh.get(PROP)
    valid = group is not None and encoding_mismatch(mesh) is None
    stored = group["keys"] if valid else {}
    rows = []
    for name in names:
        item = stored.get(name)
        rows.append((name, item is not None, None if item is None else float(item["max_integrability_violation"]),
                     None if item is None else _integrability(item)))
    return rows
