# SPDX-License-Identifier: GPL-3.0-or-later
"""Whether an object's placement changes over time, read from Blender's data (glue only; no ``frame_set``).

The mocap operators map a take's markers into the character's space with one placement of the take empty and of
the character (their world matrices at the current frame); :func:`moving_transform` names what would move
either, or None.  It reads data only -- no frame change, so no frame-change handler runs and no unkeyed edit is
reverted -- and stays in the tens of microseconds.

What moves an object, in the order checked:

* its own transform channels: keys of changing values (or F-modifiers) in its action, a driver that is not
  constant (:func:`constant_driver`), a playing NLA strip keying them with changing values;
* an enabled constraint whose effect may change (:func:`constant_constraint`: a constraint that follows its
  targets, with targets that do not move and settings that are not animated, is constant);
* its parent link: a parent bone (parent type Bone) whose pose changes (:func:`bone_dependence`: keys, drivers,
  NLA strips or constraints on the bone or its ancestors, an IK chain through them; none in the armature's Rest
  Position), parent vertices (Vertex, 3 Vertices) of a mesh that is deformed (:func:`deformation`: animated shape
  keys, a modifier that may deform it over time);
* the same for each parent up the chain (an object parent, or an armature with parent type Armature: its object
  transform places the child, its pose only deforms the child's mesh -- not the placement; the fit's point cache
  replaces that deformation).

Every unknown case (a Python driver expression, a constraint type that reads time or geometry, a modifier that is
not known to be static) counts as moving: the check never lets through what may move.
"""

import ast
import re

import bpy
import numpy as np

from .compat import animation_channels, strip_fcurves

__all__ = ["TRANSFORM_PATHS", "BONE_CHANNELS", "transform_dependence", "moving_transform", "constant_driver",
           "constant_constraint", "bone_dependence", "deformation"]

TRANSFORM_PATHS = frozenset({"location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale",
                             "delta_location", "delta_rotation_euler", "delta_rotation_quaternion", "delta_scale"})
#: A pose bone's transform channels.
BONE_CHANNELS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale")
#: Constraint types whose effect is a function of the owner's and the targets' placements and of their settings:
#: constant when neither moves nor is animated.
FOLLOWS_TARGETS = frozenset({"COPY_LOCATION", "COPY_ROTATION", "COPY_SCALE", "COPY_TRANSFORMS", "CHILD_OF",
                             "TRACK_TO", "DAMPED_TRACK", "LOCKED_TRACK", "STRETCH_TO", "LIMIT_LOCATION",
                             "LIMIT_ROTATION", "LIMIT_SCALE", "LIMIT_DISTANCE", "MAINTAIN_VOLUME", "TRANSFORM",
                             "PIVOT", "FLOOR"})
#: Modifiers that change a mesh the same way at every frame (unless their settings are animated).
STATIC_MODIFIERS = frozenset({"SUBSURF", "MULTIRES", "TRIANGULATE", "EDGE_SPLIT", "WEIGHTED_NORMAL", "SMOOTH",
                              "LAPLACIANSMOOTH", "CORRECTIVE_SMOOTH", "SOLIDIFY"})
#: How deep drivers and constraints are followed to their targets (a longer chain counts as moving).
MAX_DEPTH = 8
_ROOT = re.compile(r'\["(?:[^"\\]|\\.)*"\]|[A-Za-z_]\w*')


def _esc(name):
    return bpy.utils.escape_identifier(name)


def _changing(fc):
    """True if the un-muted F-curve ``fc`` has F-modifiers or keys of different values."""
    if fc.mute:
        return False
    co = np.empty(2 * len(fc.keyframe_points), np.float32)
    fc.keyframe_points.foreach_get("co", co)
    return bool(len(fc.modifiers) or (co.size and np.ptp(co[1::2]) > 0))


def _channel_name(data_path, struct=None):
    """The UI name of the property at the end of ``data_path`` (``"Location"``, ``"Euler Rotation"`` ...)."""
    name = data_path.rsplit(".", 1)[-1]
    prop = (struct or bpy.types.Object).bl_rna.properties.get(name)
    return prop.name if prop is not None else name


