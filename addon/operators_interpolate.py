# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: in-betweens of two shape keys and baked keyframe in-betweens (thesis 4.2).

Both operators follow the pattern of :mod:`.operators`: read the shape keys,
compute every result with :mod:`..lacore.shapes.interpolation` (linear or cubic spline
in lengths and angles, then projection onto admissible lengths and angles by
reconstruction), and only then write to Blender.  Any error is reported as
ERROR and returns CANCELLED with the object unchanged.

Results that fail their checks
------------------------------
A reconstruction whose result fails its checks (``success=False``; with issue 12's
:mod:`lacore.reconstruction.checks`: folded faces, or a minimizer that did not converge) is
still written -- it is the best shape the method found, Blender's undo removes it, and hiding it
would leave the user with nothing to inspect -- and the operator reports a WARNING naming how
many frames failed and the first failure (:func:`failure_warning`) instead of the INFO line.
For 'PREVIEW' (the least-squares relaxation, which minimizes nothing) a non-admissible target
that is merely not reproduced is expected and not reported; folds are.

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
* Baked keys are named ``"LA bake <frame>"`` (e.g. ``"LA bake 012"``).  The bake's F-curves are in
  two F-curve groups (:data:`BAKED_GROUP`: the keys it created, :data:`KEYED_GROUP`: your keys it
  keyframed); Blender rewrites an F-curve's data path when its shape key is renamed, so
  :func:`bake_identity` finds the bake under any names.  The mesh ID property
  ``"lengths_angles_bake"`` records the values your keys had before, so a new bake or Clear Bake
  removes exactly the previous bake and nothing else.

