# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: in-betweens of two shape keys and baked keyframe in-betweens (thesis 4.2).

Both operators follow the pattern of :mod:`.operators`: read the shape keys,
compute every result with :mod:`..lacore.interpolation` (linear or cubic spline
in lengths and angles, then projection onto admissible lengths and angles by
reconstruction), and only then write to Blender.  Any error is reported as
ERROR and returns CANCELLED with the object unchanged.

Results that fail their checks
------------------------------
A reconstruction whose result fails the checks of
:mod:`lacore.reconstruction.checks` (``success=False``: folded faces, or a
minimizer that did not converge) is still written -- it is the best shape the
method found, Blender's undo removes it, and hiding it would leave the user
with nothing to inspect -- and the operator reports a WARNING naming how many
frames failed and the first failure (:func:`failure_warning`) instead of the
INFO line.  For 'PREVIEW' (the least-squares relaxation, which minimizes
nothing) a non-admissible target that is merely not reproduced is expected and
not reported; folds are.

Output placement
----------------
A reconstruction is determined up to a rigid motion.  Every result is placed by
a rigid (Kabsch) fit to the *linear blend of the key coordinates* at the same
time (``(1 - t) A + t B`` for :class:`LENGTHS_ANGLES_OT_interpolate`, the
piecewise-linear blend of the keyframed keys for
:class:`LENGTHS_ANGLES_OT_bake_keyframes`).  So the in-betweens follow the keys
without drifting or rotating about a single fixed triangle; at ``t = 0`` and
``t = 1`` they coincide with the keys themselves (up to float32 round-off).

Marking
-------
* In-betweens are named ``"LA <from>><to> <t>"`` (e.g. ``"LA Basis>Bend 0.250"``);
  re-running with the same keys and factors overwrites those keys in place.
* Baked keys are named ``"LA bake <frame>"`` (e.g. ``"LA bake 012"``).  The mesh
  ID property ``"lengths_angles_bake"`` lists the baked keys, the data paths of
  the F-curves the bake created and the values the keyframed user keys had
  before, so a new bake removes exactly the previous one (keys carrying the
  prefix AND listed there) and nothing else.