def animated(id_data, wanted, depth=0):
    """How the animation of ``id_data`` changes a property whose data path ``wanted(path)`` accepts:
    ``("keys", fcurve, None)`` (its action's keys change), ``("driver", fcurve, None)`` (a driver that is not
    constant: :func:`constant_driver`), ``("nla", fcurve, (strip, track))`` (a playing NLA strip keys it with
    changing values), else None."""
    owner = animation_channels(id_data)
    if owner is not None:
        fc = next((fc for fc in owner.fcurves if wanted(fc.data_path) and _changing(fc)), None)
        if fc is not None:
            return ("keys", fc, None)
    ad = id_data.animation_data
    if ad is None:
        return None
    for fc in ad.drivers:
        if wanted(fc.data_path) and not fc.mute and not constant_driver(fc.driver, depth):
            return ("driver", fc, None)
    tracks = [t for t in ad.nla_tracks if not t.mute] if ad.use_nla else []
    if any(t.is_solo for t in tracks):
        tracks = [t for t in tracks if t.is_solo]
    for track in tracks:
        for strip in track.strips:
            if strip.mute:
                continue
            fc = next((fc for fc in strip_fcurves(strip) if wanted(fc.data_path) and _changing(fc)), None)
            if fc is not None:
                return ("nla", fc, (strip, track))
    return None


def expression_names(expression):
    """The names an arithmetic driver expression uses (a set), or None when it is more than arithmetic on names,
    numbers and function calls (attributes, subscripts, comprehensions ...).

    >>> sorted(expression_names("sin(frame / 10) * var"))
    ['frame', 'sin', 'var']
    >>> expression_names("bpy.context.scene.frame_current") is None
    True
    """
    try:
        tree = ast.parse(expression.strip() or "0", mode="eval")
    except (SyntaxError, ValueError):
        return None
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.keywords:
                return None
        elif not isinstance(node, (ast.Expression, ast.BinOp, ast.UnaryOp, ast.BoolOp, ast.Compare, ast.IfExp,
                                   ast.Constant, ast.Load, ast.operator, ast.unaryop, ast.boolop, ast.cmpop)):
            return None
    return names


def constant_driver(driver, depth=0):
    """True if ``driver``'s value cannot change over time: a simple expression (Blender's own evaluator, no
    Python) that does not use ``frame``, or an average / sum / min / max, of variables that are constant (a custom
    property or a transform channel that nothing animates; an object's or bone's transform that does not move).
    Python expressions, context properties and invalid drivers count as changing."""
    if depth > MAX_DEPTH or not driver.is_valid:
        return False
    variables = {v.name: v for v in driver.variables}
    if driver.type == 'SCRIPTED':
        if not driver.is_simple_expression:
            return False
        names = expression_names(driver.expression)
        if names is None or "frame" in names:
            return False
        used = [variables[n] for n in names if n in variables]
    else:
        used = list(variables.values())
    return all(_constant_variable(v, depth + 1) for v in used)


def _constant_variable(var, depth):
    if var.type == 'SINGLE_PROP':
        target = var.targets[0]
        return target.id is not None and _constant_property(target.id, target.data_path, depth)
    if var.type in ('TRANSFORMS', 'LOC_DIFF', 'ROTATION_DIFF'):
        targets = var.targets[:1] if var.type == 'TRANSFORMS' else var.targets[:2]
        return all(t.id is not None and _still(t.id, t.bone_target, depth) for t in targets)
    return False


def _constant_property(id_data, data_path, depth):
    """True if the property ``data_path`` of ``id_data`` is a custom property or an object's transform channel
    that its animation does not change (other properties may be evaluated, or change with the frame)."""
    match = _ROOT.match(data_path)
    if match is None:
        return False
    root = match.group(0)
    if not (root.startswith('["') or (isinstance(id_data, bpy.types.Object) and root in TRANSFORM_PATHS)):
        return False
    return animated(id_data, lambda p: p == root, depth) is None


#: Verdicts of :func:`_still` during one :func:`moving_transform` call: each target is looked at once, and a
#: dependency cycle counts as moving.
_SEEN = {}


def _still(ob, bone="", depth=0):
    """True if the object ``ob`` (and its bone ``bone``, if it is an armature) does not move."""
    if not isinstance(ob, bpy.types.Object) or depth > MAX_DEPTH:
        return False
    key = (ob.as_pointer(), bone)
    if key not in _SEEN:
        _SEEN[key] = False                  # while it is being looked at: reached again through a cycle
        _SEEN[key] = moving_transform(ob, depth) is None and not (
            bone and ob.type == 'ARMATURE' and bone_dependence(ob, bone, depth) is not None)
    return _SEEN[key]


