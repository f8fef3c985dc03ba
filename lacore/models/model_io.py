"""Shape-model files: one ``.npz`` whose entries are listed once, in :data:`FIELDS`.

A file holds ``format`` (:data:`FORMAT`), ``format_version`` and one entry per
row of :data:`FIELDS`.  :func:`save_model` writes the rows, :func:`load_model`
reads them and checks presence, shape, finiteness and allowed values against
the same rows, so a new entry of the file is one new row:

* ``since`` is the :data:`FORMAT_VERSION` that introduced it (raise the
  version), ``default`` the value files of older versions mean: older files
  keep loading;
* ``shape`` names the axes with the symbols ``F`` (faces), ``E`` (edges),
  ``2E`` (entries of ``z``), ``V`` (vertices), ``J`` (modes), ``N`` (training
  samples) or a number; a new symbol is bound by the first row that uses it;
* ``role`` says where the value goes: ``"model"`` (a keyword of the
  :class:`~lacore.models.shape_model.ShapeModel` constructor), ``"settings"`` (a
  field of its :class:`~lacore.reconstruction.ReconstructionSettings`),
  ``"topology"`` (faces and edges, which make the mesh topology) or
  ``"derived"`` (written for other readers, recomputed by the model and compared
  on load);
* ``kind="record"`` rows are composite records (:data:`RECORDS`: a class with
  ``to_arrays()`` and ``from_arrays(arrays)``, e.g. the fine level, keys
  ``fine_*``), written and read by their class.
"""

import os
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, MeshError
from ..geometry.topology import MeshTopology
from ..io.atomic import save_npz_atomic
from ..io.npz import open_npz, read_array
from ..reconstruction import METHODS
from ..reconstruction.settings import WEIGHTS, ReconstructionSettings
from .settings import PROJECTION_METRICS, TANGENTS, ShapeModelError

__all__ = ["FORMAT", "FORMAT_ALIASES", "FORMAT_VERSION", "Field", "FIELDS", "save_model", "load_model"]

#: Value of the ``format`` entry of a saved model.
FORMAT = "lacore.shape_model"
#: Other ``format`` values read as :data:`FORMAT`.
FORMAT_ALIASES = ("lacore.models.shape_model",)
#: Version of the layout written by :func:`save_model`; :func:`load_model` reads versions 1 to this one.
FORMAT_VERSION = 2
#: Directions accepted for ``up_axis`` and ``forward_axis``.
AXES = ("x", "y", "z", "-x", "-y", "-z", "+x", "+y", "+z")

_REQUIRED = object()


@dataclass(frozen=True)
class Field:
    """One entry of a shape-model file (see the module docstring).

    Attributes
    ----------
    name : str
        Key in the ``.npz`` and attribute of the model.
    kind : {"float", "int", "str", "scalar", "record"}
        Float array, integer array, string, float number, or a record of :data:`RECORDS`.
    shape : tuple or None
        Axes as symbols or numbers (arrays only); ``None``: any 1-D array.
    choices : tuple or None
        Allowed values of a string.
    role : {"model", "settings", "topology", "derived"}
    since : int
        Format version that introduced the entry.
    default : object
        Value of a missing entry (files older than ``since``, or an optional entry); none: required.
    nonempty : bool
        An array with a zero-length axis is refused.
    """

    name: str
    kind: str
    shape: tuple | None = None
    choices: tuple | None = None
    role: str = "model"
    since: int = 1
    default: object = _REQUIRED
    nonempty: bool = False

    def optional_in(self, version):
        """Whether a file of format ``version`` may lack this entry."""
        return version < self.since or self.default is not _REQUIRED


#: The entries of a shape-model file, in the order they are checked.
FIELDS = (
    Field("faces", "int", ("F", 3), role="topology"),
    Field("edges", "int", ("E", 2), role="topology"),
    Field("reference_vertices", "float", ("V", 3)),
    Field("mean_z", "float", ("2E",)),
    Field("mean_vertices", "float", ("V", 3)),
    Field("linear_mean_z", "float", ("2E",)),
    Field("modes", "float", ("J", "2E"), nonempty=True),
    Field("variances", "float", ("J",)),
    Field("explained_variance_ratio", "float", ("J",)),
    Field("total_variance", "scalar"),
    Field("training_coefficients", "float", ("N", "J")),
    Field("all_eigenvalues", "float", None, default=None),
    Field("metric_weights", "float", ("2E",), role="derived"),
    Field("bending_weight", "scalar", role="settings"),
    Field("weights", "str", choices=WEIGHTS, role="settings"),
    Field("tangent", "str", choices=TANGENTS),
    Field("projection_metric", "str", choices=PROJECTION_METRICS),
    Field("method", "str", choices=METHODS),
    Field("length_unit", "scalar", since=2, default=None),
    Field("up_axis", "str", choices=AXES, since=2, default=None),
    Field("forward_axis", "str", choices=AXES, since=2, default=None),
    Field("fine_level", "record", since=2, default=None),
)


