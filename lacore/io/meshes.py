"""Reading and writing triangle meshes without changing vertex order.

Meshes in *dense correspondence* are identified by vertex index, so loading must
neither merge, drop nor reorder vertices or faces:

* ``.ply`` and ``.stl`` are read with :mod:`trimesh` (``process=False``,
  ``maintain_order=True``).  Trimesh silently triangulates polygons, so the face
  count announced in the PLY header is checked to reject non-triangle meshes.
  STL stores every triangle separately; its exactly-equal vertices are merged
  (in order of first appearance, deterministic) since STL has no shared vertices.
* ``.obj`` and ``.off`` are parsed here (``v``/``f`` records, resp. the OFF
  counts): trimesh's OBJ loader drops unreferenced vertices.

:mod:`trimesh` is imported lazily, so importing :mod:`lacore` does not need it.
"""

import os

import numpy as np
import trimesh

from .atomic import atomic_write
from ..errors import MeshError

__all__ = ["load_mesh", "save_mesh", "SUPPORTED_EXTENSIONS", "MESH_FORMATS"]

SUPPORTED_EXTENSIONS = (".ply", ".obj", ".off", ".stl")
#: The same formats without the dot (the CLI's ``--format`` choices).
MESH_FORMATS = tuple(ext[1:] for ext in SUPPORTED_EXTENSIONS)


def _extension(path):
    ext = os.path.splitext(str(path))[1].lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise MeshError(f"{path}: unsupported mesh format {ext or '(no extension)'!r}; "
                        f"supported: {', '.join(SUPPORTED_EXTENSIONS)}")
    return ext


def load_mesh(path):
    """Load a triangle mesh.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply``, ``.obj``, ``.off`` or ``.stl`` file.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        In file order; no vertex is merged, removed or reordered (except the
        exact duplicates of STL, see the module docstring).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    MeshError
        For an unsupported format, an unreadable file, polygons that are not
        triangles, an empty mesh or out-of-range face indices.

    Examples
    --------
    >>> import os, tempfile
    >>> from lacore.io.meshes import load_mesh, save_mesh
    >>> from lacore.samples.bar import bar_mesh
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> path = os.path.join(tempfile.mkdtemp(), "bar.ply")
    >>> save_mesh(path, X, faces)
    >>> X2, faces2 = load_mesh(path)
    >>> bool((X2 == X).all() and (faces2 == faces).all())
    True
    """
    path = os.fspath(path)
    ext = _extension(path)
    if os.path.isdir(path):
        raise MeshError(f"{path} is a folder, not a mesh file")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such mesh file")
    try:
        if ext == ".obj":
            vertices, faces = _load_obj(path)
        elif ext == ".off":
            vertices, faces = _load_off(path)
        elif ext == ".ply":
            vertices, faces = _load_ply(path)
        else:
            vertices, faces = _load_stl(path)
    except MeshError:
        raise
    except (ValueError, IndexError, KeyError, TypeError, UnicodeDecodeError, AttributeError, OverflowError) as exc:
        raise MeshError(f"{path}: cannot read mesh ({type(exc).__name__}: {_one_line(exc)}): is it a valid "
                        f"{ext[1:].upper()} file?") from None
    return _finish(path, vertices, faces)


def _one_line(exc):
    return " ".join(str(exc).split())[:200] or type(exc).__name__


def _trimesh_load(path, ext, counts=None):
    """``trimesh.load`` of a PLY or STL file; any failure of the parser becomes a MeshError naming the file."""
    try:
        return trimesh.load(path, process=False, maintain_order=True, force="mesh")
    except Exception as exc:  # a third-party parser on arbitrary bytes: any exception means "cannot read it"
        if counts:
            announced = ", ".join(f"{n} {'vertices' if k == 'vertex' else k + 's'}" for k, n in counts.items())
            raise MeshError(f"{path}: the file does not hold what its header announces ({announced}): it is "
                            f"truncated or damaged ({type(exc).__name__}: {_one_line(exc)})") from None
        raise MeshError(f"{path}: cannot read mesh ({type(exc).__name__}: {_one_line(exc)}): is it a valid "
                        f"{ext[1:].upper()} file?") from None


def _finish(path, vertices, faces):
    vertices = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64).reshape(-1, 3))
    faces = np.asarray(faces)
    if faces.size == 0:
        raise MeshError(f"{path}: the mesh has no faces")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"{path}: faces must be triangles, got an array of shape {faces.shape}")
    faces = np.ascontiguousarray(faces.astype(np.int64))
    if len(vertices) == 0:
        raise MeshError(f"{path}: the mesh has no vertices")
    bad = np.flatnonzero((faces < 0).any(1) | (faces >= len(vertices)).any(1))
    if bad.size:
        raise MeshError(f"{path}: faces {bad[:8].tolist()} use vertex indices outside 0..{len(vertices) - 1}")
    return vertices, faces


def _non_triangle_error(path, face_index, n):
    return MeshError(f"{path}: face {face_index} has {n} vertices; only triangle meshes are supported "
                     "(triangulate the mesh first)")


def _load_obj(path):
    vertices, faces = [], []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            tokens = line.split("#", 1)[0].split()          # any whitespace, leading blanks, trailing comments
            if not tokens:
                continue
            if tokens[0] == "v":
                vertices.append(tokens[1:4])
            elif tokens[0] == "f":
                items = tokens[1:]
                if len(items) != 3:
                    raise _non_triangle_error(path, len(faces), len(items))
                idx = [int(item.split("/")[0]) for item in items]
                # 1-based; negative indices count back from the last vertex read so far
                faces.append([i - 1 if i > 0 else len(vertices) + i for i in idx])
    if any(len(v) != 3 for v in vertices):
        raise MeshError(f"{path}: a vertex record has fewer than 3 coordinates")
    return np.array(vertices, dtype=np.float64).reshape(-1, 3), np.array(faces, dtype=np.int64).reshape(-1, 3)