"""

import hashlib
import math
import re
import traceback
from collections import OrderedDict
from contextlib import contextmanager

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..lacore.errors import InputError, MeshError
from ..lacore.interpolation import keyframe_inbetweens, piecewise_linear_z
from ..lacore.reconstruction import GaussNewtonOptions, HybridOptions
from ..lacore.rigid import rigid_align
from ..lacore.topology import MeshTopology
from . import compat, mesh_access

__all__ = ["LENGTHS_ANGLES_OT_interpolate", "LENGTHS_ANGLES_OT_bake_keyframes", "classes", "parse_factors",
           "parse_key_list", "parse_frames", "inbetween_key_name", "bake_key_name", "interpolate_object",
           "failure_warning", "bake_object", "inbetween_shapes", "read_mesh", "write_key", "BAKE_PROP", "BAKE_PREFIX",
           "INBETWEEN_PREFIX"]

INBETWEEN_PREFIX = "LA "
BAKE_PREFIX = "LA bake "
BAKE_PROP = "lengths_angles_bake"
MAX_NEW_KEYS = 1000
_NAME_BYTES = 63  # Blender's shape-key names hold 63 bytes

METHOD_ITEMS = [
    ('PREVIEW', "Preview", "Least-squares relaxation of the frame-based reconstruction only (one linear solve "
                           "over the whole mesh): quickest, edge lengths within ~1.5 % on strong blends"),
    ('FAST', "Fast", "Least-squares relaxation followed by two Gauss-Newton smoothing steps that reuse "
                     "factorizations: near the exact projection at a fraction of its cost"),
    ('GAUSS_NEWTON', "Gauss-Newton", "Energy-based projection: Gauss-Newton run to convergence (slowest, "
                                     "most accurate)"),
]
_LACORE_METHOD = {'PREVIEW': "lsq", 'FAST': "hybrid", 'GAUSS_NEWTON': "gn"}
# Measured on a 50k-vertex bar (benchmarks/bench_blender_interpolate.py, README): PREVIEW ~1.6 s per
# in-between with edge lengths within ~1.4 % on a bend -> twist blend; FAST ~5.4 s per in-between (the
# first version, an MST walk + 3 Gauss-Newton iterations, took ~20 s and left 160 % errors there, because a
# tree walk accumulates the integrability error along the tree); the two smoothing steps are what small
# meshes with non-admissible targets need (tests/test_blender_interpolate.py: n-gon prism).
_METHOD_OPTIONS = {'PREVIEW': {},
                   'FAST': {"hybrid": HybridOptions(start="lsq", smoothing_iterations=2),
                            "options": GaussNewtonOptions(reuse_factorization=True)},
                   'GAUSS_NEWTON': {}}


class InterpolationInputError(InputError):
    """Unusable operator input (unknown key, bad factor list ...)."""


# ----------------------------------------------------------------------------- parsing and naming
def parse_factors(text):
    """``"0.25 0.5, 0.75 1.5"`` -> ``[0.25, 0.5, 0.75, 1.5]`` (spaces and/or commas separate)."""
    items = [s for s in re.split(r"[\s,;]+", text.strip()) if s]
    factors = []
    for s in items:
        try:
            t = float(s)
        except ValueError:
            raise InterpolationInputError(f"Factors: cannot read {s!r} as a number (use numbers separated by "
                                          "spaces or commas, e.g. \"0.25 0.5 0.75 1.5\")") from None
        if not math.isfinite(t):
            raise InterpolationInputError(f"Factors: {s!r} is not a finite number")
        factors.append(t)
    if not factors:
        raise InterpolationInputError("Factors: no numbers given")
    return factors


def parse_key_list(text):
    """``"Basis, Bend, Twist"`` -> ``["Basis", "Bend", "Twist"]`` (commas separate; names may hold spaces)."""
    names = [s.strip() for s in text.split(",")]
    if not any(names):
        raise InterpolationInputError("Keys: no shape-key names given (separate them by commas)")
    if not all(names):
        raise InterpolationInputError(f"Keys: empty name in {text!r} (separate names by single commas)")
    return names


def parse_frames(text):
    """``"1, 12 24"`` -> ``[1, 12, 24]`` (integers separated by spaces or commas)."""
    items = [s for s in re.split(r"[\s,;]+", text.strip()) if s]
    if not items:
        raise InterpolationInputError("Frames: no frame numbers given")
    frames = []
    for s in items:
        try:
            value = float(s)
        except ValueError:
            raise InterpolationInputError(f"Frames: cannot read {s!r} as a frame number") from None
        if not math.isfinite(value) or value != int(value):
            raise InterpolationInputError(f"Frames: {s!r} is not a whole frame number")
        frames.append(int(value))
    return frames


def _fit(name, n_bytes):
    data = name.encode("utf-8")
    return name if len(data) <= n_bytes else data[: max(n_bytes - 1, 1)].decode("utf-8", "ignore") + "~"


def inbetween_key_name(key_from, key_to, t):
    """``"LA <from>><to> <t:.3f>"``, the key names shortened if needed to fit 63 bytes."""
    suffix = f" {t:.3f}"
    room = _NAME_BYTES - len((INBETWEEN_PREFIX + ">" + suffix).encode("utf-8"))
    a, b = key_from, key_to
    if len(a.encode()) + len(b.encode()) > room:
        half = room // 2
        a, b = _fit(a, half), _fit(b, room - half)
    return f"{INBETWEEN_PREFIX}{a}>{b}{suffix}"


def bake_key_name(frame):
    """``"LA bake 012"``."""
    return f"{BAKE_PREFIX}{frame:03d}"


def _value_path(name):
    return f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'


# ----------------------------------------------------------------------------- reading (no writes)
# The last topologies by connectivity: lacore caches everything that does not depend on the
# targets on the topology (Gauss-Newton pattern, fill-reducing ordering, symbolic factorization,
# reconstruction contexts), so re-running the operator (redo panel) on the same mesh skips that set-up.
_TOPOLOGIES = OrderedDict()
_TOPOLOGY_CACHE_SIZE = 1  # a 50k-vertex factorization holds ~0.5 GB


def read_mesh(obj):
    """Validated ``(mesh, names, coords (K, V, 3), topology)`` of a mesh object with shape keys."""
    mesh = mesh_access.require_mesh_object(obj)
    if obj.mode == 'EDIT':
        obj.update_from_editmode()  # make edit-mode changes visible in the mesh data
    names, coords = mesh_access.read_shape_keys(mesh)
    tri = mesh_access.triangulate(mesh)
    key = (tri.n_vertices, hashlib.blake2b(tri.faces.tobytes() + b"|" + tri.edges.tobytes()).hexdigest())
    topology = _TOPOLOGIES.get(key)
    if topology is None:
        try:
            topology = MeshTopology.from_faces(tri.faces, edges=tri.edges, n_vertices=tri.n_vertices)
        except MeshError as exc:
            raise MeshError(f"Mesh '{mesh.name}' cannot be interpolated: {exc}") from exc
        _TOPOLOGIES[key] = topology
        while len(_TOPOLOGIES) > _TOPOLOGY_CACHE_SIZE:
            _TOPOLOGIES.popitem(last=False)
    else:
        _TOPOLOGIES.move_to_end(key)
    return mesh, names, coords, topology


def _require_keys(names, wanted, what):
    missing = [w for w in wanted if w not in names]
    if missing:
        shown = ", ".join(f"'{m}'" for m in missing)
        have = ", ".join(f"'{n}'" for n in names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
        raise InterpolationInputError(f"{what}: no shape key {shown} (the mesh has {have})")


def interpolate_object(obj, key_from, key_to, factors, method='FAST', progress=None, failures=None):
    """Compute in-betweens of two shape keys WITHOUT touching Blender data.

    Returns a list of ``(key name, (V, 3) float64 coordinates)``, one per factor,
    placed as described in the module docstring.  Raises
    :class:`lacore.errors.InputError` subclasses for unusable input.
    """
    if not key_from or not key_to:
        raise InterpolationInputError("Choose the two shape keys to interpolate between (From and To)")
    if key_from == key_to:
        raise InterpolationInputError(f"From and To are the same shape key '{key_from}': choose two different keys")
    mesh, names, coords, topology = read_mesh(obj)
    _require_keys(names, [key_from, key_to], f"Mesh '{mesh.name}'")
    out_names = [inbetween_key_name(key_from, key_to, t) for t in factors]
    seen = {}
    for t, n in zip(factors, out_names, strict=True):
        if n in seen and seen[n] != t:
            raise InterpolationInputError(f"Factors {seen[n]:g} and {t:g} give the same key name '{n}' "
                                          "(3 decimals): use factors that differ in the first 3 decimals")
        seen[n] = t
    clash = [n for n in out_names if n in (key_from, key_to)]
    if clash:
        raise InterpolationInputError(f"The result '{clash[0]}' would overwrite one of the input keys")
    unique = list(dict.fromkeys(out_names))
    factors = [seen[n] for n in unique]
    if len(unique) > MAX_NEW_KEYS:
        raise InterpolationInputError(f"{len(unique)} in-betweens requested; at most {MAX_NEW_KEYS}")
    A, B = coords[names.index(key_from)], coords[names.index(key_to)]
    return list(zip(unique, inbetween_shapes(topology, A, B, factors, method, progress, failures), strict=True))


def inbetween_shapes(topology, A, B, factors, method='FAST', progress=None, failures=None):
    """The placed in-betweens ``[(V, 3)]`` of the shapes ``A`` (t = 0) and ``B`` (t = 1) at ``factors``.

    ``failures`` (a list, optional) collects the frames failing their checks, see :func:`_project`.
    """
    results = _inbetweens(topology, A, B, factors, method, progress, failures)
    return [rigid_align(X, (1.0 - t) * A + t * B) for t, X in zip(factors, results, strict=True)]


def _inbetweens(topology, A, B, factors, method, progress, failures=None):
    """Projected linear interpolation/extrapolation of the lengths and angles of ``A`` (t = 0) and ``B`` (t = 1)."""
    return _project(topology, [A, B], [0.0, 1.0], factors, False, method, progress, failures)


def _keyframe_shapes(topology, shapes, keyframes, frames, smooth, method, progress, failures=None):
    """Projected piecewise-linear (or cubic spline) lengths and angles of the keyed shapes at ``frames``."""
    return _project(topology, shapes, keyframes, frames, smooth, method, progress, failures)


def _project(topology, shapes, keyframes, times, smooth, method, progress, failures=None):
    """:func:`lacore.interpolation.keyframe_inbetweens` of the shapes at ``times`` (list of ``(V, 3)``).

    ``progress(done, total, message)`` is called after every frame (:mod:`lacore.progress`).
    Frames whose reconstruction failed its checks (:mod:`lacore.reconstruction.checks`) are
    appended to ``failures`` as ``"t = ...: <failure>: <message>"``; for 'PREVIEW' (the
    least-squares relaxation, which minimizes nothing) a target that is merely not reproduced
    is expected and not listed, folds are.
    """
    res = keyframe_inbetweens(shapes, topology, keyframes, frames=np.asarray(times, float), smooth=smooth,
                              method=_LACORE_METHOD[method], progress=progress, **_METHOD_OPTIONS[method])
    if failures is not None:
        for t, r in zip(res.times, res.reconstructions, strict=True):
            if not r.success and not (method == 'PREVIEW' and r.failure == "not_reproduced"):
                failures.append(f"t = {float(t):g}: {r.failure}: {r.message}")
    return list(res.vertices)


def failure_warning(failures, what="in-between"):
    """The operator's WARNING text for frames that failed their checks (written anyway), or None."""
    if not failures:
        return None
    n = len(failures)
    return (f"{n} {what}{'s' if n != 1 else ''} failed the reconstruction checks and {'were' if n != 1 else 'was'} "
            f"written anyway (inspect, undo, or use the Gauss-Newton method): {failures[0]}")


