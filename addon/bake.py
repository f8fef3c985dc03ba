# SPDX-License-Identifier: GPL-3.0-or-later
"""Bakes: the shape keys and keyframes of a baked lengths-and-angles motion, their record, writing and removal.

A bake of the user's keys ``K_0 .. K_{n-1}`` at frames ``f_0 < .. < f_{n-1}`` creates one key
``"LA bake <frame>"`` per in-between frame (:func:`.naming.bake_key_name`) and keyframes the value of
every key it drives so that playback shows exactly one key at 1 per frame
(:func:`activity_keyframes`; STEPPED = CONSTANT keyframes, SMOOTH = LINEAR: neighbouring frames
cross-fade).

Identity
--------
The bake's F-curves are in two F-curve groups (:data:`BAKED_GROUP`: the keys it created,
:data:`KEYED_GROUP`: your keys it keyframed).  Blender rewrites an F-curve's data path when its
shape key is renamed, so :func:`bake_identity` finds the bake under any names.  The mesh ID
property :data:`BAKE_PROP` records the values your keys had before, so a new bake or Clear Bake
(:func:`remove_bake`) removes exactly the previous bake and nothing else.

:func:`check_bake` validates a bake against the object and returns its plan (nothing written);
:func:`write_bake` replaces the previous bake by a computed plan.
"""

import bpy
import numpy as np

from . import compat, mesh_access
from .naming import OperatorInputError, bake_key_name

__all__ = ["BAKE_PROP", "BAKED_GROUP", "KEYED_GROUP", "PLAYBACK_ITEMS", "MAX_BAKED_KEYS", "value_path",
           "read_bake_record", "bake_identity", "has_bake", "activity_keyframes", "bake_frames", "bake_summary",
           "check_bake", "complete_bake", "remove_bake", "write_bake"]

BAKE_PROP = "lengths_angles_bake"
# F-curve groups of a bake: the identity of its curves and keys (Blender fixes the data paths of
# F-curves when a shape key is renamed, so the group finds them under any name).
BAKED_GROUP = "Lengths & Angles bake: new keys"
KEYED_GROUP = "Lengths & Angles bake: your keys"
MAX_BAKED_KEYS = 1000

PLAYBACK_ITEMS = [
    ('STEPPED', "Stepped", "CONSTANT keyframes: exactly one baked key at full value on every frame, held "
                           "between frames"),
    ('SMOOTH', "Smooth", "LINEAR keyframes: between two frames the neighbouring baked keys cross-fade (sub-frame "
                         "motion blur, retimed playback); identical to Stepped on whole frames"),
]
_INTERPOLATION = {'STEPPED': 0, 'SMOOTH': 1}  # keyframe interpolation enum values: CONSTANT, LINEAR