def _records():
    from .fine_level import FineLevel
    return {"fine_level": (FineLevel, "fine_")}


#: Composite rows: name -> (class, key prefix); filled on first use (import order).
RECORDS = {}


def _encode(field, value):
    if field.kind == "str":
        return np.array(str(value))
    if field.kind == "scalar":
        return np.array(float(value))
    return np.asarray(value)


def save_model(model, path):
    """Write ``model`` (every row of :data:`FIELDS`) to one ``.npz`` file, atomically.

    The file appears complete or not at all (a temporary file in the same
    folder, then a rename; :func:`lacore.io.atomic.atomic_write`).  Entries whose
    value is None are left out (they load as their default).

    Parameters
    ----------
    model : ShapeModel
    path : str, path-like or binary file object
        ``.npz`` is appended to a file name without it (as :func:`numpy.savez` does).

    Returns
    -------
    str or None
        The path written (None for a file object).
    """
    data = {"format": np.array(FORMAT), "format_version": np.array(FORMAT_VERSION)}
    for field in FIELDS:
        value = getattr(model, field.name, None)
        if value is None:
            continue
        if field.kind == "record":
            data.update(value.to_arrays())
        else:
            data[field.name] = _encode(field, value)
    if not isinstance(path, (str, os.PathLike)):  # a binary file object
        np.savez(path, **data)
        return None
    return save_npz_atomic(path, **data)


def _source_name(path):
    if isinstance(path, (str, os.PathLike)):
        return os.fspath(path)
    return getattr(path, "name", None) or "the model data"


def _read(path, name):
    """``(version, {entry: array})`` of the file; ShapeModelError for anything but a readable model file."""
    def read(key):  # one array; object arrays and damaged members are refused naming the file
        return read_array(npz, key, name, "shape model", ShapeModelError)

    with open_npz(path if not isinstance(path, os.PathLike) else os.fspath(path), "shape model",
                  ShapeModelError) as npz:
        keys = set(npz.files)
        fmt = read("format") if "format" in keys else None
        if fmt is None or fmt.shape != () or fmt.dtype.kind != "U" or str(fmt) not in (FORMAT, *FORMAT_ALIASES):
            raise ShapeModelError(f"{name} is not a lacore shape model (no format entry {FORMAT!r})")
        version = read("format_version") if "format_version" in keys else np.array(-1)
        if version.shape != () or version.dtype.kind not in "iu" or not 1 <= int(version) <= FORMAT_VERSION:
            known = "version 1" if FORMAT_VERSION == 1 else f"versions 1 to {FORMAT_VERSION}"
            raise ShapeModelError(f"{name} has shape-model format version {version.tolist()!r}; this lacore reads "
                                  f"{known}")
        version = int(version)
        missing = [f.name for f in FIELDS if f.name not in keys and f.kind != "record" and not f.optional_in(version)]
        if missing:
            raise ShapeModelError(f"{name} is a corrupt shape model: missing {', '.join(missing)}")
        raw = {f.name: read(f.name) for f in FIELDS if f.name in keys and f.kind != "record"}
        RECORDS.update(RECORDS or _records())
        for field in FIELDS:
            if field.kind == "record":
                prefix = RECORDS[field.name][1]
                sub = {k: read(k) for k in keys if k.startswith(prefix)}
                if sub:
                    raw[field.name] = sub
        return version, raw


def _decode(field, raw, dims, name):
    """The value of one entry, checked against its row; ``dims`` binds the shape symbols."""
    def corrupt(what):
        return ShapeModelError(f"{name} is a corrupt shape model: {field.name} {what}")

    if field.kind == "str":
        value = str(raw) if raw.ndim == 0 else raw.tolist()
        if raw.ndim != 0 or raw.dtype.kind != "U" or (field.choices is not None and value not in field.choices):
            raise corrupt(f"must be one of {', '.join(field.choices or ())}, got {value!r}")
        return value
    if field.kind == "scalar":
        if raw.ndim != 0 or raw.dtype.kind not in "fiu" or not np.isfinite(raw):
            raise corrupt(f"must be a finite number, got {raw.tolist()!r}")
        return float(raw)
    if raw.dtype.kind not in ("iu" if field.kind == "int" else "fiu"):
        raise corrupt(f"must hold {'integers' if field.kind == 'int' else 'real numbers'}, got {raw.dtype} values")
    expected = field.shape if field.shape is not None else (None,)
    if raw.ndim == len(expected):
        for axis, symbol in zip(raw.shape, expected, strict=True):
            if isinstance(symbol, str) and symbol not in dims:
                dims[symbol] = axis
    want = tuple(raw.shape[i] if i < raw.ndim and s is None else dims.get(s, s) for i, s in enumerate(expected))
    if raw.shape != want:
        raise corrupt(f"has shape {raw.shape}, expected {want}")
    if field.nonempty and raw.size == 0:
        raise corrupt("is empty: the model has no modes" if field.name == "modes" else "is empty")
    if field.kind == "int":
        return raw.astype(np.int64)
    if not np.all(np.isfinite(raw)):
        raise corrupt("has NaN or infinite entries")
    return raw.astype(float)