Runs
----
Validation builds a :class:`JobRunner` (nothing written); its :meth:`JobRunner.tick` computes one
frame (:class:`.jobs.ProjectionJob`), :meth:`JobRunner.finish` writes.  The operators run it
modally from the UI (timer, progress bar, Esc) and synchronously from scripts, in background
mode and from the redo panel; :mod:`.session` caches what depends only on the mesh and its keys.
"""

import math
import re
import traceback
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..lacore.errors import InputError
from ..lacore.parallel import close_workers
from ..lacore.reconstruction.settings import FAST
from . import compat, jobs, mesh_access, session

__all__ = ["LENGTHS_ANGLES_OT_interpolate", "LENGTHS_ANGLES_OT_bake_keyframes", "classes", "parse_factors",
           "parse_key_list", "parse_frames", "inbetween_key_name", "bake_key_name", "interpolate_object",
           "bake_object", "inbetween_shapes", "read_mesh", "write_key", "BAKE_PROP", "BAKE_PREFIX", "INBETWEEN_PREFIX",
           "JobRunner", "interpolate_runner", "bake_runner", "bake_frames", "bake_summary", "key_items",
           "BAKED_GROUP", "KEYED_GROUP", "bake_identity", "remove_bake", "object_mode", "failure_warning"]

INBETWEEN_PREFIX = "LA "
BAKE_PREFIX = "LA bake "
BAKE_PROP = "lengths_angles_bake"
# F-curve groups of a bake: the identity of its curves and keys (Blender fixes the data paths of
# F-curves when a shape key is renamed, so the group finds them under any name).
BAKED_GROUP = "Lengths & Angles bake: new keys"
KEYED_GROUP = "Lengths & Angles bake: your keys"
NO_KEY = "__NONE__"
MAX_NEW_KEYS = 1000
_NAME_BYTES = 63  # Blender's shape-key names hold 63 bytes

METHOD_ITEMS = [
    ('PREVIEW', "Preview", "Least-squares relaxation of the frame-based reconstruction only (one linear solve "
                           "over the whole mesh): quickest, edge lengths within ~1.5 % on strong blends"),
    ('FAST', "Fast", "Each in-between starts from the extrapolation of the ones before it and takes one "
                     "Gauss-Newton step: the exact projection on smooth motions at one solve per in-between "
                     "(strongly mixed blends, such as a bend into a twist, need Gauss-Newton)"),
    ('GAUSS_NEWTON', "Gauss-Newton", "Energy-based projection: Gauss-Newton run to convergence (slowest, "
                                     "most accurate)"),
]
# Not offered in the UI: 'MULTIRES' (lacore.multiresolution: coarse solve, prolongation, three fine Gauss-Newton
# steps; the hierarchy is built once per keys in the session cache; the runner takes it).  Measured at 50k
# (benchmarks/bench_multires.py, README "Multiresolution", 2026-11-25): on the bar 10x full Gauss-Newton's energy
# in ~5 s per in-between where the previous Fast reached 3.4x in 3.3 s; on a character-like body both reach
# Gauss-Newton's energy, multires in 1.4-1.6 s and that Fast in 1.7 s, after an 8-10 s set-up.  Add the item once
# it pays:
# ('MULTIRES', "Multiresolution", "Solve on a coarsened mesh, carry the result to the full mesh and finish with a "
#                                 "few Gauss-Newton steps (the coarse hierarchy is built once per keys)"),
PLAYBACK_ITEMS = [
    ('STEPPED', "Stepped", "CONSTANT keyframes: exactly one baked key at full value on every frame, held "
                           "between frames"),
    ('SMOOTH', "Smooth", "LINEAR keyframes: between two frames the neighbouring baked keys cross-fade (sub-frame "
                         "motion blur, retimed playback); identical to Stepped on whole frames"),
]
_INTERPOLATION = {'STEPPED': 0, 'SMOOTH': 1}  # keyframe interpolation enum values: CONSTANT, LINEAR
_LACORE_METHOD = {'PREVIEW': "lsq", 'FAST': FAST.method, 'GAUSS_NEWTON': "gn", 'MULTIRES': jobs.MULTIRES}
# FAST: continuation along t (lacore.shapes.interpolation.predicted_start: the secant through the two nearest
# computed in-betweens or keys, kept when its energy is lower than the nearest one's) and one Gauss-Newton
# step; a frame starting from a known shape itself (the first after a key) gets up to three, stopping once
# the predicted decrease is below ftol = 1e-4 of the energy.  Measured (benchmarks/bench_continuation.py,
# README "In-betweens of large meshes"): one factorization per in-between, within 1e-6 of Gauss-Newton's
# energy on a 53k-vertex body, where the previous FAST (least-squares start + two steps reusing
# factorizations across frames) left 35-40 % on every other frame; on a bend -> twist bar blend it drifts
# from Gauss-Newton's minima mid-blend (use Gauss-Newton there).
_METHOD_OPTIONS = {'PREVIEW': {},
                   'FAST': {"hybrid": FAST.hybrid, "options": FAST.options},  # lacore's preset (the CLI's default)
                   'GAUSS_NEWTON': {},
                   'MULTIRES': {"fine_iterations": 3, "fine_solver": "exact"}}


PROCESSES_DESCRIPTION = (
    f"Frames computed side by side in this many processes, each starting next to a key (each process builds "
    f"its own solver, about 2-4 s and one more solver's memory at 50,000 vertices). 0 = Auto: one per CPU core "
    f"(at most 4) for meshes of {jobs.AUTO_WORKERS_MIN_VERTICES:,} vertices or more with at least "
    f"{jobs.AUTO_WORKERS_MIN_FRAMES} frames to compute, else 1")


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
def read_mesh(obj):
    """Validated ``(mesh, names, coords (K, V, 3), topology)`` of a mesh object with shape keys (session cache)."""
    data = session.read_mesh(obj, "interpolated")
    return data.mesh, data.names, data.coords, data.topology


def _require_keys(names, wanted, what):
    missing = [w for w in wanted if w not in names]
    if missing:
        shown = ", ".join(f"'{m}'" for m in missing)
        have = ", ".join(f"'{n}'" for n in names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
        raise InterpolationInputError(f"{what}: no shape key {shown} (the mesh has {have})")


def _job(data, keys, keyframes, times, smooth, method, workers=1):
    return jobs.ProjectionJob(data, keys, keyframes, times, smooth, _LACORE_METHOD[method], _METHOD_OPTIONS[method],
                              method, workers=workers)


def _inbetween_plan(obj, key_from, key_to, factors, method, workers=1):
    """Validate and set up in-betweens: ``(data, names of the new keys, ProjectionJob)``; nothing written."""
    data = session.read_mesh(obj, "interpolated")
    if not key_from or not key_to or NO_KEY in (key_from, key_to):
        raise InterpolationInputError("Choose the two shape keys to interpolate between (From and To)")
    if key_from == key_to:
        raise InterpolationInputError(f"From and To are the same shape key '{key_from}': choose two different keys")
    _require_keys(data.names, [key_from, key_to], f"Mesh '{data.mesh.name}'")
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
    if len(unique) > MAX_NEW_KEYS:
        raise InterpolationInputError(f"{len(unique)} in-betweens requested; at most {MAX_NEW_KEYS}")
    job = _job(data, [key_from, key_to], [0.0, 1.0], [seen[n] for n in unique], False, method, workers)
    return data, unique, job


def interpolate_object(obj, key_from, key_to, factors, method='FAST', progress=None, failures=None):
    """Compute in-betweens of two shape keys WITHOUT touching Blender data.

    Returns a list of ``(key name, (V, 3) float64 coordinates)``, one per factor,
    placed as described in the module docstring.  Raises
    :class:`lacore.errors.InputError` subclasses for unusable input.
    """
    _data, names, job = _inbetween_plan(obj, key_from, key_to, factors, method)
    results = list(zip(names, job.run(progress), strict=True))
    if failures is not None:
        failures.extend(job.failures)
    return results


def inbetween_shapes(topology, A, B, factors, method='FAST', progress=None, failures=None):
    """The placed in-betweens ``[(V, 3)]`` of the shapes ``A`` (t = 0) and ``B`` (t = 1) at ``factors``.

    ``failures`` (a list, optional) collects the frames failing their checks (:meth:`.jobs.ProjectionJob._failure`).
    """
    A, B = np.asarray(A, float), np.asarray(B, float)
    data = session.MeshData(mesh=None, names=["A", "B"], coords=np.stack([A, B]), topology=topology,
                            topology_hash=session.topology_hash(topology.faces, topology.edges, topology.n_vertices),
                            key_hashes=[session.coords_hash(A), session.coords_hash(B)])
    job = _job(data, ["A", "B"], [0.0, 1.0], factors, False, method)
    results = job.run(progress)
    if failures is not None:
        failures.extend(job.failures)
    return results


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
        return {"keys": [], "fcurves": [], "values_before": {}, "user_keys": [], "action": "", "source": {}}
    rec = rec.to_dict()
    return {"keys": list(rec.get("keys", [])), "fcurves": list(rec.get("fcurves", [])),
            "values_before": dict(rec.get("values_before", {})), "user_keys": list(rec.get("user_keys", [])),
            "action": str(rec.get("action", "")), "source": dict(rec.get("source", {}))}


def _curve_key_name(key, fc):
    """The name of the shape key whose value ``fc`` animates (None if it animates something else)."""
    path = fc.data_path
    if not path.startswith("key_blocks[") or not path.endswith(".value"):
        return None
    try:
        kb = key.path_resolve(path[: -len(".value")])
    except ValueError:
        return None
    return kb.name if isinstance(kb, bpy.types.ShapeKey) else None


def bake_identity(obj):
    """The bake on ``obj`` found by identity, under the keys' CURRENT names (renames are followed).

    Returns ``{"baked": [(fcurve or None, key name)], "keyed": [(fcurve, key name)]}``: the curves of
    the bake's F-curve groups (:data:`BAKED_GROUP`: the keys the bake created, :data:`KEYED_GROUP`:
    your keys it keyframed; Blender updates an F-curve's data path when its key is renamed), plus
    keys listed in the bake record that lost their curve.
    """
    out = {"baked": [], "keyed": []}
    key = obj.data.shape_keys
    if key is None:
        return out
    cb = _channelbag(key)
    if cb is not None:
        for fc in cb.fcurves:
            group = fc.group.name if fc.group is not None else None
            role = "baked" if group == BAKED_GROUP else "keyed" if group == KEYED_GROUP else None
            if role is not None:
                out[role].append((fc, _curve_key_name(key, fc)))
    named = {n for _, n in out["baked"]}
    for n in read_bake_record(obj.data)["keys"]:
        if n not in named and n in key.key_blocks:
            out["baked"].append((None, n))
    return out


def activity_keyframes(active_frames, first, last):
    """Keyframes ``[(frame, value)]`` of a key that is 1 exactly at ``active_frames`` (CONSTANT interpolation)
    and 0 at every other frame of ``[first, last]`` (held constant outside).  With LINEAR interpolation the
    same points cross-fade neighbouring frames (the values of all keys sum to 1 at every time)."""
    active = set(active_frames)
    points = {first}
    for f in active:
        points.update((f - 1, f, f + 1))
    return [(f, 1.0 if f in active else 0.0) for f in sorted(points) if first <= f <= last]


def bake_frames(keys, frames):
    """The frames a bake of ``keys`` at ``frames`` creates a key for (validated), list of int."""
    if len(keys) < 2:
        raise InterpolationInputError("Keys: give at least two shape keys (the keyframes of the motion)")
    if len(keys) != len(frames):
        raise InterpolationInputError(f"{len(keys)} keys but {len(frames)} frames: give one frame per key")
    bad = [i for i in range(1, len(frames)) if frames[i] <= frames[i - 1]]
    if bad:
        i = bad[0]
        raise InterpolationInputError(f"Frames must increase strictly: {frames[i - 1]} is followed by {frames[i]}")
    inbetween = [f for f in range(frames[0] + 1, frames[-1]) if f not in set(frames)]
    if len(inbetween) > MAX_NEW_KEYS:
        raise InterpolationInputError(f"Frames {frames[0]}..{frames[-1]} would bake {len(inbetween)} shape keys; "
                                      f"at most {MAX_NEW_KEYS}")
    return inbetween


def bake_summary(obj, keys, frames):
    """One line for the Bake dialog: how many keys the bake creates (and replaces), or what is wrong."""
    try:
        inbetween = bake_frames(keys, frames)
    except InputError as exc:
        return str(exc)
    old = len(bake_identity(obj)["baked"]) if obj is not None and obj.type == 'MESH' else 0
    text = (f"Creates {len(inbetween)} shape key{'s' if len(inbetween) != 1 else ''} "
            f"(frames {frames[0]}-{frames[-1]}) and keyframes {len(set(keys))} of yours")
    return text + (f"; replaces the previous bake ({old} keys)" if old else "")


def _bake_plan(obj, keys, frames, smooth, method, workers=1):
    """Validate a bake and set it up: ``(data, plan without shapes, ProjectionJob or None)``; nothing written."""
    inbetween = bake_frames(keys, frames)
    data = session.read_mesh(obj, "interpolated")
    mesh, names = data.mesh, data.names
    _require_keys(names, keys, f"Mesh '{mesh.name}'")
    ident = bake_identity(obj)
    own_keys = {n for _, n in ident["baked"] if n is not None}
    used_own = [k for k in keys if k in own_keys]
    if used_own:
        raise InterpolationInputError(f"Keys: '{used_own[0]}' is a key of the previous bake, which a new bake "
                                      "replaces; keyframe your own keys")
    out_names = [bake_key_name(f) for f in inbetween]
    foreign = [n for n in out_names if n in names and n not in own_keys]
    if foreign:
        raise InterpolationInputError(f"Shape key '{foreign[0]}' exists but was not made by a bake: rename it "
                                      "(a bake names its keys 'LA bake <frame>')")
    cb = _channelbag(mesh.shape_keys)
    if cb is not None:
        own_paths = {fc.data_path for role in ("baked", "keyed") for fc, _ in ident[role] if fc is not None}
        for k in dict.fromkeys(keys):
            path = _value_path(k)
            if cb.fcurves.find(path) is not None and path not in own_paths:
                raise InterpolationInputError(f"Shape key '{k}' already has animation of its value: the bake "
                                              "keyframes it, so remove that animation first (or duplicate the key)")
    first, last = frames[0], frames[-1]
    active = {}
    for k, f in zip(keys, frames, strict=True):
        active.setdefault(k, []).append(f)
    for n, f in zip(out_names, inbetween, strict=True):
        active[n] = [f]
    plan = {"names": out_names, "animation": {n: activity_keyframes(fs, first, last) for n, fs in active.items()},
            "user_keys": list(dict.fromkeys(keys)), "frames": list(frames), "inbetween_frames": inbetween}
    job = _job(data, keys, frames, inbetween, smooth, method, workers) if inbetween else None
    return data, plan, job


def _complete_plan(plan, results):
    plan = dict(plan, keys=list(zip(plan["names"], results, strict=True)))
    _check_finite(plan["keys"], "Bake")
    return plan


def bake_object(obj, keys, frames, smooth=False, method='FAST', progress=None, failures=None):
    """Compute a bake WITHOUT touching Blender data.

    Returns a dict with ``keys`` (list of ``(name, (V, 3) coordinates)`` of the
    baked in-betweens, by frame), ``animation`` (``{key name: [(frame, value)]}``
    for every key the bake drives), ``user_keys`` (the keyframed keys) and
    ``frames``.  Raises :class:`lacore.errors.InputError` subclasses for unusable input.
    """
    _data, plan, job = _bake_plan(obj, keys, frames, smooth, method)
    plan = _complete_plan(plan, job.run(progress) if job is not None else [])
    if failures is not None and job is not None:
        failures.extend(job.failures)
    return plan


# ----------------------------------------------------------------------------- writing
@contextmanager
def object_mode(obj):
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
    """Remove the bake of ``obj`` by identity (:func:`bake_identity`): its F-curves and keys, under any
    names; restore the values your keyframed keys had before.  Returns the number of removed keys."""
    mesh = obj.data
    record = read_bake_record(mesh)
    ident = bake_identity(obj)
    key = mesh.shape_keys
    if BAKE_PROP not in mesh and not ident["baked"] and not ident["keyed"]:
        return 0
    removed = 0
    if key is not None:
        baked_names = [n for _, n in ident["baked"] if n is not None]
        keyed = [n for _, n in ident["keyed"]]
        by_order = len(keyed) == len(record["user_keys"])  # renamed keys: the curves keep their creation order
        values = []
        for i, n in enumerate(keyed):
            original = n if n in record["values_before"] else (record["user_keys"][i] if by_order else None)
            values.append((n, record["values_before"].get(original)))
        cb = _channelbag(key)
        if cb is not None:
            for fc in [fc for role in ("baked", "keyed") for fc, _ in ident[role] if fc is not None]:
                cb.fcurves.remove(fc)
            for name in (BAKED_GROUP, KEYED_GROUP):
                group = cb.groups.get(name)
                if group is not None:
                    cb.groups.remove(group)
        ad = key.animation_data
        if (record["action"] and ad is not None and ad.action is not None and ad.action.name == record["action"]
                and cb is not None and len(cb.fcurves) == 0):
            action = ad.action
            ad.action = None
            if action.users == 0:
                bpy.data.actions.remove(action)
        for name, value in values:
            if name is not None and value is not None and name in key.key_blocks:
                key.key_blocks[name].value = float(value)
        for name in baked_names:
            kb = key.key_blocks.get(name)
            if kb is not None:
                obj.shape_key_remove(kb)
                removed += 1
    if BAKE_PROP in mesh:
        del mesh[BAKE_PROP]
    return removed


def _ensure_channelbag(key):
    """The channelbag of the Key datablock's action, creating action and slot if needed.

    Returns ``(channelbag, name of the created action or "")``.
    """
    return compat.ensure_animation_channels(key, f"{key.user.name} LA bake" if key.user else "LA bake")


def write_bake(obj, plan, source, playback='STEPPED'):
    """Replace the previous bake of ``obj`` by ``plan`` (from :func:`bake_object`).

    ``playback``: 'STEPPED' (CONSTANT keyframes) or 'SMOOTH' (LINEAR: neighbouring frames cross-fade).
    """
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
    groups = {True: compat.fcurve_group(cb, BAKED_GROUP), False: compat.fcurve_group(cb, KEYED_GROUP)}
    baked = {n for n, _ in plan["keys"]}
    paths = []
    for name, points in plan["animation"].items():
        path = _value_path(name)
        fc = cb.fcurves.new(path)
        fc.group = groups[name in baked]
        fc.keyframe_points.add(len(points))
        fc.keyframe_points.foreach_set("co", np.asarray(points, np.float32).ravel())
        fc.keyframe_points.foreach_set("interpolation", np.full(len(points), _INTERPOLATION[playback], np.int32))
        fc.update()
        paths.append(path)
    frame = bpy.context.scene.frame_current
    for name in plan["animation"]:
        key.key_blocks[name].value = cb.fcurves.find(_value_path(name)).evaluate(frame)
    mesh[BAKE_PROP] = {
        "keys": [n for n, _ in plan["keys"]],
        "fcurves": paths,
        "values_before": values_before,
        "user_keys": list(plan["user_keys"]),
        "action": created or old["action"],
        "source": source,
    }
    mesh.update()


# ----------------------------------------------------------------------------- runs (plain Python, testable)
def _counts(mesh):
    return {"vertices": len(mesh.vertices), "edges": len(mesh.edges), "faces": len(mesh.polygons)}


class JobRunner:
    """One run of a long operator as plain Python (no event loop): the modal operator's step function.

    Created after all validation (nothing written yet); :meth:`tick` computes one frame
    (one unit of work), :meth:`finish` checks that the object is still the one read (same
    datablock, connectivity and input keys) and writes the results, :meth:`cancel` drops
    everything (nothing was written, so the object stays exactly as it was).
    """

    def __init__(self, obj, data, job, keys, write, what="in-between"):
        self.what = what
        self.obj_name, self.obj_pointer = obj.name, obj.as_pointer()
        self.counts = _counts(data.mesh)
        self.topology_hash = data.topology_hash
        self.key_hashes = {k: data.key_hashes[data.index(k)] for k in keys}
        self.job = job
        self._write = write
        self.cancelled = False

    @property
    def total(self):
        return 0 if self.job is None else self.job.total

    @property
    def done(self):
        return 0 if self.job is None else self.job.done

    @property
    def finished(self):
        return self.job is None or self.job.finished

    @property
    def failures(self):
        """Frames that failed their reconstruction checks (written anyway, with a WARNING)."""
        return [] if self.job is None else self.job.failures

    @property
    def notes(self):
        """Other things the report should say (a worker process failed and this process took over ...)."""
        return [] if self.job is None else self.job.notes

    def tick(self):
        """Compute one frame; True when all are done."""
        if self.cancelled:
            raise RuntimeError("the run was cancelled")
        if self.job is not None:
            self.job.step()
        return self.finished

    def run(self, progress=None):
        if self.job is not None:
            self.job.run(progress)

    def cancel(self):
        self.cancelled = True
        if self.job is not None:
            self.job.close()  # worker processes, if any
        self.job = None

    def status(self):
        return f"Lengths & Angles: frame {self.done + 1} of {self.total} (Esc to cancel)"

    def _current_object(self):
        obj = bpy.data.objects.get(self.obj_name)
        if obj is None or obj.as_pointer() != self.obj_pointer:
            raise InterpolationInputError(f"Object '{self.obj_name}' was deleted or renamed while computing; "
                                          "nothing was written")
        return obj

    def finish(self):
        """Write the results (after checking the inputs did not change); returns the report text."""
        if self.cancelled or not self.finished:
            raise RuntimeError("finish() before the last frame")
        obj = self._current_object()
        now = _counts(obj.data)
        changed = [f"{k} {self.counts[k]} -> {now[k]}" for k in now if now[k] != self.counts[k]]
        if changed:
            raise InterpolationInputError(f"The mesh of '{obj.name}' changed while computing ({', '.join(changed)}); "
                                          "nothing was written: run again")
        data = session.read_mesh(obj, "interpolated")
        if data.topology_hash != self.topology_hash:
            raise InterpolationInputError(f"The faces of '{obj.name}' changed while computing; nothing was written: "
                                          "run again")
        edited = [k for k, h in self.key_hashes.items() if k not in data.names or data.key_hashes[data.index(k)] != h]
        if edited:
            raise InterpolationInputError(f"Shape key '{edited[0]}' was edited, renamed or deleted while computing; "
                                          "nothing was written: run again")
        results = [] if self.job is None else self.job.results
        return self._write(obj, results)


def interpolate_runner(obj, key_from, key_to, factors, method='FAST', workers=1):
    """A :class:`JobRunner` for in-betweens (validated; raises InputError subclasses); ``workers``: processes
    (:func:`.jobs.job_workers`, 0 = Auto)."""
    data, names, job = _inbetween_plan(obj, key_from, key_to, factors, method, workers)

    def write(obj, shapes):
        results = list(zip(names, shapes, strict=True))
        _check_finite(results, "Interpolate")
        existing = set(mesh_access.key_names(obj.data))
        with object_mode(obj):
            for name, X in results:
                write_key(obj, name, X)
            obj.data.update()
        replaced = sum(name in existing for name, _ in results)
        return (f"{len(results)} in-between key{'s' if len(results) != 1 else ''} '{key_from}' > '{key_to}'"
                + (f" ({replaced} replaced)" if replaced else ""))
    return JobRunner(obj, data, job, [key_from, key_to], write)


def bake_runner(obj, keys, frames, smooth=False, method='FAST', playback='STEPPED', workers=1):
    """A :class:`JobRunner` for a bake (validated; raises InputError subclasses); ``workers`` as in
    :func:`interpolate_runner`."""
    data, plan, job = _bake_plan(obj, keys, frames, smooth, method, workers)

    def write(obj, shapes):
        full = _complete_plan(plan, shapes)
        with object_mode(obj):
            write_bake(obj, full, {"keys": list(keys), "frames": list(frames), "smooth": bool(smooth),
                                   "method": method, "playback": playback}, playback)
        return (f"Baked {len(full['keys'])} in-between keys for frames {frames[0]}..{frames[-1]} "
                f"({'cubic spline' if smooth else 'piecewise linear'} in lengths and angles, "
                f"{playback.lower()} playback)")
    return JobRunner(obj, data, job, keys, write, what="baked frame")


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


_WORKER = []


def _worker():
    """The one worker thread of the modal runs (created on first use): a frame is computed there while
    Blender keeps redrawing and handling events; it runs lacore only, never bpy."""
    if not _WORKER:
        _WORKER.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="lengths_angles"))
    return _WORKER[0]


def shutdown_worker():
    """Stop the worker thread and kill lacore's worker processes (add-on unregister); a frame being computed is
    dropped."""
    while _WORKER:
        _WORKER.pop().shutdown(wait=False, cancel_futures=True)
    close_workers()


_ITEMS = {}  # Blender needs Python to keep the strings of dynamic enum items alive


def _remember(kind, items):
    key = (kind, tuple(i[0] for i in items))
    if key not in _ITEMS:
        if len(_ITEMS) > 256:
            _ITEMS.clear()
        _ITEMS[key] = items
    return _ITEMS[key]


def _context_key_names(context):
    obj = getattr(context, "object", None)
    if obj is None or obj.type != 'MESH':
        return []
    return mesh_access.key_names(obj.data)


def key_items(self, context):
    """Dynamic enum items: the shape keys of ``context.object`` (value = position in the key list)."""
    names = _context_key_names(context) if context is not None else []
    items = [(n, n, f"Shape key '{n}' (position {i} in the key list)", 'SHAPEKEY_DATA', i)
             for i, n in enumerate(names)]
    return _remember("key", items or [(NO_KEY, "(no shape keys)", "The object has no shape keys", 'ERROR', 0)])


def key_flag_items(self, context):
    """Dynamic ENUM_FLAG items: the first 32 shape keys of ``context.object`` (bit i = key i)."""
    names = _context_key_names(context)[:32] if context is not None else []
    return _remember("flag", [(n, n, f"Pass through shape key '{n}'", 'NONE', 1 << i) for i, n in enumerate(names)])


def _default_pair(obj):
    """(reference key, active key or the first other key that is not an in-between), or None."""
    key = obj.data.shape_keys if obj is not None and obj.type == 'MESH' else None
    if key is None or key.reference_key is None or len(key.key_blocks) < 2:
        return None
    ref = key.reference_key.name
    active = obj.active_shape_key.name if obj.active_shape_key is not None else ref
    if active == ref or active.startswith(INBETWEEN_PREFIX):
        active = next((kb.name for kb in key.key_blocks if kb.name != ref and not kb.name.startswith(INBETWEEN_PREFIX)),
                      None)
    return None if active is None else (ref, active)


def _warn_transform(op, obj):
    """Lengths and angles are measured in the mesh's own coordinates; warn if the object scales non-uniformly."""
    if obj is None or obj.type != 'MESH':
        return
    s = [abs(v) for v in obj.matrix_world.to_scale()]
    if max(s) > 0 and (max(s) - min(s)) > 1e-4 * max(s):
        op.report({'WARNING'}, f"Object '{obj.name}' has a non-uniform scale ({s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g}): "
                               "lengths and angles are measured in the mesh's own coordinates, ignoring the object's "
                               "transform (Apply Scale, Ctrl+A, to use the displayed shape)")