def value_path(name):
    """The data path of the value of the shape key ``name`` (on the Key datablock)."""
    return f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'


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
    your keys it keyframed), plus keys listed in the bake record that lost their curve.
    """
    out = {"baked": [], "keyed": []}
    key = obj.data.shape_keys
    if key is None:
        return out
    cb = compat.animation_channels(key)
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


def has_bake(obj):
    """Whether ``obj`` (a mesh object) has a bake: its record or any of its curves and keys."""
    return BAKE_PROP in obj.data or any(bake_identity(obj).values())


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
        raise OperatorInputError("Keys: give at least two shape keys (the keyframes of the motion)")
    if len(keys) != len(frames):
        raise OperatorInputError(f"{len(keys)} keys but {len(frames)} frames: give one frame per key")
    bad = [i for i in range(1, len(frames)) if frames[i] <= frames[i - 1]]
    if bad:
        i = bad[0]
        raise OperatorInputError(f"Frames must increase strictly: {frames[i - 1]} is followed by {frames[i]}")
    inbetween = [f for f in range(frames[0] + 1, frames[-1]) if f not in set(frames)]
    if len(inbetween) > MAX_BAKED_KEYS:
        raise OperatorInputError(f"Frames {frames[0]}..{frames[-1]} would bake {len(inbetween)} shape keys; "
                                 f"at most {MAX_BAKED_KEYS}")
    return inbetween


def bake_summary(obj, keys, frames):
    """One line for the Bake dialog: how many keys the bake creates (and replaces), or what is wrong."""
    try:
        inbetween = bake_frames(keys, frames)
    except OperatorInputError as exc:
        return str(exc)
    old = len(bake_identity(obj)["baked"]) if obj is not None and obj.type == 'MESH' else 0
    text = (f"Creates {len(inbetween)} shape key{'s' if len(inbetween) != 1 else ''} "
            f"(frames {frames[0]}-{frames[-1]}) and keyframes {len(set(keys))} of yours")
    return text + (f"; replaces the previous bake ({old} keys)" if old else "")


def check_bake(obj, names, keys, frames):
    """Validate a bake of ``keys`` at ``frames`` on ``obj`` (whose shape keys are ``names``) and plan it.

    Returns the plan without shapes: ``names`` (of the keys to create), ``animation`` (``{key name:
    [(frame, value)]}`` of every key the bake drives), ``user_keys``, ``frames``, ``inbetween_frames``.
    Raises :class:`.naming.OperatorInputError` naming the problem; nothing is written.
    """
    inbetween = bake_frames(keys, frames)
    mesh = obj.data
    if mesh.shape_keys is not None and not mesh.shape_keys.use_relative:
        raise OperatorInputError(f"Mesh '{mesh.name}': Bake needs Relative shape keys (absolute keys ignore the "
                                 "values a bake keyframes): check Relative in the Shape Keys panel")
    missing = [k for k in keys if k not in names]
    if missing:
        shown = ", ".join(f"'{m}'" for m in missing)
        have = ", ".join(f"'{n}'" for n in names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
        raise OperatorInputError(f"Mesh '{mesh.name}': no shape key {shown} (the mesh has {have})")
    ident = bake_identity(obj)
    own_keys = {n for _, n in ident["baked"] if n is not None}
    used_own = [k for k in keys if k in own_keys]
    if used_own:
        raise OperatorInputError(f"Keys: '{used_own[0]}' is a key of the previous bake, which a new bake "
                                 "replaces; keyframe your own keys")
    out_names = [bake_key_name(f) for f in inbetween]
    foreign = [n for n in out_names if n in names and n not in own_keys]
    if foreign:
        raise OperatorInputError(f"Shape key '{foreign[0]}' exists but was not made by a bake: rename it "
                                 "(a bake names its keys 'LA bake <frame>')")
    ad = mesh.shape_keys.animation_data if mesh.shape_keys is not None else None
    if ad is not None:
        driven = [k for k in dict.fromkeys(keys) if ad.drivers.find(value_path(k)) is not None]
        if driven:
            raise OperatorInputError(f"Shape key '{driven[0]}' has a driver on its value, which would override the "
                                     "bake's keyframes: remove the driver first (or duplicate the key)")
    cb = compat.animation_channels(mesh.shape_keys)
    if cb is not None:
        own_paths = {fc.data_path for role in ("baked", "keyed") for fc, _ in ident[role] if fc is not None}
        for k in dict.fromkeys(keys):
            path = value_path(k)
            if cb.fcurves.find(path) is not None and path not in own_paths:
                raise OperatorInputError(f"Shape key '{k}' already has animation of its value: the bake "
                                         "keyframes it, so remove that animation first (or duplicate the key)")
    first, last = frames[0], frames[-1]
    active = {}
    for k, f in zip(keys, frames, strict=True):
        active.setdefault(k, []).append(f)
    for n, f in zip(out_names, inbetween, strict=True):
        active[n] = [f]
    return {"names": out_names, "animation": {n: activity_keyframes(fs, first, last) for n, fs in active.items()},
            "user_keys": list(dict.fromkeys(keys)), "frames": list(frames), "inbetween_frames": inbetween}


def complete_bake(plan, shapes):
    """The plan with its computed shapes: ``keys`` = ``[(name, (V, 3) coordinates)]`` by frame."""
    keys = list(zip(plan["names"], shapes, strict=True))
    for name, X in keys:
        if not np.all(np.isfinite(X)):
            raise OperatorInputError(f"Bake: the reconstruction of '{name}' is not finite (the lengths and angles "
                                     "are too far from any shape)")
    return dict(plan, keys=keys)


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
        cb = compat.animation_channels(key)
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


def write_bake(obj, plan, source, playback='STEPPED'):
    """Replace the previous bake of ``obj`` by ``plan`` (:func:`complete_bake`); ``source`` (the bake's
    inputs) is kept in the record.  ``playback``: 'STEPPED' (CONSTANT keyframes) or 'SMOOTH' (LINEAR)."""
    mesh = obj.data
    old = read_bake_record(mesh)
    values_before = {}
    for name in plan["user_keys"]:  # the value before the FIRST bake that drove the key
        values_before[name] = old["values_before"].get(name, mesh.shape_keys.key_blocks[name].value)
    remove_bake(obj)
    for name, X in plan["keys"]:
        mesh_access.set_shape_key(obj, name, X)
    key = mesh.shape_keys
    cb, created = compat.ensure_animation_channels(key, f"{key.user.name} LA bake" if key.user else "LA bake")
    groups = {True: compat.fcurve_group(cb, BAKED_GROUP), False: compat.fcurve_group(cb, KEYED_GROUP)}
    baked = {n for n, _ in plan["keys"]}
    paths = []
    for name, points in plan["animation"].items():
        path = value_path(name)
        fc = cb.fcurves.new(path)
        fc.group = groups[name in baked]
        fc.keyframe_points.add(len(points))
        fc.keyframe_points.foreach_set("co", np.asarray(points, np.float32).ravel())
        fc.keyframe_points.foreach_set("interpolation", np.full(len(points), _INTERPOLATION[playback], np.int32))
        fc.update()
        paths.append(path)
    frame = bpy.context.scene.frame_current
    for name in plan["animation"]:
        key.key_blocks[name].value = cb.fcurves.find(value_path(name)).evaluate(frame)
    mesh[BAKE_PROP] = {
        "keys": [n for n, _ in plan["keys"]],
        "fcurves": paths,
        "values_before": values_before,
        "user_keys": list(plan["user_keys"]),
        "action": created or old["action"],
        "source": source,
    }
    mesh.update()