def _decode_record(field, arrays, name):
    """A composite entry (:data:`RECORDS`) from its ``prefix*`` arrays; ShapeModelError naming the file if corrupt."""
    cls = RECORDS[field.name][0]
    try:
        return cls.from_arrays(arrays)
    except (InputError, MeshError, ValueError, KeyError, TypeError) as exc:
        raise ShapeModelError(f"{name} is a corrupt shape model: its {field.name.replace('_', ' ')}: {exc}") from None


def _check_values(values, name):
    """The values a model needs beyond its fields' shapes: modes, positive variances and lengths, ratios in [0, 1]."""
    def corrupt(key, what):
        return ShapeModelError(f"{name} is a corrupt shape model: {key} {what}")

    if np.any(values["variances"] <= 0):
        raise corrupt("variances", f"must be positive, got {np.min(values['variances']):g}")
    ratio = values["explained_variance_ratio"]
    if np.any(ratio < 0) or np.sum(ratio) > 1.0 + 1e-9:
        raise corrupt("explained_variance_ratio", "must be in [0, 1] with a sum of at most 1")
    if values["total_variance"] <= 0:
        raise corrupt("total_variance", f"must be positive, got {values['total_variance']:g}")
    if values["bending_weight"] < 0:
        raise corrupt("bending_weight", f"must be >= 0, got {values['bending_weight']:g}")
    E = len(values["edges"])
    if np.any(values["mean_z"][:E] <= 0):
        raise corrupt("mean_z", "has lengths <= 0")


def load_model(path, cls, faces=None):
    """Read a model written by :func:`save_model` (any format version up to :data:`FORMAT_VERSION`).

    Parameters
    ----------
    path : str, path-like or binary file object
    cls : type
        The model class (:class:`~lacore.models.shape_model.ShapeModel`), called with
        ``topology``, ``settings`` and the ``"model"`` rows as keywords.
    faces : (F, 3) array_like, optional
        If given, the model must have exactly these faces.

    Returns
    -------
    ShapeModel

    Raises
    ------
    ShapeModelError
        Not a shape-model file, another format version, missing, inconsistent or
        non-finite entries, or other faces than ``faces``.
    FileNotFoundError
    """
    name = _source_name(path)
    version, raw = _read(path, name)
    dims = {}
    values = {}
    for field in FIELDS:
        if field.name not in raw:
            values[field.name] = field.default
            continue
        if field.kind == "record":
            values[field.name] = _decode_record(field, raw[field.name], name)
            continue
        values[field.name] = _decode(field, raw[field.name], dims, name)
        if "E" in dims:
            dims.setdefault("2E", 2 * dims["E"])
    _check_values(values, name)
    try:
        topology = MeshTopology.from_faces(values["faces"], edges=values["edges"],
                                           n_vertices=len(raw["reference_vertices"]))
    except MeshError as exc:
        raise ShapeModelError(f"{name} is a corrupt shape model: {exc}") from None
    try:
        settings = ReconstructionSettings(**{f.name: values[f.name] for f in FIELDS if f.role == "settings"})
    except InputError as exc:
        raise ShapeModelError(f"{name} is a corrupt shape model: {exc}") from None
    try:
        model = cls(topology=topology, settings=settings,
                    **{f.name: values[f.name] for f in FIELDS if f.role == "model"})
    except InputError as exc:  # e.g. a reference mesh with degenerate triangles
        raise ShapeModelError(f"{name} is a corrupt shape model: {exc}") from None
    for field in FIELDS:
        if field.role == "derived" and values[field.name] is not None and not np.allclose(
                getattr(model, field.name), values[field.name], rtol=1e-12, atol=0):
            raise ShapeModelError(f"{name} is a corrupt shape model: its {field.name} do not match its reference "
                                  "mesh")
    fine = model.fine_level
    if fine is not None and (fine.coarsening.n_vertices != len(model.reference_vertices)
                             or fine.key_coefficients.shape[1] != model.n_modes):
        raise ShapeModelError(f"{name} is a corrupt shape model: its fine level does not match its "
                              f"{len(model.reference_vertices)} vertices and {model.n_modes} modes")
    if faces is not None:
        model.check_mesh(faces=faces)
    return model