class _ModalRun:
    """Shared run logic: interactive (modal, timer-driven, progress bar, Esc) or synchronous."""

    interactive: BoolProperty(name="Interactive", default=False, options={'HIDDEN', 'SKIP_SAVE'},
                              description="Compute frame by frame in a worker thread with a progress bar and Esc "
                                          "to cancel (set by the user interface; scripts, background mode and "
                                          "the redo panel run at once)")

    def _run(self, context, make_runner):
        obj = context.object
        try:
            runner = make_runner(obj)
        except Exception as exc:  # nothing has been written: report and leave the object as it was
            self.report({'ERROR'}, _error_text(exc))
            return {'CANCELLED'}
        _warn_transform(self, obj)
        if self.interactive and not bpy.app.background and context.window is not None and not runner.finished:
            return self._start_modal(context, runner)
        wm = context.window_manager
        update = _progress(wm, runner.total)
        try:
            runner.run(update)
        except Exception as exc:
            self.report({'ERROR'}, _error_text(exc))
            return {'CANCELLED'}
        finally:
            wm.progress_end()
        return self._finish(runner)

    def _finish(self, runner):
        try:
            message = runner.finish()
        except Exception as exc:
            self.report({'ERROR'}, _error_text(exc))
            return {'CANCELLED'}
        warning = " ".join([w for w in [failure_warning(runner.failures, runner.what), *runner.notes] if w])
        self.report({'WARNING'} if warning else {'INFO'}, warning or message)
        return {'FINISHED'}

    def _start_modal(self, context, runner):
        self._begin_modal(context, runner)
        context.window_manager.modal_handler_add(self)
        return {'RUNNING_MODAL'}

    def _begin_modal(self, context, runner):
        """Progress bar, status text and the timer whose events drive :meth:`modal`; with more than one
        process, every frame is computed in a worker process (Blender's Python stays free for the UI)."""
        if runner.job is not None:
            runner.job.all_in_workers = True
        wm = context.window_manager
        self._runner = runner
        self._future = None
        wm.progress_begin(0, max(runner.total, 1))
        self._timer = wm.event_timer_add(0.05, window=context.window)
        self._status(context, runner.status())

    @staticmethod
    def _status(context, text):
        if context.workspace is not None and context.window is not None:
            context.workspace.status_text_set(text)

    def _end_modal(self, context):
        wm = context.window_manager
        if getattr(self, "_timer", None) is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        self._status(context, None)

    def modal(self, context, event):
        """One unit of work at a time: ``runner.tick()`` (one frame) runs in the worker thread (it never touches
        bpy), timer events poll it, update the progress and start the next; Esc / right-click cancels."""
        runner = self._runner
        if event.type in {'ESC', 'RIGHTMOUSE'} and event.value == 'PRESS':
            runner.cancel()  # a frame being computed finishes in the worker and is dropped
            self._future = None
            self._end_modal(context)
            self.report({'WARNING'}, "Cancelled: nothing was changed")
            return {'CANCELLED'}
        if event.type != 'TIMER' or event.timer is not self._timer:
            return {'PASS_THROUGH'}
        if self._future is None:
            self._future = _worker().submit(runner.tick)
            return {'RUNNING_MODAL'}
        if not self._future.done():
            return {'RUNNING_MODAL'}
        future, self._future = self._future, None
        try:
            finished = future.result()
        except Exception as exc:
            runner.cancel()
            self._end_modal(context)
            self.report({'ERROR'}, _error_text(exc))
            return {'CANCELLED'}
        context.window_manager.progress_update(runner.done)
        if not finished:
            self._status(context, runner.status())
            self._future = _worker().submit(runner.tick)
            return {'RUNNING_MODAL'}
        self._end_modal(context)
        self.interactive = False  # a redo-panel change re-runs synchronously (from the session cache)
        return self._finish(runner)

    def cancel(self, context):  # Blender ends the modal operator (e.g. the window closes)
        if getattr(self, "_runner", None) is not None:
            self._runner.cancel()
        self._end_modal(context)