def _check_finite(results, what):
    for name, X in results:
        if not np.all(np.isfinite(X)):
            raise InterpolationInputError(f"{what}: the reconstruction of '{name}' is not finite (the lengths "
                                          "and angles are too far from any shape; try smaller factors)")


# ----------------------------------------------------------------------------- bake planning (no writes)
def _channelbag(key):
    """The F-curve container of the action assigned to the Key datablock ``key`` (or None)."""
    return compat.animation_channels(key)


def read_bake_record(mesh):
    """The record of the previous bake on ``mesh`` as plain data (empty lists if there is none)."""
    rec = mesh.get(BAKE_PROP)
    if rec is None:
        return {"keys": [], "fcurves": [], "values_before": {}, "action": "", "source": {}}
    rec = rec.to_dict()
    return {"keys": list(rec.get("keys", [])), "fcurves": list(rec.get("fcurves", [])),
            "values_before": dict(rec.get("values_before", {})), "action": str(rec.get("action", "")),
            "source": dict(rec.get("source", {}))}


def activity_keyframes(active_frames, first, last):
    """Keyframes ``[(frame, value)]`` of a key that is 1 exactly at ``active_frames`` (CONSTANT interpolation)
    and 0 at every other frame of ``[first, last]`` (held constant outside)."""
    active = set(active_frames)
    points = {first}
    for f in active:
        points.update((f - 1, f, f + 1))
    return [(f, 1.0 if f in active else 0.0) for f in sorted(points) if first <= f <= last]


