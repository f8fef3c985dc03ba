# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender API differences between the supported versions (4.2 LTS .. 5.2), in one place.

Animation data
--------------
Blender 4.4 introduced *slotted* actions: the F-curves of an ID live in the
*channelbag* of the action slot assigned to the ID (``AnimData.action_slot``) in a
keyframe strip of the action's layer.  The legacy ``Action.fcurves`` of 4.4/4.5 sees only
single-slot actions, and Blender 5.0 removed it.  Blender 4.2 (and 4.3) have
only ``Action.fcurves``.  The functions here return the *owner* of the F-curve
collection: the channelbag where slotted actions exist, else the Action itself;
both have the same ``.fcurves`` collection API (``find``, ``new``, ``remove``,
iteration, ``len``).

File paths
----------
Blender 5.x warns when a ``//`` (blend-relative) path is given to a file-path property that does
not declare ``PATH_SUPPORTS_BLEND_RELATIVE`` (:data:`BLEND_RELATIVE_PATH`); 4.2 has no such option.

Tested headless with bpy 4.2.23 and 5.2.3 (``make test``: tests/blender/check_compat.py and
the bake checks), and by hand with bpy 4.2.0, 4.5.15 and 5.0.1.
"""

import bpy

__all__ = ["HAS_SLOTTED_ACTIONS", "BLEND_RELATIVE_PATH", "animation_channels", "ensure_animation_channels",
           "id_fcurves", "strip_fcurves", "fcurve_group"]


HAS_SLOTTED_ACTIONS = bpy.app.version >= (4, 4, 0)

#: ``options`` of a file-path property that takes ``//`` paths (relative to the .blend): newer Blenders warn
#: when such a path is given to a property without ``PATH_SUPPORTS_BLEND_RELATIVE``, which 4.2 does not know.
BLEND_RELATIVE_PATH = ({'PATH_SUPPORTS_BLEND_RELATIVE'}
                       if "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties else set())


def _channelbag(action, slot, ensure=False):
    """The channelbag of ``slot`` in ``action``'s first keyframe strip holding one (Blender 4.4+).

    Same as ``bpy_extras.anim_utils.action_get_channelbag_for_slot`` / ``action_ensure_channelbag_for_slot``
    (the latter exists only from 5.0 on); with ``ensure`` the layer, strip and channelbag are created.
    """
    for layer in action.layers:
        for strip in layer.strips:
            bag = strip.channelbag(slot)
            if bag:
                return bag
    if not ensure:
        return None
    layer = action.layers[0] if len(action.layers) else action.layers.new("Layer")
    strip = layer.strips[0] if len(layer.strips) else layer.strips.new(type='KEYFRAME')
    return strip.channelbag(slot, ensure=True)


def animation_channels(id_data):
    """The owner of the F-curves animating ``id_data`` (an ID with animation data), or None.

    Returns the channelbag of the assigned action slot (Blender 4.4+) or the assigned
    Action (4.2, 4.3); None when there is no action (or, 4.4+, no slot or channelbag).
    Never creates anything.
    """
    ad = getattr(id_data, "animation_data", None)
    if ad is None or ad.action is None:
        return None
    if not HAS_SLOTTED_ACTIONS:
        return ad.action
    if ad.action_slot is None:
        return None
    return _channelbag(ad.action, ad.action_slot)


def strip_fcurves(strip):
    """The F-curves an NLA strip plays: its action's channelbag of the strip's slot (Blender 4.4+; none without a
    slot) or the action's F-curves (4.2, 4.3); an empty tuple without an action.  Never creates anything."""
    action = strip.action
    if action is None:
        return ()
    if not HAS_SLOTTED_ACTIONS:
        return action.fcurves
    slot = strip.action_slot
    bag = _channelbag(action, slot) if slot is not None else None
    return bag.fcurves if bag else ()


def ensure_animation_channels(id_data, action_name):
    """The owner of ``id_data``'s F-curves, creating the action (named ``action_name``) and slot if needed.

    Returns ``(owner, created)``: ``owner.fcurves`` is the F-curve collection, ``created`` the
    name of the action created here ("" when ``id_data`` already had one).
    """
    ad = id_data.animation_data or id_data.animation_data_create()
    created = ""
    if ad.action is None:
        action = bpy.data.actions.new(action_name)
        ad.action = action
        created = action.name
    action = ad.action
    if not HAS_SLOTTED_ACTIONS:
        return action, created
    if ad.action_slot is None:
        slot = next((s for s in action.slots if s.target_id_type in (id_data.id_type, 'UNSPECIFIED')), None)
        if slot is None:
            slot = action.slots.new(id_type=id_data.id_type, name=id_data.name)
        ad.action_slot = slot
    return _channelbag(action, ad.action_slot, ensure=True), created


def id_fcurves(id_data, create=False, action_name=None):
    """The F-curve collection animating ``id_data`` (None if there is none and ``create`` is False).

    With ``create=True`` the action (``action_name``, default ``"<ID name> Action"``) and its
    slot are created when missing.  Use ``.find(data_path, index=...)`` / ``.new(data_path, index=...)``.
    """
    if create:
        owner, _created = ensure_animation_channels(id_data, action_name or f"{id_data.name} Action")
        return owner.fcurves
    owner = animation_channels(id_data)
    return None if owner is None else owner.fcurves


def fcurve_group(owner, name):
    """The F-curve group ``name`` of ``owner`` (a channelbag or an Action), created if missing.

    Both have ``.groups`` (``new(name)``); assign it with ``fcurve.group = group``.
    """
    group = owner.groups.get(name)
    return group if group is not None else owner.groups.new(name)