class LENGTHS_ANGLES_OT_interpolate(_ModalRun, bpy.types.Operator):
    """Create in-between (or extrapolated) shape keys by interpolating edge lengths and dihedral angles
    of two shape keys and reconstructing: bending and twisting stay rigid where a linear blend shrinks"""

    bl_idname = "lengths_angles.interpolate"
    bl_label = "Lengths & Angles In-betweens"
    bl_description = ("Create in-between shape keys of two keys by interpolating edge lengths and dihedral angles: "
                      "bends and twists stay rigid where a linear blend shrinks")
    bl_options = {'REGISTER', 'UNDO'}

    key_from: EnumProperty(name="From", items=key_items, options={'SKIP_SAVE'},
                           description="Shape key at factor 0 (default: the reference key)")
    key_to: EnumProperty(name="To", items=key_items, options={'SKIP_SAVE'},
                         description="Shape key at factor 1 (default: the active shape key)")
    factors: StringProperty(
        name="Factors",
        description="Factors of the new keys, separated by spaces or commas (0 = From, 1 = To; values below 0 or "
                    "above 1 extrapolate); empty: Count evenly spaced in-betweens")
    count: IntProperty(name="Count", description="Number of evenly spaced in-betweens when Factors is empty",
                       default=3, min=1, soft_max=50, max=MAX_NEW_KEYS)
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default='FAST',
                         description="How the interpolated lengths and angles are turned into a shape")
    processes: IntProperty(name="Processes", default=0, min=0, max=8, description=PROCESSES_DESCRIPTION)

    @classmethod
    def poll(cls, context):
        return True  # execute() explains what is wrong instead of a greyed-out button

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "key_from")
        layout.prop(self, "key_to")
        layout.prop(self, "factors")
        row = layout.row()
        row.enabled = not self.factors.strip()
        row.prop(self, "count")
        layout.prop(self, "method")
        layout.prop(self, "processes")

    def _fill_defaults(self, obj):
        pair = _default_pair(obj)
        if pair is None:
            return
        if not self.properties.is_property_set("key_from"):
            self.key_from = pair[0]
        if not self.properties.is_property_set("key_to"):
            self.key_to = pair[1]

    def _factors(self):
        if self.factors.strip():
            return parse_factors(self.factors)
        return [i / (self.count + 1) for i in range(1, self.count + 1)]

    def invoke(self, context, event):
        self._fill_defaults(context.object)
        self.interactive = True
        return context.window_manager.invoke_props_dialog(self, width=360)

    def execute(self, context):
        self._fill_defaults(context.object)
        return self._run(context, lambda obj: interpolate_runner(obj, self.key_from, self.key_to, self._factors(),
                                                                 self.method, workers=self.processes))