def constant_constraint(con, owner_id, prefix, depth=0):
    """True if the effect of the constraint ``con`` cannot change over time: its type follows its targets
    (:data:`FOLLOWS_TARGETS`), its settings (data paths of ``owner_id`` starting with ``prefix``) are not
    animated, and its target and custom space object do not move (a vertex group of a mesh target counts as
    moving).  The owner's own placement is checked apart."""
    if con.type not in FOLLOWS_TARGETS or depth > MAX_DEPTH:
        return False
    if animated(owner_id, lambda p: p.startswith(prefix), depth) is not None:
        return False
    target, sub = getattr(con, "target", None), getattr(con, "subtarget", "")
    if target is not None and (not _still(target, sub, depth + 1) or (sub and target.type != 'ARMATURE')):
        return False
    space = getattr(con, "space_object", None)
    uses_space = 'CUSTOM' in (getattr(con, "owner_space", ""), getattr(con, "target_space", ""))
    return not (uses_space and space is not None and not _still(space, getattr(con, "space_subtarget", ""),
                                                                depth + 1))


def _active(con):
    return con.enabled and con.influence > 0 and con.is_valid


def _constraint_prefix(con, bone=None):
    own = f'constraints["{_esc(con.name)}"].'
    return own if bone is None else f'pose.bones["{_esc(bone)}"].{own}'


def _moving_constraint(constraints, owner_id, bone, depth):
    """The first constraint of ``constraints`` (of ``owner_id``, or of its pose bone ``bone``) whose effect may
    change over time: active and not constant, or with animated settings (it may switch on), else None."""
    for con in constraints:
        prefix = _constraint_prefix(con, bone)
        if _active(con):
            if not constant_constraint(con, owner_id, prefix, depth):
                return con
        elif con.is_valid and animated(owner_id, lambda p, prefix=prefix: p.startswith(prefix), depth) is not None:
            return con
    return None


def transform_dependence(ob, depth=0):
    """Why ``ob``'s own transform may change over time: ``(reason, advice)`` one-line phrases, or None.

    In this order: a keyed transform of its action that changes, a driver on a transform channel that is not
    constant, a strip of a playing NLA track keying a changing transform (:func:`animated`), an enabled
    constraint whose effect may change (:func:`constant_constraint`)."""
    name = ob.name
    found = animated(ob, TRANSFORM_PATHS.__contains__, depth)
    if found is not None:
        kind, fc, nla = found
        channel = _channel_name(fc.data_path)
        if kind == "keys":
            return ("keyed location, rotation or scale",
                    f"clear the transform keys of '{name}' (Object > Animation > Clear Keyframes)")
        if kind == "driver":
            return (f"a driver on its {channel}",
                    f"delete the driver of '{name}' (right-click {channel} > Delete Driver)")
        strip, track = nla
        return (f"its NLA strip '{strip.name}' keys {channel}",
                f"mute the NLA track '{track.name}' of '{name}' (Nonlinear Animation editor)")
    con = _moving_constraint(ob.constraints, ob, None, depth)
    if con is not None:
        return (f"its constraint '{con.name}' places it",
                f"apply, disable or delete the constraint '{con.name}' of '{name}' (Object Constraint Properties)")
    return None


def bone_dependence(arm, bone_name, depth=0):
    """Why the pose of the bone ``bone_name`` of the armature object ``arm`` may change over time: ``(reason,
    advice)``, or None (also in the armature's Rest Position, and for a bone that is not there).

    Keys, drivers and NLA strips on the transform channels of the bone or an ancestor (:func:`animated`), their
    constraints (:func:`constant_constraint`), and an IK or Spline IK constraint whose chain may pass through them.
    """
    if arm.type != 'ARMATURE' or arm.data.pose_position == 'REST' or arm.pose is None:
        return None
    pbone = arm.pose.bones.get(bone_name)
    if pbone is None:
        return None
    chain = [pbone, *pbone.parent_recursive]
    names = {b.name for b in chain}
    paths = {f'pose.bones["{_esc(n)}"].{c}': n for n in names for c in BONE_CHANNELS}
    found = animated(arm, paths.__contains__, depth)
    if found is not None:
        kind, fc, nla = found
        bone = paths[fc.data_path]
        channel = _channel_name(fc.data_path, bpy.types.PoseBone)
        if kind == "keys":
            return (f"keyed {channel} of its bone '{bone}'",
                    f"clear the keys of bone '{bone}' of '{arm.name}' (Pose Mode: Pose > Animation > Clear "
                    "Keyframes)")
        if kind == "driver":
            return (f"a driver on the {channel} of its bone '{bone}'",
                    f"delete the driver on the {channel} of bone '{bone}' of '{arm.name}' (Pose Mode: right-click "
                    f"{channel} > Delete Driver)")
        strip, track = nla
        return (f"its NLA strip '{strip.name}' keys the {channel} of its bone '{bone}'",
                f"mute the NLA track '{track.name}' of '{arm.name}' (Nonlinear Animation editor)")
    for b in chain:
        con = _moving_constraint(b.constraints, arm, b.name, depth)
        if con is not None:
            break
    else:   # an IK chain from a descendant may reach the bone
        b, con = next(((pb, c) for pb in arm.pose.bones for c in pb.constraints
                       if c.type in ('IK', 'SPLINE_IK') and _active(c) and names.intersection(_ik_chain(pb, c))),
                      (None, None))
        if con is None:
            return None
    return (f"the constraint '{con.name}' of its bone '{b.name}' poses it",
            f"apply, disable or delete the constraint '{con.name}' of bone '{b.name}' of '{arm.name}' (Bone "
            "Constraint Properties)")


