"""Shape-mixer files: one ``.npz`` with ``format`` (:data:`FORMAT`), ``format_version`` (:data:`FORMAT_VERSION`), the
keys, the faces, the options (:meth:`MixerOptions.to_array`) and the reduced model (basis, cubature edges and
weights, expansions, indicator and correction data, the local correction's vertices, build seconds); a file
without ``local_vertices`` mixes without the local correction.  Loading validates every entry's shape and
finiteness and raises :class:`MixerError` naming the file and what to do.
"""

import os
import tempfile

import numpy as np

from ...errors import InputError
from ...io.atomic import save_npz_atomic
from ...io.npz import open_npz, read_array

__all__ = ["save_mixer", "load_mixer", "mixer_bytes", "build_mixer_bytes", "FORMAT", "FORMAT_VERSION"]

#: Value of the ``format`` entry of a saved mixer.
FORMAT = "lacore.shape_mixer"
#: Version of the layout :func:`save_mixer` writes; :func:`load_mixer` reads this one.
FORMAT_VERSION = 2


def save_mixer(mixer, path):
    """Write ``mixer`` (a :class:`ShapeMixer`) to ``path`` (``.npz`` appended unless it ends so), atomically; returns
    the path written."""
    cub = mixer._cubature
    data = {"format": np.array(FORMAT), "format_version": np.array(FORMAT_VERSION),
            "keys": mixer.keys, "faces": mixer.faces, "options": mixer.options.to_array(),
            "basis": mixer.basis, "cubature_edges": cub.edges, "cubature_weights": cub.c,
            "expansion_weights": mixer._exp_w, "expansion_q": mixer._exp_q, "expansion_order": mixer._exp_order,
            "expansion_first": mixer._exp_A, "expansion_second": mixer._exp_T,
            "indicator_weights": np.zeros((0, mixer.n_keys - 1)) if mixer._error_w is None else mixer._error_w,
            "indicator_values": np.zeros(0) if mixer._error_v is None else mixer._error_v,
            "correction_weights": np.zeros((0, mixer.n_keys - 1)) if mixer._corr_w is None else mixer._corr_w,
            "correction": (np.zeros((0, mixer.n_keys, mixer.reduced_size)) if mixer._corr is None else mixer._corr),
            "local_vertices": mixer.local_vertices,
            "build_stages": np.array(list(mixer.build_seconds), dtype=str),
            "build_seconds": np.array(list(mixer.build_seconds.values()), float)}
    return save_npz_atomic(path, **data)