def _load_off(path):
    with open(path, encoding="utf-8", errors="replace") as fh:
        tokens_lines = [line.split("#", 1)[0].split() for line in fh]
    lines = [t for t in tokens_lines if t]
    if not lines or not lines[0][0].upper().endswith("OFF"):
        raise MeshError(f"{path}: not an OFF file (missing OFF header)")
    header = lines[0]
    if header[0].upper() != "OFF":
        raise MeshError(f"{path}: OFF variant {header[0]!r} is not supported")
    rest = lines[1:]
    counts = header[1:]
    if not counts:
        counts, rest = rest[0], rest[1:]
    n_v, n_f = int(counts[0]), int(counts[1])
    if len(rest) < n_v + n_f:
        raise MeshError(f"{path}: OFF file announces {n_v} vertices and {n_f} faces but is shorter")
    vertices = np.array([r[:3] for r in rest[:n_v]], dtype=np.float64).reshape(-1, 3)
    faces = []
    for i, r in enumerate(rest[n_v:n_v + n_f]):
        n = int(r[0])
        if n != 3:
            raise _non_triangle_error(path, i, n)
        faces.append(r[1:4])
    return vertices, np.array(faces, dtype=np.int64).reshape(-1, 3)


def _ply_header_counts(path):
    """Element counts announced in a PLY header (ASCII or binary files)."""
    counts = {}
    with open(path, "rb") as fh:
        first = fh.readline().strip()
        if first != b"ply":
            raise MeshError(f"{path}: not a PLY file (missing 'ply' magic)")
        for raw in fh:
            line = raw.decode("ascii", errors="replace").strip()
            if line == "end_header":
                break
            parts = line.split()
            if len(parts) == 3 and parts[0] == "element":
                try:
                    counts[parts[1]] = int(parts[2])
                except ValueError:
                    raise MeshError(f"{path}: malformed PLY header line {line!r}") from None
                if counts[parts[1]] < 0:
                    raise MeshError(f"{path}: malformed PLY header: {line!r} announces a negative count")
    return counts


def _load_ply(path):
    counts = _ply_header_counts(path)
    if not counts.get("face"):
        raise MeshError(f"{path}: the mesh has no faces (a point cloud: {counts.get('vertex', 0)} vertices): export "
                        "it with its faces")
    mesh = _trimesh_load(path, ".ply", counts)
    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces)
    n_v, n_f = counts.get("vertex", len(vertices)), counts.get("face", len(faces))
    if n_v != len(vertices) or len(faces) < n_f:
        raise MeshError(f"{path}: the header announces {n_v} vertices and {n_f} faces but the file holds "
                        f"{len(vertices)} vertices and {len(faces)} faces: it is truncated or damaged")
    if n_f and len(faces) != n_f:
        raise MeshError(f"{path}: the header announces {n_f} faces but they triangulate to {len(faces)} "
                        "triangles: only triangle meshes are supported (triangulate the mesh first)")
    return vertices, faces


def _load_stl(path):
    mesh = _trimesh_load(path, ".stl")
    soup = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)].reshape(-1, 3)
    if len(soup) == 0:
        raise MeshError(f"{path}: the mesh has no faces")
    _, first, inverse = np.unique(soup, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(first, kind="stable")  # unique vertices in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return soup[first[order]], rank[inverse].reshape(-1, 3)


def save_mesh(path, vertices, faces):
    """Write a triangle mesh; vertex and face order are kept exactly.

    ``.ply`` is written as binary float64 PLY, ``.obj`` and ``.off`` as plain
    text with full float64 precision (``repr`` round-trip): all three reload
    bit-identically.  ``.stl`` (written with trimesh) is lossy: float32, and it
    stores no shared vertices, so reading it back renumbers the vertices.

    The file is written atomically (:func:`lacore.io.atomic.atomic_write`): on
    an error an existing file at ``path`` is left unchanged.

    Examples
    --------
    Every format but STL reloads bit-identically:

    >>> import os, tempfile
    >>> from lacore.io.meshes import load_mesh, save_mesh
    >>> from lacore.samples.bar import bar_mesh
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> folder = tempfile.mkdtemp()
    >>> for ext in ("ply", "obj", "off"):
    ...     save_mesh(os.path.join(folder, "bar." + ext), X, faces)
    ...     print(ext, bool((load_mesh(os.path.join(folder, "bar." + ext))[0] == X).all()))
    ply True
    obj True
    off True
    """
    path = os.fspath(path)
    ext = _extension(path)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"vertices must have shape (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"faces must have shape (F, 3), got {faces.shape}")
    if len(faces) == 0:
        raise MeshError("the mesh has no faces")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"face indices outside 0..{len(vertices) - 1}")
    if ext in (".obj", ".off"):
        with atomic_write(path, "w") as fh:
            if ext == ".off":
                fh.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
                fh.writelines(f"{x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
                fh.writelines(f"3 {a} {b} {c}\n" for a, b, c in faces.tolist())
            else:
                fh.write("# written by lacore\n")
                fh.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
                fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist())
        return
    if ext == ".ply":
        _save_ply(path, vertices, faces)
        return
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    with atomic_write(path, "wb") as fh:
        mesh.export(fh, file_type=ext.lstrip("."))


def _save_ply(path, vertices, faces):
    """Binary little-endian PLY with float64 coordinates (lossless)."""
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by lacore\n"
        f"element vertex {len(vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face_rec = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_rec["n"] = 3
    face_rec["v"] = faces
    with atomic_write(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
        fh.write(face_rec.tobytes())