def bake_object(obj, keys, frames, smooth=False, method='FAST', progress=None, failures=None):
    """Compute a bake WITHOUT touching Blender data.

    Returns a dict with ``keys`` (list of ``(name, (V, 3) coordinates)`` of the
    baked in-betweens, by frame), ``animation`` (``{key name: [(frame, value)]}``
    for every key the bake drives), ``user_keys`` (the keyframed keys) and
    ``frames``.  Raises ``ValueError`` subclasses for unusable input.
    """
    if len(keys) < 2:
        raise InterpolationInputError("Keys: give at least two shape keys (the keyframes of the motion)")
    if len(keys) != len(frames):
        raise InterpolationInputError(f"{len(keys)} keys but {len(frames)} frames: give one frame per key")
    bad = [i for i in range(1, len(frames)) if frames[i] <= frames[i - 1]]
    if bad:
        i = bad[0]
        raise InterpolationInputError(f"Frames must increase strictly: {frames[i - 1]} is followed by {frames[i]}")
    mesh, names, coords, topology = read_mesh(obj)
    _require_keys(names, keys, f"Mesh '{mesh.name}'")
    record = read_bake_record(mesh)
    own_keys = {n for n in record["keys"] if n.startswith(BAKE_PREFIX)}
    used_own = [k for k in keys if k in own_keys]
    if used_own:
        raise InterpolationInputError(f"Keys: '{used_own[0]}' is a key of the previous bake, which a new bake "
                                      "replaces; keyframe your own keys")
    inbetween = [f for f in range(frames[0] + 1, frames[-1]) if f not in set(frames)]
    if len(inbetween) > MAX_NEW_KEYS:
        raise InterpolationInputError(f"Frames {frames[0]}..{frames[-1]} would bake {len(inbetween)} shape keys; "
                                      f"at most {MAX_NEW_KEYS}")
    out_names = [bake_key_name(f) for f in inbetween]
    foreign = [n for n in out_names if n in names and n not in own_keys]
    if foreign:
        raise InterpolationInputError(f"Shape key '{foreign[0]}' exists but was not made by a bake: rename it "
                                      "(a bake names its keys 'LA bake <frame>')")
    cb = _channelbag(mesh.shape_keys)
    if cb is not None:
        own_paths = set(record["fcurves"])
        for k in dict.fromkeys(keys):
            path = _value_path(k)
            if cb.fcurves.find(path) is not None and path not in own_paths:
                raise InterpolationInputError(f"Shape key '{k}' already has animation of its value: the bake "
                                              "keyframes it, so remove that animation first (or duplicate the key)")
    shapes = np.stack([coords[names.index(k)] for k in keys])
    baked = _keyframe_shapes(topology, shapes, frames, inbetween, smooth, method, progress,
                             failures) if inbetween else []
    targets = _piecewise_linear(shapes, frames, inbetween) if inbetween else []
    results = [(n, rigid_align(X, T)) for n, X, T in zip(out_names, baked, targets, strict=True)]
    _check_finite(results, "Bake")
    first, last = frames[0], frames[-1]
    active = {}
    for k, f in zip(keys, frames, strict=True):
        active.setdefault(k, []).append(f)
    for n, f in zip(out_names, inbetween, strict=True):
        active[n] = [f]
    animation = {n: activity_keyframes(fs, first, last) for n, fs in active.items()}
    return {"keys": results, "animation": animation, "user_keys": list(dict.fromkeys(keys)), "frames": list(frames),
            "inbetween_frames": inbetween}