def load_mixer(cls, path):
    """A ``cls`` (:class:`ShapeMixer`) read from a file written by :func:`save_mixer`; :class:`MixerError` naming the
    file for anything else."""
    from .mixer import _OPTION_FIELDS, MixerError, MixerOptions
    name = os.fspath(path) if isinstance(path, (str, os.PathLike)) else str(path)
    what = "shape mixer"
    with open_npz(path, what, MixerError) as npz:
        keys = set(npz.files)
        fmt = np.asarray(npz["format"]) if "format" in keys else None
        if fmt is None or fmt.shape != () or fmt.dtype.kind != "U" or str(fmt) != FORMAT:
            raise MixerError(f"{name} is not a lacore shape mixer (no format entry {FORMAT!r})")
        version = np.asarray(npz["format_version"]) if "format_version" in keys else np.array(-1)
        if version.shape != () or version.dtype.kind not in "iu" or int(version) != FORMAT_VERSION:
            raise MixerError(f"{name} has shape-mixer format version {version.tolist()!r}; this lacore reads "
                             f"version {FORMAT_VERSION}: rebuild the mixer from its keys")

        def read(key, kind, ndim):
            return read_array(npz, key, name, what, MixerError, kind=kind, ndim=ndim)

        K = read("keys", "f", 3)
        F = read("faces", "i", 2)
        opt = read("options", "f", 1)
        U = read("basis", "f", 2)
        edges = read("cubature_edges", "i", 1)
        c = read("cubature_weights", "f", 1)
        ew = read("expansion_weights", "f", 2)
        eq = read("expansion_q", "f", 2)
        eo = read("expansion_order", "i", 1)
        eA = read("expansion_first", "f", 3)
        eT = read("expansion_second", "f", 4)
        iw = read("indicator_weights", "f", 2)
        iv = read("indicator_values", "f", 1)
        cw = read("correction_weights", "f", 2)
        cc = read("correction", "f", 3)
        hot = read("local_vertices", "i", 1) if "local_vertices" in keys else np.zeros(0, np.int64)
        stages = read("build_stages", "U", 1)
        secs = read("build_seconds", "f", 1)
    n_opt = len(_OPTION_FIELDS)
    if opt.shape == (n_opt - 2,):            # written before cubature_energy_norm and local_vertices: without them
        opt = np.append(opt, [0.0, 0.0])
    elif opt.shape == (n_opt - 1,):          # written before local_vertices: built without a local correction
        opt = np.append(opt, 0.0)
    if opt.shape != (len(_OPTION_FIELDS),):
        raise MixerError(f"{name}: 'options' must hold {len(_OPTION_FIELDS)} numbers, got {opt.size}")
    try:
        mixer = cls(K, F, MixerOptions.from_array(opt))
    except InputError as exc:
        raise MixerError(f"{name} is not a valid shape mixer: {exc}") from None
    V, m = mixer.n_vertices, mixer.n_keys - 1
    r = U.shape[1] if U.ndim == 2 else 0
    P = len(ew)
    expect = {"basis": (U.shape, (3 * V, r)), "cubature_weights": (c.shape, edges.shape),
              "expansion_weights": (ew.shape, (P, m)), "expansion_q": (eq.shape, (P, r)),
              "expansion_order": (eo.shape, (P,)), "expansion_first": (eA.shape, (P, r, m)),
              "expansion_second": (eT.shape, (P, m, m, r)), "build_seconds": (secs.shape, stages.shape),
              "indicator_weights": (iw.shape, (len(iv), m)), "correction_weights": (cw.shape, (len(cc), m)),
              "correction": (cc.shape, (len(cw), m + 1, r))}
    for key, (got, want) in expect.items():
        if got != want:
            raise MixerError(f"{name}: '{key}' has shape {got}, expected {want}: the file is damaged; rebuild "
                             "the mixer")
    bad = [k for k, a in (("basis", U), ("cubature_weights", c), ("expansion_q", eq), ("expansion_first", eA),
                          ("expansion_second", eT), ("correction", cc)) if not np.all(np.isfinite(a))]
    if len(hot) and (hot.min() < 0 or hot.max() >= V or np.any(np.diff(hot) <= 0)):
        bad.append("local_vertices")
    if bad or r < 1 or edges.size == 0 or edges.min() < 0 or edges.max() >= mixer.n_edges or np.any(c < 0):
        raise MixerError(f"{name}: the reduced model is damaged ({', '.join(bad) or 'cubature'}); rebuild the "
                         "mixer")
    mixer.basis = np.ascontiguousarray(U)
    mixer._exp_w, mixer._exp_q, mixer._exp_order, mixer._exp_A, mixer._exp_T = ew, eq, eo, eA, eT
    mixer._output_basis()
    if len(iv):
        mixer._error_w, mixer._error_v = iw, iv
    if len(cw):
        mixer._corr_w, mixer._corr = cw, cc
    mixer._cubature = mixer._make_energy(edges, c)
    mixer._set_local(hot)
    mixer.build_seconds = dict(zip(stages.tolist(), secs.tolist(), strict=True))
    return mixer


def mixer_bytes(mixer):
    """The file :func:`save_mixer` writes for ``mixer``, as bytes (``ShapeMixer.load(io.BytesIO(data))`` reads it)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = save_mixer(mixer, os.path.join(tmp, "mixer.npz"))
        with open(path, "rb") as fh:
            return fh.read()


def build_mixer_bytes(keys, faces, options=None, *, progress=None):
    """:meth:`ShapeMixer.build` returning :func:`mixer_bytes`: what crosses a process boundary
    (:func:`lacore.parallel.call_in_process`; a built mixer holds sparse factorizations, which do not pickle)."""
    from .mixer import ShapeMixer
    return mixer_bytes(ShapeMixer.build(keys, faces, options, progress=progress))