def _ik_chain(pbone, con):
    """Names of the bones an IK or Spline IK constraint of ``pbone`` may pose: ``pbone`` and its ancestors, as
    many as its chain length (all for 0), one more to be safe."""
    chain = [pbone, *pbone.parent_recursive]
    n = int(getattr(con, "chain_count", 0))
    return {b.name for b in (chain[:n + 1] if n > 0 else chain)}


def deformation(ob, depth=0):
    """Why the vertices of the object ``ob`` (a mesh, curve or lattice a child is parented to) may move in its own
    space over time: a phrase, or None.

    Shape keys animated (:func:`animated` on the Key: keyed values or evaluation time, a driver that is not
    constant, an NLA strip), an Armature modifier whose armature moves or whose pose is animated or constrained,
    a modifier not known to be static (:data:`STATIC_MODIFIERS`), or a static modifier with animated settings.
    Modifiers hidden in the viewport are not evaluated there and do not count."""
    key = getattr(ob.data, "shape_keys", None)
    if key is not None:
        found = animated(key, lambda p: p.startswith("key_blocks[") or p == "eval_time", depth)
        if found is not None:
            what = {"keys": "keyed", "driver": "driven", "nla": "played by an NLA strip"}[found[0]]
            return f"its shape keys are {what}"
    for mod in ob.modifiers:
        if not mod.show_viewport:
            continue
        if mod.type == 'ARMATURE':
            arm = mod.object
            if arm is None:
                continue
            if (not _still(arm, "", depth + 1) or (arm.data.pose_position != 'REST' and (
                    animated(arm, lambda p: p.startswith("pose.bones["), depth) is not None
                    or any(_active(c) for b in arm.pose.bones for c in b.constraints)))):
                return f"its modifier '{mod.name}' deforms it with the armature '{arm.name}', which is animated"
            continue
        prefix = f'modifiers["{_esc(mod.name)}"].'
        settings = animated(ob, lambda p, prefix=prefix: p.startswith(prefix), depth)
        if mod.type not in STATIC_MODIFIERS or settings is not None:
            return f"its modifier '{mod.name}' may deform it over time"
    return None


def moving_transform(ob, depth=0):
    """``(object, reason, advice, link)`` for the first of ``ob`` and its parents whose placement may change over
    time, else None.  ``object`` is the one whose data moves it; ``link`` is ``""`` when it is ``ob`` or a parent
    moving by itself (:func:`transform_dependence`), else how the child ``link`` names is attached: a parent bone
    whose pose changes (:func:`bone_dependence`) or parent vertices that are deformed (:func:`deformation`)."""
    if depth == 0:
        _SEEN.clear()
    child = None
    while ob is not None:
        why = transform_dependence(ob, depth)
        if why is not None:
            return (ob, *why, "")
        parent = ob.parent
        if parent is not None and ob.parent_type == 'BONE' and ob.parent_bone:
            why = bone_dependence(parent, ob.parent_bone, depth)
            if why is not None:
                on = f"bone '{ob.parent_bone}' of '{parent.name}'"
                return (parent, *why, f"its parent {on}" if child is None else f"its parent '{ob.name}' on {on}")
        elif parent is not None and ob.parent_type in ('VERTEX', 'VERTEX_3'):
            why = deformation(parent, depth)
            if why is not None:
                return (parent, why, f"parent '{ob.name}' to '{parent.name}' as an object, not to its vertices "
                        "(Object > Parent > Object)", f"the vertices of its parent '{parent.name}'" if child is None
                        else f"its parent '{ob.name}' on the vertices of '{parent.name}'")
        child, ob = ob, parent
    return None