def _piecewise_linear(shapes, keyframes, frames):
    """Piecewise-linear blend of the key coordinates at ``frames`` (the placement targets), list of ``(V, 3)``."""
    V = len(shapes[0])
    flat = np.asarray(shapes, float).reshape(len(shapes), 3 * V)
    return list(piecewise_linear_z(flat, keyframes, frames).reshape(-1, V, 3))


# ----------------------------------------------------------------------------- writing
@contextmanager
def _object_mode(obj):
    """Shape keys written in Edit Mode would be overwritten on leaving it: write in Object Mode."""
    if obj.mode != 'EDIT':
        yield
        return
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.object.mode_set(mode='OBJECT')
    try:
        yield
    finally:
        with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
            bpy.ops.object.mode_set(mode='EDIT')


def write_key(obj, name, coords):
    """Create (relative to the reference key, value 0) or overwrite the shape key ``name``."""
    mesh = obj.data
    if name not in mesh.shape_keys.key_blocks:
        kb = obj.shape_key_add(name=name, from_mix=False)
        kb.value = 0.0
        kb.relative_key = mesh.shape_keys.reference_key
        if kb.name != name:  # pragma: no cover - names are fitted to Blender's limit beforehand
            raise RuntimeError(f"Blender renamed the new key '{name}' to '{kb.name}'")
    mesh.shape_keys.key_blocks[name].points.foreach_set("co", np.asarray(coords, np.float32).ravel())


