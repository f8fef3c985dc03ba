"""Shape-mixer files: one ``.npz`` with ``format`` (:data:`FORMAT`), ``format_version`` (:data:`FORMAT_VERSION`) and
the arrays of :data:`ENTRIES`: the keys, the faces, the options (:meth:`MixerOptions.to_array`), the keys' masks,
relative keys and shapes at weight 1 (``corners``), and the reduced model (the faces its coordinates hold still,
basis, cubature edges and weights, expansions, indicator and correction data, the local correction's vertices,
build seconds); a file without ``local_vertices`` mixes without the local correction.

This module knows the layout of the file and nothing of the mixer: :meth:`ShapeMixer.save` hands it the arrays,
:meth:`ShapeMixer.load` checks that the arrays it reads fit together.
"""

import os

import numpy as np

from ...errors import InputError
from ...io.atomic import save_npz_atomic
from ...io.npz import open_npz, read_array

__all__ = ["write_mixer_file", "read_mixer_file", "FORMAT", "FORMAT_VERSION", "READ_VERSIONS", "ENTRIES",
           "OPTIONAL_ENTRIES"]

#: Value of the ``format`` entry of a saved mixer.
FORMAT = "lacore.shape_mixer"
#: Version of the layout :func:`write_mixer_file` writes; :func:`read_mixer_file` reads this one.
FORMAT_VERSION = 4

#: Versions :func:`read_mixer_file` reads: version 2 files have no masks, relative keys or corners (their keys are
#: relative to the basis, unmasked); version 2 and 3 files do not name their fixed faces.
READ_VERSIONS = (2, 3, 4)

#: The arrays of a mixer file: ``name: (kind, ndim)`` (kinds as :func:`lacore.io.npz.read_array`'s).
ENTRIES = {
    "keys": ("f", 3), "faces": ("i", 2), "options": ("f", 1), "basis": ("f", 2),
    "cubature_edges": ("i", 1), "cubature_weights": ("f", 1),
    "expansion_weights": ("f", 2), "expansion_q": ("f", 2), "expansion_order": ("i", 1),
    "expansion_first": ("f", 3), "expansion_second": ("f", 4),
    "indicator_weights": ("f", 2), "indicator_values": ("f", 1),
    "correction_weights": ("f", 2), "correction": ("f", 3),
    "local_vertices": ("i", 1), "fixed_faces": ("i", 1),
    "masks": ("f", 2), "relative_to": ("i", 1), "corners": ("f", 3),
    "build_stages": ("U", 1), "build_seconds": ("f", 1),
}

#: Entries a file may lack, with what stands in for them (None: the mixer's default): files written before the local
#: correction have no ``local_vertices`` (none), version 2 files no ``masks`` (1), ``relative_to`` (the basis) and
#: ``corners`` (the keys), version 2 and 3 files no ``fixed_faces`` (the faces whose 3-2-1 coordinates the basis
#: vanishes on).
OPTIONAL_ENTRIES = {"local_vertices": np.zeros(0, np.int64), "masks": None, "relative_to": None, "corners": None,
                    "fixed_faces": None}


def write_mixer_file(path, arrays):
    """Write the mixer ``arrays`` (every name of :data:`ENTRIES`) to ``path`` (``.npz`` appended unless it ends so)
    with the format and its version, atomically; returns the path written."""
    missing = sorted(set(ENTRIES) - set(arrays))
    if missing:
        raise InputError(f"a mixer file needs the arrays {', '.join(missing)}")
    return save_npz_atomic(path, format=np.array(FORMAT), format_version=np.array(FORMAT_VERSION),
                           **{name: arrays[name] for name in ENTRIES})


def read_mixer_file(path, error=InputError):
    """The arrays of :data:`ENTRIES` in a file written by :func:`write_mixer_file`, each of its kind and number of
    dimensions (floats as float64, integers as int64).

    Raises
    ------
    error
        Naming the file: not a shape mixer, another format version, an entry missing or of another kind.
    """
    name = os.fspath(path) if isinstance(path, (str, os.PathLike)) else str(path)
    what = "shape mixer"
    with open_npz(path, what, error) as npz:
        present = set(npz.files)
        fmt = np.asarray(npz["format"]) if "format" in present else None
        if fmt is None or fmt.shape != () or fmt.dtype.kind != "U" or str(fmt) != FORMAT:
            raise error(f"{name} is not a lacore shape mixer (no format entry {FORMAT!r})")
        version = np.asarray(npz["format_version"]) if "format_version" in present else np.array(-1)
        if version.shape != () or version.dtype.kind not in "iu" or int(version) not in READ_VERSIONS:
            raise error(f"{name} has shape-mixer format version {version.tolist()!r}; this lacore reads "
                        f"versions {READ_VERSIONS[0]} to {READ_VERSIONS[-1]}: rebuild the mixer from its keys")
        arrays = {}
        for key, (kind, ndim) in ENTRIES.items():
            if key not in present and key in OPTIONAL_ENTRIES:
                default = OPTIONAL_ENTRIES[key]
                arrays[key] = None if default is None else default.copy()
            else:
                arrays[key] = read_array(npz, key, name, what, error, kind=kind, ndim=ndim)
    return arrays