class LENGTHS_ANGLES_OT_bake_keyframes(_ModalRun, bpy.types.Operator):
    """Bake a lengths-and-angles motion through shape keys at given frames: one new shape key per in-between
    frame, keyframed so that playback shows exactly one key per frame"""

    bl_idname = "lengths_angles.bake_keyframes"
    bl_label = "Bake Lengths & Angles In-betweens"
    bl_description = ("Bake a motion through shape keys: one new shape key per in-between frame, keyframed so that "
                      "playback shows one key per frame")
    bl_options = {'REGISTER', 'UNDO'}

    key_set: EnumProperty(name="Keys", items=key_flag_items, options={'ENUM_FLAG', 'SKIP_SAVE'},
                          description="Shape keys the motion passes through, in key-list order (default: the "
                                      "reference key and the active key)")
    frame_start: IntProperty(name="Start Frame", default=1, options={'SKIP_SAVE'},
                             description="Frame of the first key (default: the current frame)")
    frame_step: IntProperty(name="Frames Between Keys", default=10, min=1, soft_max=100,
                            description="Frames from one key to the next")
    keys: StringProperty(name="Keys (typed)", options={'SKIP_SAVE'},
                         description="For scripts: shape keys separated by commas, e.g. \"Basis, Bend, Twist\"; "
                                     "overrides Keys, Start Frame and Frames Between Keys")
    frames: StringProperty(name="Frames (typed)", options={'SKIP_SAVE'},
                           description="For scripts: the frame of every typed key, strictly increasing, "
                                       "e.g. \"1, 12, 24\"")
    smooth: BoolProperty(name="Spline", default=False,
                         description="Cubic spline through the keys' lengths and angles (otherwise piecewise linear)")
    playback: EnumProperty(name="Playback", items=PLAYBACK_ITEMS, default='STEPPED',
                           description="Interpolation of the keyframes on the key values")
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default='FAST',
                         description="How the interpolated lengths and angles are turned into a shape")
    processes: IntProperty(name="Processes", default=0, min=0, max=8, description=PROCESSES_DESCRIPTION)

    @classmethod
    def poll(cls, context):
        return True

    def bake_inputs(self, obj):
        """``(keys, frames)`` of this bake: the typed lists, else the picked keys from Start Frame on."""
        if self.keys.strip() or self.frames.strip():
            return parse_key_list(self.keys), parse_frames(self.frames)
        names = [n for n in (mesh_access.key_names(obj.data) if obj is not None and obj.type == 'MESH' else [])
                 if n in self.key_set]
        return names, [self.frame_start + i * self.frame_step for i in range(len(names))]

    def summary(self, obj):
        try:
            keys, frames = self.bake_inputs(obj)
        except InputError as exc:
            return str(exc)
        return bake_summary(obj, keys, frames)

    def draw(self, context):
        layout = self.layout
        obj = context.object
        if self.keys.strip() or self.frames.strip():
            layout.prop(self, "keys")
            layout.prop(self, "frames")
        else:
            layout.label(text="Keys")
            layout.column(align=True).prop(self, "key_set")
            layout.prop(self, "frame_start")
            layout.prop(self, "frame_step")
        layout.prop(self, "smooth")
        layout.prop(self, "playback")
        layout.prop(self, "method")
        layout.prop(self, "processes")
        layout.label(text=self.summary(obj), icon='INFO')

    def invoke(self, context, event):
        obj = context.object
        pair = _default_pair(obj)
        if not self.keys.strip() and not self.properties.is_property_set("key_set") and pair is not None:
            self.key_set = set(pair)
        if not self.properties.is_property_set("frame_start"):
            self.frame_start = context.scene.frame_current
        self.interactive = True
        return context.window_manager.invoke_props_dialog(self, width=420)

    def execute(self, context):
        def make(obj):
            keys, frames = self.bake_inputs(obj)
            return bake_runner(obj, keys, frames, smooth=self.smooth, method=self.method, playback=self.playback,
                               workers=self.processes)
        return self._run(context, make)


class LENGTHS_ANGLES_OT_clear_bake(bpy.types.Operator):
    """Remove the keys and keyframes made by Bake In-betweens (your own keys stay)"""

    bl_idname = "lengths_angles.clear_bake"
    bl_label = "Clear Lengths & Angles Bake"
    bl_description = "Remove the shape keys and keyframes made by Bake In-betweens, even if renamed (your keys stay)"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == 'MESH' and (BAKE_PROP in obj.data or any(bake_identity(obj).values()))

    def execute(self, context):
        obj = context.object
        with object_mode(obj):
            n = remove_bake(obj)
            obj.data.update()
        self.report({'INFO'}, f"Removed the bake ({n} keys)")
        return {'FINISHED'}


classes = (LENGTHS_ANGLES_OT_interpolate, LENGTHS_ANGLES_OT_bake_keyframes, LENGTHS_ANGLES_OT_clear_bake)