def remove_bake(obj):
    """Remove the previous bake of ``obj``: its F-curves, its keys; restore keyframed user keys' values.

    Returns the number of removed keys.
    """
    mesh = obj.data
    record = read_bake_record(mesh)
    if BAKE_PROP not in mesh:
        return 0
    key = mesh.shape_keys
    removed = 0
    if key is not None:
        cb = _channelbag(key)
        if cb is not None:
            for path in record["fcurves"]:
                fc = cb.fcurves.find(path)
                if fc is not None:
                    cb.fcurves.remove(fc)
        ad = key.animation_data
        if (record["action"] and ad is not None and ad.action is not None and ad.action.name == record["action"]
                and cb is not None and len(cb.fcurves) == 0):
            action = ad.action
            ad.action = None
            if action.users == 0:
                bpy.data.actions.remove(action)
        for name, value in record["values_before"].items():
            if name in key.key_blocks:
                key.key_blocks[name].value = float(value)
        for name in record["keys"]:
            kb = key.key_blocks.get(name)
            if kb is not None and name.startswith(BAKE_PREFIX):
                obj.shape_key_remove(kb)
                removed += 1
    del mesh[BAKE_PROP]
    return removed


def _ensure_channelbag(key):
    """The channelbag of the Key datablock's action, creating action and slot if needed.

    Returns ``(channelbag, name of the created action or "")``.
    """
    return compat.ensure_animation_channels(key, f"{key.user.name} LA bake" if key.user else "LA bake")


def write_bake(obj, plan, source):
    """Replace the previous bake of ``obj`` by ``plan`` (from :func:`bake_object`)."""
    mesh = obj.data
    old = read_bake_record(mesh)
    values_before = {}
    for name in plan["user_keys"]:  # the value before the FIRST bake that drove the key
        values_before[name] = old["values_before"].get(name, mesh.shape_keys.key_blocks[name].value)
    remove_bake(obj)
    for name, X in plan["keys"]:
        write_key(obj, name, X)
    key = mesh.shape_keys
    cb, created = _ensure_channelbag(key)
    paths = []
    for name, points in plan["animation"].items():
        path = _value_path(name)
        fc = cb.fcurves.new(path)
        fc.keyframe_points.add(len(points))
        fc.keyframe_points.foreach_set("co", np.asarray(points, np.float32).ravel())
        fc.keyframe_points.foreach_set("interpolation", np.zeros(len(points), np.int32))  # 0 = 'CONSTANT'
        fc.update()
        paths.append(path)
    frame = bpy.context.scene.frame_current
    for name in plan["animation"]:
        key.key_blocks[name].value = cb.fcurves.find(_value_path(name)).evaluate(frame)
    mesh[BAKE_PROP] = {
        "keys": [n for n, _ in plan["keys"]],
        "fcurves": paths,
        "values_before": values_before,
        "action": created or old["action"],
        "source": source,
    }
    mesh.update()


# ----------------------------------------------------------------------------- operators
def _error_text(exc):
    """The message of an expected input error (:class:`lacore.errors.InputError`: MeshAccessError, MeshError,
    LengthsAnglesError, InterpolationInputError); type and traceback (console) for anything else (a bug)."""
    if isinstance(exc, InputError):
        return str(exc)
    traceback.print_exc()
    return f"Lengths & Angles failed ({type(exc).__name__}: {exc}); nothing was changed (details in the console)"


def _progress(wm, n):
    """Begin the window manager's progress indicator (no-op in background mode) and return a
    :mod:`lacore.progress` callback ``(done, total, message)`` that updates it."""
    wm.progress_begin(0, max(n, 1))

    def update(done, total, message=""):
        wm.progress_update(min(int(done), n))
    return update


class LENGTHS_ANGLES_OT_interpolate(bpy.types.Operator):
    """Create in-between (or extrapolated) shape keys by interpolating edge lengths and dihedral angles
    of two shape keys and reconstructing: bending and twisting stay rigid where a linear blend shrinks"""

    bl_idname = "lengths_angles.interpolate"
    bl_label = "Interpolate Shape Keys"
    bl_options = {'REGISTER', 'UNDO'}

    key_from: StringProperty(name="From", description="Shape key at factor 0 (default: the reference key)")
    key_to: StringProperty(name="To", description="Shape key at factor 1 (default: the active shape key)")
    factors: StringProperty(
        name="Factors",
        description="Factors of the new keys, separated by spaces or commas (0 = From, 1 = To; values below 0 or "
                    "above 1 extrapolate); empty: Count evenly spaced in-betweens")
    count: IntProperty(name="Count", description="Number of evenly spaced in-betweens when Factors is empty",
                       default=3, min=1, soft_max=50, max=MAX_NEW_KEYS)
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default='FAST')

    @classmethod
    def poll(cls, context):
        return True  # execute() explains what is wrong instead of a greyed-out button

    def draw(self, context):
        layout = self.layout
        obj = context.active_object
        key = obj.data.shape_keys if obj is not None and obj.type == 'MESH' else None
        for prop in ("key_from", "key_to"):
            if key is not None:
                layout.prop_search(self, prop, key, "key_blocks")
            else:
                layout.prop(self, prop)
        layout.prop(self, "factors")
        row = layout.row()
        row.enabled = not self.factors.strip()
        row.prop(self, "count")
        layout.prop(self, "method")

    def _fill_defaults(self, obj):
        if obj is None or obj.type != 'MESH' or obj.data.shape_keys is None:
            return
        key = obj.data.shape_keys
        if not self.key_from and key.reference_key is not None:
            self.key_from = key.reference_key.name
        if not self.key_to and obj.active_shape_key is not None:
            self.key_to = obj.active_shape_key.name

    def execute(self, context):
        obj = context.active_object
        wm = context.window_manager
        self._fill_defaults(obj)
        failures = []
        try:
            if self.factors.strip():
                factors = parse_factors(self.factors)
            else:
                factors = [i / (self.count + 1) for i in range(1, self.count + 1)]
            update = _progress(wm, len(factors))
            try:
                results = interpolate_object(obj, self.key_from, self.key_to, factors, self.method, progress=update,
                                             failures=failures)
                _check_finite(results, "Interpolate")
            finally:
                wm.progress_end()
        except Exception as exc:  # nothing has been written yet: report and leave the object as it was
            self.report({'ERROR'}, _error_text(exc))
            return {'CANCELLED'}
        existing = set(mesh_access.key_names(obj.data))
        with _object_mode(obj):
            for name, X in results:
                write_key(obj, name, X)
            obj.data.update()
        replaced = sum(name in existing for name, _ in results)
        warning = failure_warning(failures)
        if warning:
            self.report({'WARNING'}, warning)
            return {'FINISHED'}
        self.report({'INFO'}, f"{len(results)} in-between key{'s' if len(results) != 1 else ''} "
                              f"'{self.key_from}' > '{self.key_to}'" + (f" ({replaced} replaced)" if replaced else ""))
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_bake_keyframes(bpy.types.Operator):
    """Bake a lengths-and-angles motion through shape keys at given frames: one new shape key per in-between
    frame, and CONSTANT keyframes on the key values so that playback shows exactly one key per frame"""

    bl_idname = "lengths_angles.bake_keyframes"
    bl_label = "Bake Keyframe In-betweens"
    bl_options = {'REGISTER', 'UNDO'}

    keys: StringProperty(name="Keys", description="Shape keys to pass through, separated by commas, "
                                                  "e.g. \"Basis, Bend, Twist\"")
    frames: StringProperty(name="Frames", description="Frame of every key, strictly increasing, e.g. \"1, 12, 24\"")
    smooth: BoolProperty(name="Smooth", description="Cubic spline through the keys' lengths and angles "
                                                    "(otherwise piecewise linear)", default=False)
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default='FAST')

    @classmethod
    def poll(cls, context):
        return True

    def invoke(self, context, event):
        obj = context.active_object
        if not self.keys and obj is not None and obj.type == 'MESH' and obj.data.shape_keys is not None:
            names = [n for n in mesh_access.key_names(obj.data) if not n.startswith(INBETWEEN_PREFIX)]
            if len(names) >= 2:
                scene = context.scene
                start, end = scene.frame_start, scene.frame_end
                step = max((end - start) // (len(names) - 1), 1)
                self.keys = ", ".join(names)
                self.frames = ", ".join(str(start + i * step) for i in range(len(names)))
        return context.window_manager.invoke_props_dialog(self, width=400)

    def execute(self, context):
        obj = context.active_object
        wm = context.window_manager
        failures = []
        try:
            keys = parse_key_list(self.keys)
            frames = parse_frames(self.frames)
            n = max(frames[-1] - frames[0] - len(frames) + 1, 1)
            update = _progress(wm, n)
            try:
                plan = bake_object(obj, keys, frames, smooth=self.smooth, method=self.method, progress=update,
                                   failures=failures)
            finally:
                wm.progress_end()
        except Exception as exc:  # nothing has been written yet
            self.report({'ERROR'}, _error_text(exc))
            return {'CANCELLED'}
        with _object_mode(obj):
            write_bake(obj, plan, {"keys": keys, "frames": frames, "smooth": bool(self.smooth),
                                   "method": self.method})
        warning = failure_warning(failures, what="baked frame")
        if warning:
            self.report({'WARNING'}, warning)
            return {'FINISHED'}
        self.report({'INFO'}, f"Baked {len(plan['keys'])} in-between keys for frames {frames[0]}..{frames[-1]} "
                              f"({'cubic spline' if self.smooth else 'piecewise linear'} in lengths and angles)")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_clear_bake(bpy.types.Operator):
    """Remove the keys and keyframes made by Bake Keyframe In-betweens (your own keys stay)"""

    bl_idname = "lengths_angles.clear_bake"
    bl_label = "Clear Bake"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type == 'MESH' and BAKE_PROP in obj.data

    def execute(self, context):
        obj = context.active_object
        with _object_mode(obj):
            n = remove_bake(obj)
            obj.data.update()
        self.report({'INFO'}, f"Removed the bake ({n} keys)")
        return {'FINISHED'}


classes = (LENGTHS_ANGLES_OT_interpolate, LENGTHS_ANGLES_OT_bake_keyframes, LENGTHS_ANGLES_OT_clear_bake)
