# SPDX-License-Identifier: GPL-3.0-or-later
"""Live nonlinear mixing: Blender's own shape-key sliders drive lacore's :class:`ShapeMixer` (glue only).

``lengths_angles.live_mix_enable`` builds a mixer of the active mesh's keys through the one run
mechanism (:mod:`.runs`: modal with progress and Esc from the UI, synchronous from scripts) and stores
it with the mesh; from then on the mesh shows the lengths-and-angles mix of its keys' current values.

How the mesh follows the sliders
--------------------------------
The user's keys are never changed (values, mutes, ranges, drivers, keyframes): they stay the controls,
and Blender keeps adding them linearly.  One add-on key, :data:`.naming.LIVE_MIX_KEY` (relative to the
basis, value 1), carries the *correction* from Blender's linear sum to the mix::

    mix key = N(w) - sum_k w_k g_k (K_k - K_rel(k))
    so that   B + sum_k w_k g_k (K_k - K_rel(k)) + (mix key - B) = N(w)

where ``g_k`` are the per-vertex weights of key ``k``'s vertex group (1 without one) and ``K_rel(k)`` its relative
key (:func:`vertex_masks`, :meth:`_Live._set_reference`): Blender's own sum, which the mixer blends in lengths and
angles (``ShapeMixer.build(..., masks=, relative_to=)``).

with ``N(w)`` = :meth:`ShapeMixer.mix` of the weights ``w``, placed like the in-betweens (the rigid motion
that best fits it to Blender's linear blend, :func:`lacore.geometry.rigid.rigid_align`: at a single key at
1 the mesh is that key where it is).  The handlers ``depsgraph_update_post``
(a slider dragged, a driver, undo) and ``frame_change_post`` (playback, ``frame_set``, animation
renders: the values are read from the depsgraph being evaluated, the render's included) rewrite the
mix key when the weights change; Blender evaluates the key once more in the same update (for a render
the evaluated values are copied to the original keys first, as Blender does itself for the viewport, since
that second evaluation copies the key, values included, from the original).  Animation renders from the
user interface should use Render > Lock Interface (the render thread writes the mix key).  So
modifiers after the shape keys (Armature, Subdivision Surface ...) apply to the mix, and
:func:`disable` (removing the mix key and the stored mixer) gives back Blender's linear mixing bit for
bit.  Why a correction key rather than muting the user's keys: nothing of the user's state has to be
remembered and restored, mute and the slider range keep working as Blender's own controls, and a stale
mixer shows the exact linear mix by zeroing one key.

The mix key's value is 1: an edit of it (a script, Clear Shape Key Weights) is set back by the next update,
so are its coordinates, its relative key and vertex group, a slider range that excludes 1 and a new name (the
renamed key is found by the correction it holds, and named back before the file is saved, where only the name
identifies it); Enable refuses a mesh with a key of that name it did not make (the user's coordinates would be
written over);
muted, or keyed or driven to another value, the mixer is stale (below).

Exact renders: with the mesh's :data:`EXACT_RENDERS_PROP` on, a render's update (its depsgraph in
``'RENDER'`` mode) finishes the mix with the full Gauss-Newton projection (``ShapeMixer.mix(polish=True)``),
so F12, animation and command-line renders show the exact lengths-and-angles blend while the viewport stays
real-time.  A polish costs a full reconstruction per rendered frame (about a second at 13k vertices); where
it does not converge the render keeps the reduced mix and the panel says so.

Weights: a key's value as evaluated (slider min/max applied by Blender), 0 when it is muted.  Which keys are
mixed (:func:`split_keys`): every key relative to the basis or to another mixed key, with or without a vertex
group (Blender's rule for the group, matched by :func:`vertex_masks`: a name the mesh lacks, or a mesh without
vertex-group weights, limits nothing), up to :attr:`lacore.shapes.MixerOptions.max_keys` of them.  Blender mixes
linearly on top of the mix the keys added after the build, keys relative to themselves (they add nothing), keys the
artist chose to keep linear (:data:`LINEAR_KEYS_PROP`, :func:`set_linear_choice`: small local keys such as faces and
correctives, whose linear sum is already right) and keys relative to a key that is not mixed (an add-on ``"LA ..."``
key, or a key relative to one); the panel lists them with the reason (:func:`linear_reason`).

Staleness: every update compares the basis and mixer keys' coordinates, relative keys and vertex-group names and
the mesh's corners with the ones the mixer was built from (and after loading a .blend, with their stored digest
and record).  The vertex-group weights (:func:`vertex_masks`: 10-36 ms at 13k vertices, 42-130 ms at 50k) are
read again and compared with the mixer's only when a key's group name or the group it resolves to changed, after
undo and loading, and after an update that changed the mesh's data but no key value (a weight painted, a
script's edit, leaving Edit Mode: :func:`_edited_meshes`), so sliders, playback and posing a rig never pay for it.
While an object showing the mesh is in Weight Paint mode, such updates (every dab of a stroke) are not read: the weights
are read once the painting pauses for :data:`PAINT_SETTLE` seconds (:func:`settle_painting`, a timer) and when
the mode is left.  Until then the mesh shows the mix with the weights it was built with, plus Blender's own linear
change of the painted weights.  A renamed key (the basis too) is followed: the next update finds it by the
coordinates it was built with and the record takes its new name (:meth:`_Live.follow_renames`).  An edited
mesh or key, a deleted key (or one renamed and edited at once), an edited weight, a key given another vertex group
or relative key makes the mixer *stale*: the mix key is zeroed (the mesh shows Blender's linear mix) and the panel
says so until Rebuild; undoing the edit makes it live again.  In Edit Mode nothing is written.

Storage (saved in the .blend, decoded once per session: :func:`live_meshes` after ``load_post``): the
mixer's ``.npz`` (:meth:`ShapeMixer.save`, masks and relative keys included) is a payload of
:func:`.storage.store_payload` (a text datablock ``"LA live mixer <mesh>"``), and ``mesh["lengths_angles_live_mix"]``
its record: the text's name, the token, the key names, each key's vertex-group name (``groups``) and relative key
(``relative``; records without them: none and the basis), a fingerprint digest and the build time.

Linked meshes: Blender keeps data linked from a library as saved there (writes to it are dropped), so the mix key of
a linked live mesh cannot follow its values: :meth:`_Live.check` calls it stale, naming the library, Library Override
and Make Local, and enabling or disabling it is refused (:func:`linked_from`).

Library overrides (a character linked into a shot and overridden, its mesh made an override too so that its key values
can be keyed there): the record and the text it points at come along from the library, and the mix key is rewritten as
for a local mesh.  Blender drops a bulk write (``foreach_set``) into the key blocks of an override (their coordinates
are not overridable) but keeps a point's, so there :func:`_write` writes into the key block's own array (point by
point where it cannot be had).  Opening the file takes the override's key coordinates from the library again, and the
update after loading writes the mix key again.  Enabling or disabling is refused (:func:`override_from`): the
override's keys and mixer are the library's, reapplied whenever the file is opened.
"""

import hashlib
import io
import threading
import time

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..lacore.errors import InputError, MeshError
from ..lacore.geometry.rigid import rigid_align
from ..lacore.shapes import MixerOptions, ShapeMixer
from ..lacore.shapes.mixing import check_keys
from ..lacore.shapes.mixing.mixer import build_mixer_bytes, mixer_bytes
from . import storage
from .bake import value_path
from .compat import animation_channels
from .jobs import CallJob
from .mesh_access import (MeshAccessError, key_block_array, linked_from, override_from, read_shape_keys,
                          require_mesh_object, require_nondegenerate_keys, require_writable_keys, topology_error,
                          triangulate)
from .naming import LIVE_MIX_KEY, is_own_key
from .runs import ObjectWatch, Run

__all__ = ["MIXER_PROP", "TEXT_HEADER", "stored_npz", "LiveMixError", "split_keys", "enable_run", "store_mixer",
           "LINEAR_KEYS_PROP", "linear_choice", "set_linear_choice", "keep_linear",
           "disable", "require_live", "is_live", "status", "update_all", "register_handlers", "unregister_handlers",
           "live_meshes", "mixer_for_keys", "EXACT_RENDERS_PROP"]

MIXER_PROP = "lengths_angles_live_mix"
#: Mesh property (bool): renders show the exact projection (the mix polished by full Gauss-Newton).
EXACT_RENDERS_PROP = "lengths_angles_live_mix_exact_renders"
#: Mesh property (list of str): the names of the keys the artist keeps in Blender's linear mix.
LINEAR_KEYS_PROP = "lengths_angles_live_mix_linear"
FORMAT_VERSION = 1


class LiveMixError(InputError):
    """A mesh that cannot be mixed live (no keys, Edit Mode, absolute keys, no mixer ...)."""


# ------------------------------------------------------------------------------------------- reading
def _key_print(kb):
    """A digest of the key block ``kb``'s coordinates by value (:func:`_coords_print`)."""
    co = np.empty(3 * len(kb.points), np.float32)
    kb.points.foreach_get("co", co)
    return _coords_print(co)


def _coords_print(coords):
    """A digest of one key's ``(3 V,)`` float32 coordinates by value (:func:`_digest`): what finds a key after a
    rename (:func:`_keys_by_print`)."""
    return _digest(coords, np.empty(0, np.int32))


def _keys_by_print(blocks, prints):
    """For each digest of ``prints``, the name of the one key block of ``blocks`` whose coordinates have it (None if
    no key or several do); each block's coordinates are read once."""
    have = {kb.name: _key_print(kb) for kb in blocks}
    found = [[n for n, p in have.items() if p == d] for d in prints]
    return [m[0] if len(m) == 1 else None for m in found]


def _stored_choice(mesh):
    """``{name: digest}`` of the keys kept linear as stored on ``mesh`` (digest "" in files that stored names only)."""
    stored = mesh.get(LINEAR_KEYS_PROP)
    if stored is None:
        return {}
    if hasattr(stored, "keys"):
        return {str(n): str(d) for n, d in stored.items()}
    return {str(n): "" for n in stored}


def linear_choice(mesh):
    """The names of the keys of ``mesh`` the artist keeps in Blender's linear mix (:func:`set_linear_choice`).

    A stored name that no key has any more is followed to the key renamed from it: the one key, not chosen under its
    own name, whose coordinates have the digest stored with the choice (a key both renamed and edited, or one of two
    equal keys, is not found and mixes live again).  A name that a key still has is that key's, even if the names
    were swapped."""
    stored = _stored_choice(mesh)
    key = mesh.shape_keys
    if key is None:
        return set(stored)
    blocks = key.key_blocks
    found = {n for n in stored if blocks.get(n) is not None}
    lost = [d for n, d in stored.items() if n not in found and d]
    if lost:
        others = [kb for kb in blocks
                  if kb.name not in stored and kb != key.reference_key and not is_own_key(kb.name)]
        found |= {n for n in _keys_by_print(others, lost) if n is not None}
    return found


def set_linear_choice(mesh, name, linear=True):
    """Keep the key ``name`` of ``mesh`` in Blender's linear mix (``linear``), or mix it live again.  Applies at the
    next Enable or Rebuild.  Stores each chosen key's name and coordinates' digest (:func:`linear_choice` follows a
    rename by it); a chosen key deleted since is dropped."""
    keep = linear_choice(mesh)
    keep = keep | {name} if linear else keep - {name}
    _store_choice(mesh, keep)


def _store_choice(mesh, names):
    """Store ``names`` (keys of ``mesh``; others are dropped) as the keys kept linear, each with its digest."""
    blocks = mesh.shape_keys.key_blocks if mesh.shape_keys is not None else {}
    keep = {n: _key_print(blocks[n]) for n in sorted(names) if blocks.get(n) is not None}
    if keep:
        mesh[LINEAR_KEYS_PROP] = keep
    elif LINEAR_KEYS_PROP in mesh:
        del mesh[LINEAR_KEYS_PROP]


def keep_linear(obj, linear=True):
    """Keep the active shape key of ``obj`` in Blender's linear mix (``linear``) or mix it live again
    (:func:`set_linear_choice`); returns the report's line.  Raises :class:`LiveMixError` (one line) for no key, the
    basis, an add-on key or a linked mesh."""
    mesh = require_mesh_object(obj)
    kb = obj.active_shape_key
    if mesh.shape_keys is None or kb is None:
        raise LiveMixError(f"'{obj.name}' has no shape keys: add a Basis and the keys to mix")
    if kb == mesh.shape_keys.reference_key:
        raise LiveMixError(f"'{kb.name}' is the basis: select the key to keep linear in the key list")
    if is_own_key(kb.name):
        raise LiveMixError(f"'{kb.name}' is the add-on's own key: select one of your keys in the key list")
    _require_local(mesh, "choose its linear keys")
    set_linear_choice(mesh, kb.name, linear)
    state = status(mesh)
    when = "" if state is None or (kb.name in state["keys"]) != linear else " from the next Rebuild"
    return f"'{kb.name}' {'stays in the linear mix' if linear else 'mixes live'}{when}"


def split_keys(mesh):
    """``(basis, nonlinear, linear)`` key names of ``mesh``: the reference key, the keys the mixer mixes and the keys
    Blender keeps mixing linearly.  The add-on's own ``"LA ..."`` keys are in neither list.

    Mixed: every key relative to the basis or to another mixed key, with or without a vertex group.  Linear: a key
    relative to itself (it adds nothing), a key the artist keeps linear (:func:`linear_choice`) or a key relative to a
    key that is not mixed (an add-on key, a key relative to one)."""
    key = mesh.shape_keys
    ref = key.reference_key
    chosen = linear_choice(mesh)
    blocks = [kb for kb in key.key_blocks if kb != ref and not is_own_key(kb.name)]
    mixed = {kb.name for kb in blocks if kb.relative_key != kb and kb.name not in chosen}
    while True:  # drop the keys relative to a key that is not mixed, until none is left
        keep = {kb.name for kb in blocks
                if kb.name in mixed and (kb.relative_key == ref or kb.relative_key.name in mixed)}
        if keep == mixed:
            break
        mixed = keep
    return (ref.name, [kb.name for kb in blocks if kb.name in mixed],
            [kb.name for kb in blocks if kb.name not in mixed])


def linear_reason(kb, reference, mixed, chosen=()):
    """Why Blender mixes the key block ``kb`` linearly while ``mixed`` (names) are mixed on the basis ``reference``
    and ``chosen`` (names) are kept linear by the artist (a few words for the panel)."""
    rel = kb.relative_key
    if rel == kb:
        return "relative to itself: adds nothing"
    if kb.name in chosen:
        return "kept linear"
    if rel != reference and rel.name not in mixed:
        return f"relative to '{rel.name}', which is not mixed"
    return "added or changed after the build: Rebuild to mix it"


def _owner(mesh, hint=""):
    """An object using ``mesh`` (the object ``hint`` if it does), None if none: its vertex groups are the mesh's."""
    obj = bpy.data.objects.get(hint) if hint else None
    if obj is not None and obj.data == mesh:
        return obj
    if mesh.users <= mesh.use_fake_user:  # no object uses it: no scan
        return None
    return next((o for o in bpy.data.objects if o.data == mesh), None)


def _weight_painted(mesh, hint=""):
    """Whether an object showing ``mesh`` is in Weight Paint mode (the object ``hint`` first; a linked duplicate may be
    the one painted)."""
    obj = _owner(mesh, hint)
    if obj is None:
        return False
    if obj.mode == 'WEIGHT_PAINT':
        return True
    return mesh.users > 1 and any(o.data == mesh and o.mode == 'WEIGHT_PAINT' for o in bpy.data.objects)


def _group_indices(obj, groups):
    """The index of the vertex group Blender applies for each vertex-group name of ``groups`` (-1: the key applies to
    all vertices: no name, or a name ``obj``, the mesh's user, does not have)."""
    vgs = None if obj is None else obj.vertex_groups
    found = [vgs.get(g) if g and vgs is not None else None for g in groups]
    return tuple(-1 if vg is None else vg.index for vg in found)


def vertex_masks(mesh, indices):
    """``(len(indices), V)`` float32: the factor Blender applies to each vertex of a key limited to the vertex group
    of index ``indices[k]``: its weight, 0 outside the group; 1 everywhere for -1 (:func:`_group_indices`) and when
    the mesh stores no vertex-group weights at all (Blender then limits nothing).

    Read through a BMesh copy: reading ``mesh.vertices[i].groups`` would add an empty weight layer to a mesh without
    one, and so limit its keys' groups to nothing.  10-11 ms at 13k vertices and 42-43 ms at 50k with 3 shape keys,
    36 ms and 107-130 ms with 50 (the copy takes the keys along), two groups read, bpy 4.2 and 5.2."""
    import bmesh
    out = np.ones((len(indices), len(mesh.vertices)), np.float32)
    wanted = sorted({g for g in indices if g >= 0})
    if not wanted:
        return out
    bm = bmesh.new()
    try:
        bm.from_mesh(mesh)
        layer = bm.verts.layers.deform.active
        if layer is None:
            return out
        dverts = [v[layer] for v in bm.verts]
        read = {g: np.fromiter((d.get(g, 0.0) for d in dverts), np.float32, count=len(dverts)) for g in wanted}
    finally:
        bm.free()
    for row, g in enumerate(indices):
        if g >= 0:
            out[row] = read[g]
    return out


def _corners(mesh):
    """The corner (loop) vertex indices as int32 (the connectivity a mixer was built on)."""
    attr = mesh.attributes.get(".corner_vert")
    out = np.empty(len(mesh.loops), np.int32)
    if attr is not None and len(attr.data) == len(out):
        attr.data.foreach_get("value", out)
    else:  # pragma: no cover - Blender versions without the generic corner attribute
        mesh.loops.foreach_get("vertex_index", out)
    return out


def _key_coords(key, names, n_vertices):
    """``(len(names), 3 V)`` float32 coordinates of the keys ``names`` (None if one is missing or resized)."""
    out = np.empty((len(names), 3 * n_vertices), np.float32)
    for i, name in enumerate(names):
        kb = key.key_blocks.get(name)
        if kb is None or len(kb.points) != n_vertices:
            return None
        kb.points.foreach_get("co", out[i])
    return out


def _digest(coords, corners, signed_zeros=False):
    """A digest of key coordinates and corners by value: -0.0 and 0.0 (which an Edit Mode round trip may swap) digest
    alike, unless ``signed_zeros`` (the digest of the bytes as they are, which records may hold too)."""
    values = coords if signed_zeros else coords + np.float32(0.0)  # -0.0 + 0.0 is 0.0
    return hashlib.blake2b(values.tobytes() + corners.tobytes(), digest_size=16).hexdigest()


# ------------------------------------------------------------------------------------------- runtime
class _Live:
    """The session state of one live mesh: the decoded mixer, what it was built from, the last mix."""

    def __init__(self, mesh, meta, mixer):
        self.token = str(meta["token"])
        self.basis = str(meta["basis"])
        self.names = list(meta["keys"])
        self.n_vertices = int(meta["n_vertices"])
        # each key's vertex group ("" none) and relative key when the mixer was built (records without them: no
        # group, relative to the basis)
        self.groups = [str(g) for g in meta.get("groups", [""] * len(self.names))]
        self.relative = [str(r) for r in meta.get("relative", [self.basis] * len(self.names))]
        self.build_seconds = float(meta.get("build_seconds", 0.0))
        self.reduced_size = int(meta.get("reduced_size", 0))
        self.mixer = mixer
        self.reference = None  # (K, 3V) float32 basis + mixer keys as built (None: not verified yet)
        self.corners = None
        self.deltas = None  # (K-1, 3V) float64 g_k (K_k - K_rel(k)): Blender's linear contribution of key k at 1
        self.owner = ""  # an object using the mesh (whose vertex groups are read)
        self.groups_seen = None  # the keys' vertex-group names and indices at the last check of the weights
        self.check_masks = True  # read the weights again at the next check (built, loaded, undone, edited)
        self.painted_at = None  # time.monotonic() of the last edit in Weight Paint mode not read yet (None: none)
        self.mask_reason = ""  # why the weights Blender applies differ from the mixer's ("" when they do not)
        self.values_seen = None  # the evaluated key values of the last update
        self.last = None  # weights of the mix in the mix key
        self.correction = None  # the coordinates last written into the mix key when they were not the basis'
        self.result = None  # its MixResult
        self.stale = ""  # why the mixer does not fit the mesh now ("" when it does)
        self.error = ""  # a mix that failed (the linear mix is shown)
        self.mix_seconds = 0.0
        self.renames_tried = None  # the key names when a rename was last looked for and not found
        self.unwritten = False  # names followed (:meth:`follow_renames`) and not yet stored in the record
        coords = _key_coords(mesh.shape_keys, [self.basis, *self.names], self.n_vertices) \
            if mesh.shape_keys is not None and len(mesh.vertices) == self.n_vertices else None
        if coords is not None:
            corners = _corners(mesh)
            fingerprint = str(meta["fingerprint"])
            if fingerprint == _digest(coords, corners) or fingerprint == _digest(coords, corners, signed_zeros=True):
                self._set_reference(coords, corners)

    def _set_reference(self, coords, corners):
        self.reference, self.corners = coords, corners
        c = coords.astype(np.float64)
        masks = np.repeat(np.asarray(self.mixer.masks, np.float64), 3, axis=1)
        self.deltas = masks * (c[1:] - c[np.asarray(self.mixer.relative_to, np.int64)])

    def follow_renames(self, mesh, write=True):
        """Follow the mixer's keys to their new names after a rename; True if a name changed.  A missing basis is the
        reference key, another missing key the one key, not known under another name, whose coordinates are those
        it was built with; the relative keys' names follow.  A key both renamed and edited, or one of two equal
        keys, is not found (then :meth:`check` says it was deleted).  Needs the keys as built (:attr:`reference`).

        The names are stored in the mesh's record with ``write`` (an update, a save), else at the next call with
        ``write`` (a panel's or dialog's draw, where nothing may be written)."""
        if write and self.unwritten:
            self._write_names(mesh)
        key = mesh.shape_keys
        if key is None or self.reference is None:
            return False
        blocks, ref = key.key_blocks, key.reference_key
        names = [self.basis, *self.names]
        missing = [i for i, n in enumerate(names) if blocks.get(n) is None]
        seen = tuple(kb.name for kb in blocks)
        if not missing or seen == self.renames_tried:
            return False
        self.renames_tried = seen
        others = [kb for kb in blocks if kb.name not in names and not is_own_key(kb.name)]
        new = list(names)
        for wanted, blocks_of in (([i for i in missing if i == 0], [kb for kb in others if kb == ref]),  # the basis
                                  ([i for i in missing if i > 0], [kb for kb in others if kb != ref])):
            if wanted:
                prints = [_coords_print(self.reference[i]) for i in wanted]
                for i, name in zip(wanted, _keys_by_print(blocks_of, prints), strict=True):
                    if name is not None and name not in new:
                        new[i] = name
        if new == names:
            return False
        renamed = dict(zip(names, new, strict=True))
        self.basis, self.names = new[0], new[1:]
        self.relative = [renamed.get(r, r) for r in self.relative]
        self.renames_tried, self.unwritten = None, True
        if write:
            self._write_names(mesh)
        return True

    def _write_names(self, mesh):
        """Store the key names in the mesh's record."""
        meta = mesh[MIXER_PROP]
        meta["basis"], meta["keys"], meta["relative"] = self.basis, self.names, self.relative
        self.unwritten = False

    def _masks_changed(self, mesh, key):
        """Why the vertex-group weights Blender applies to the mixer's keys differ from the mixer's now ("" if they
        do not).  The weights are read again (:func:`vertex_masks`) only when a key's group or the mesh's groups
        changed, or :attr:`check_masks` asks for it (an update that edited the mesh and no key value, undo, load)."""
        obj = _owner(mesh, self.owner)
        if obj is None:  # no object shows the mesh: nothing to compare with
            return self.mask_reason
        self.owner = obj.name
        groups = [key.key_blocks[n].vertex_group for n in self.names]
        seen = (tuple(groups), _group_indices(obj, groups))
        if seen == self.groups_seen and not self.check_masks:
            return self.mask_reason
        self.groups_seen, self.check_masks, self.painted_at = seen, False, None
        masks = vertex_masks(mesh, seen[1])
        built = np.asarray(self.mixer.masks, np.float32)
        self.mask_reason = ""
        for name, g, g0, now, then in zip(self.names, groups, self.groups, masks, built, strict=True):
            if np.array_equal(now, then):
                continue
            if g != g0:
                self.mask_reason = (f"shape key '{name}' is limited to the vertex group '{g}' now, "
                                    f"'{g0}' when the mixer was built" if g and g0 else
                                    f"shape key '{name}' has the vertex group '{g}' now" if g else
                                    f"shape key '{name}' has no vertex group now ('{g0}' when the mixer was built)")
            elif g and obj.vertex_groups.get(g) is None:
                self.mask_reason = (f"the vertex group '{g}' of shape key '{name}' is missing now (Blender applies "
                                    "the key to all vertices)")
            else:
                self.mask_reason = f"the weights of the vertex group '{g}' of shape key '{name}' were edited"
            break
        return self.mask_reason

    def check(self, mesh):
        """Why the mixer does not fit ``mesh`` now ("" if it does): structure, then coordinates."""
        library = linked_from(mesh)
        if library:
            return (f"the mesh is linked from '{library}', where its mix key cannot be rewritten: it shows the "
                    "library's mix only at the key values saved there; make the mesh a library override (Outliner: "
                    "right-click the mesh > Library Override > Make > Selected) or local (Object > Relations > Make "
                    "Local) to mix live")
        key = mesh.shape_keys
        if key is None:
            return "the shape keys were removed (applied or cleared): Disable drops the stored mixer"
        if not key.use_relative:
            return "the shape keys are not Relative any more"
        if len(mesh.vertices) != self.n_vertices:
            return f"the mesh has {len(mesh.vertices)} vertices now, {self.n_vertices} when the mixer was built"
        ref = key.reference_key
        if ref.name != self.basis:
            return f"the basis key is '{ref.name}' now, '{self.basis}' when the mixer was built"
        for name in self.names:
            if key.key_blocks.get(name) is None:
                return f"shape key '{name}' was deleted (or renamed and edited at once)"
        for name, rel in zip(self.names, self.relative, strict=True):
            now = key.key_blocks[name].relative_key.name
            if now != rel:
                return f"shape key '{name}' is relative to '{now}' now, '{rel}' when the mixer was built"
        mix = key.key_blocks.get(LIVE_MIX_KEY)
        if mix is None:
            return f"the key '{LIVE_MIX_KEY}' was deleted"
        if mix.relative_key != ref or mix.vertex_group:
            return f"the key '{LIVE_MIX_KEY}' was changed (relative key or vertex group)"
        if mix.mute:
            return f"the key '{LIVE_MIX_KEY}' was muted: unmute it"
        if mix.value != 1.0:
            return f"the value of the key '{LIVE_MIX_KEY}' is keyed or driven: remove that, its value is 1"
        if self.reference is None:
            return "the mesh or its keys differ from the ones the mixer was built from"
        coords = _key_coords(key, [self.basis, *self.names], self.n_vertices)
        if not np.array_equal(_corners(mesh), self.corners):
            return "the mesh's faces were edited"
        edited = [n for n, a, b in zip([self.basis, *self.names], coords, self.reference, strict=True)
                  if not np.array_equal(a, b)]
        if edited:
            return f"shape key '{edited[0]}' was edited"
        return self._masks_changed(mesh, key)

    def weights_edited(self, mesh):
        """An update changed ``mesh`` and no key value (a weight painted, a script's edit): read the weights again at
        the next check; while an object showing it is in Weight Paint mode, once the painting pauses
        (:func:`settle_painting`).  With a read pending (:attr:`check_masks`: the painting settled, and the update
        its tag causes is no further dab) nothing more is needed: that read takes the weights as they are then."""
        if self.check_masks:
            return
        if _weight_painted(mesh, self.owner):
            self.painted_at = time.monotonic()
            if not bpy.app.timers.is_registered(settle_painting):
                bpy.app.timers.register(settle_painting, first_interval=PAINT_SETTLE)
        else:
            self.check_masks = True

    def weights(self, key_eval):
        """The mixer weights from the evaluated key: values within the slider range, 0 for muted keys."""
        w = np.empty(len(self.names), np.float64)
        for i, name in enumerate(self.names):
            kb = key_eval.key_blocks[name]
            w[i] = 0.0 if kb.mute else min(max(kb.value, kb.slider_min), kb.slider_max)
        return w


_LIVE = {}  # mesh name_full -> _Live
_MIXERS = {}  # token -> ShapeMixer (decoded once per session)
_BROKEN = set()  # names of meshes whose stored mixer cannot be read (their mix key is zeroed)
_GUARD = [False]  # a handler writing: the updates it causes are not handled again
_LOCK = threading.Lock()  # one update at a time (a render thread and the main thread)


#: What the panel says to do about slider values outside the mixer's accurate range.
RANGE_ADVICE = "keep the sliders within that range, or use In-betweens with Gauss-Newton for such shapes"

#: First line of the text datablock holding a mixer (followed by the token): :func:`.storage.store_payload`.
TEXT_HEADER = storage.payload_header("Lengths & Angles live mixer (do not edit)")


def stored_npz(meta):
    """The mixer ``.npz`` (bytes) of the stored mixer ``meta`` (``mesh[MIXER_PROP]``), :class:`LiveMixError` if its
    text datablock is gone or is not it."""
    try:
        return storage.load_payload(meta, TEXT_HEADER)
    except storage.PayloadError as exc:
        raise LiveMixError(f"the live mixer cannot be read ({exc}): Rebuild") from None


def _decode(meta):
    token = str(meta["token"])
    mixer = _MIXERS.get(token)
    if mixer is None:
        mixer = ShapeMixer.load(io.BytesIO(stored_npz(meta)))
        _MIXERS[token] = mixer
    return mixer


def _live(mesh):
    """The session state of ``mesh`` (decoded on first use), None if it has no mixer or it cannot be read."""
    meta = mesh.get(MIXER_PROP)
    if meta is None:
        _LIVE.pop(mesh.name_full, None)
        return None
    live = _LIVE.get(mesh.name_full)
    if live is not None and live.token == str(meta["token"]):
        return live
    try:
        live = _Live(mesh, meta, _decode(meta))
    except (InputError, KeyError, ValueError) as exc:
        if mesh.name_full not in _BROKEN:
            print(f"Lengths & Angles: the live mixer of '{mesh.name}' cannot be read ({exc}): rebuild it")
        _LIVE.pop(mesh.name_full, None)
        _BROKEN.add(mesh.name_full)  # the handlers show Blender's linear mix
        return None
    _BROKEN.discard(mesh.name_full)
    _LIVE[mesh.name_full] = live
    return live


def live_meshes():
    """Meshes with a stored mixer (their session state decoded)."""
    return [m for m in bpy.data.meshes if MIXER_PROP in m and _live(m) is not None]


def is_live(mesh):
    return mesh is not None and MIXER_PROP in mesh


def status(mesh):
    """What the panel shows: ``dict(keys, linear, linear_reasons, build_seconds, reduced_size, space_size, stale,
    in_range, message, mix_seconds, polished, linked, override)`` (``reduced_size``: the quality asked for, 0
    automatic; ``space_size``: the mixer's reduced size; ``linear``: the keys Blender mixes linearly on top,
    ``linear_reasons`` why, :func:`linear_reason`; ``kept_linear_mixed``: keys the mixer mixes that the artist has
    chosen to keep linear since, until a Rebuild; ``polished``: the last mix is a render's exact one; ``linked``: the
    library path of a linked mesh, whose mix key cannot be rewritten, else ""; ``override``: the library path of a
    library override, whose mixer is rebuilt there, else "") or None when ``mesh`` has no mixer."""
    if not is_live(mesh):
        return None
    live = _live(mesh)
    if live is None:
        return {"keys": [], "linear": [], "linear_reasons": {}, "kept_linear_mixed": [], "build_seconds": 0.0,
                "reduced_size": 0,
                "space_size": 0, "stale": "the stored mixer cannot be read", "in_range": True, "message": "",
                "mix_seconds": 0.0, "polished": False,
                "linked": linked_from(mesh), "override": override_from(mesh)}
    res = live.result
    key = mesh.shape_keys
    linked = linked_from(mesh)
    linear = [] if key is None else [kb for kb in key.key_blocks
                                     if kb != key.reference_key and kb.name not in live.names
                                     and not is_own_key(kb.name)]
    chosen = linear_choice(mesh)
    reasons = {kb.name: linear_reason(kb, key.reference_key, live.names, chosen) for kb in linear}
    exact = res is not None and res.polished and res.in_range  # a converged polish: the exact projection
    message = "" if res is None or exact else (live.mixer.range_message(res.weights, names=live.names,
                                                                        advice=RANGE_ADVICE) or res.message)
    stale = live.stale or live.error or (live.check(mesh) if linked else "")  # (a linked mesh is never updated)
    return {"keys": live.names, "linear": list(reasons), "linear_reasons": reasons,
            "kept_linear_mixed": [n for n in live.names if n in chosen],
            "build_seconds": live.build_seconds,
            "reduced_size": live.reduced_size, "space_size": int(live.mixer.reduced_size), "stale": stale,
            "in_range": True if res is None else bool(res.in_range), "message": message,
            "mix_seconds": live.mix_seconds, "polished": bool(res is not None and res.polished),
            "linked": linked, "override": override_from(mesh)}


# ------------------------------------------------------------------------------------------- updating
def _write(kb, coords):
    """Write ``coords`` (3V float32) into the key ``kb`` if they differ; True if written.

    A library override's key blocks refuse a bulk write (``foreach_set`` skips every point: their coordinates are not
    overridable) but keep a point's: there ``coords`` go into Blender's own array of the key block
    (:func:`.mesh_access.key_block_array`, under 0.3 ms at 13k vertices), or point by point where that array cannot be
    had (15-40 ms at 13k vertices, each point's update walking all objects: 30-160 ms in a file of 200-1,000)."""
    old = np.empty_like(coords)
    kb.points.foreach_get("co", old)
    if np.array_equal(old, coords):
        return False
    if kb.id_data.user.override_library is None:
        kb.points.foreach_set("co", coords)
        return True
    array = key_block_array(kb, old)
    if array is not None:
        array[:] = coords
        kb.points.foreach_get("co", old)
    if array is None or not np.array_equal(old, coords):
        for point, co in zip(kb.points, coords.reshape(-1, 3).tolist(), strict=True):
            point.co = co
    return True


def _flush_values(key, key_eval):
    """Copy the values a render evaluated (keyframes, drivers) to the original key, as Blender does for the
    viewport: the mix key written here is copied into the render's depsgraph together with the original
    key's values, and the render evaluates the keys once more without animation."""
    for kb, kb_eval in zip(key.key_blocks, key_eval.key_blocks, strict=True):
        if kb.value != kb_eval.value:
            kb.value = kb_eval.value


def _zero_mix_key(mesh):
    """The mix key at its relative key's coordinates (Blender's linear mix); True if written."""
    key = mesh.shape_keys
    kb = None if key is None or mesh.is_editmode else key.key_blocks.get(LIVE_MIX_KEY)
    if kb is None or len(kb.points) != len(mesh.vertices):
        return False
    return _write(kb, _zero_offset(kb))


def _zero_offset(kb):
    """Coordinates that make the key block ``kb`` add nothing: those of its relative key (the basis unless an edit
    changed it)."""
    co = np.empty(3 * len(kb.points), np.float32)
    kb.relative_key.points.foreach_get("co", co)
    return co


def _animated(key, kb):
    """Whether the value of the key block ``kb`` of ``key`` is keyed or driven."""
    ad = key.animation_data
    if ad is None:
        return False
    path = value_path(kb.name)
    channels = animation_channels(key)
    return ad.drivers.find(path) is not None or (channels is not None and channels.fcurves.find(path) is not None)


def _renamed_mix_key(mesh, live):
    """The key block of ``mesh`` holding the mix key's last correction under another name (the mix key renamed),
    None if there is none.  Only a correction identifies it: a key at the basis' coordinates adds nothing."""
    key = mesh.shape_keys
    if key is None or live.correction is None or key.key_blocks.get(LIVE_MIX_KEY) is not None:
        return None
    co = np.empty_like(live.correction)
    for kb in key.key_blocks:
        if kb == key.reference_key or kb.name in live.names or len(kb.points) * 3 != len(co):
            continue
        kb.points.foreach_get("co", co)
        if np.array_equal(co, live.correction):
            return kb
    return None


def _name_back(mesh, live):
    """``(mix key block, renamed)``: the mix key of ``mesh``, named back if it was renamed by hand (found by the
    correction it holds); ``(None, False)`` if there is none."""
    key = mesh.shape_keys
    kb = None if key is None else key.key_blocks.get(LIVE_MIX_KEY)
    if kb is not None:
        return kb, False
    kb = _renamed_mix_key(mesh, live)
    if kb is None:
        return None, False
    kb.name = LIVE_MIX_KEY
    return kb, True


def _restore_mix_key(mesh, live):
    """Set the mix key back where an edit changed it: its name (renamed: found by its coordinates), its relative
    key (the basis) and vertex group (none), its slider range (down to 1 at least) and its value 1 (Clear Shape Key
    Weights, a script) unless keyed or driven; True if something was set."""
    key = mesh.shape_keys
    kb, changed = _name_back(mesh, live)
    if kb is None:
        return False
    if kb.relative_key != key.reference_key or kb.vertex_group:
        kb.relative_key, kb.vertex_group = key.reference_key, ""
        changed = True
    if kb.slider_max < 1.0:
        kb.slider_max = 1.0
        changed = True
    if kb.slider_min > 1.0:
        kb.slider_min = 0.0
        changed = True
    if kb.value != 1.0 and not _animated(key, kb):
        kb.value = 1.0
        changed = True
    return changed


def _update_mesh(mesh, depsgraph, force=False, edited=False):
    """Bring the mix key of ``mesh`` up to date with the key values evaluated in ``depsgraph``; True if written.
    ``edited``: the update changed the mesh's data (then, with no key value changed, vertex-group weights may have
    been edited: :meth:`_Live.check` reads them again)."""
    live = _live(mesh)
    if live is None or mesh.is_editmode:
        return False
    if linked_from(mesh):  # nothing can be written: the panel says why
        live.stale = live.check(mesh)
        return False
    if depsgraph is None or depsgraph.mode != 'RENDER':
        _restore_mix_key(mesh, live)
        live.follow_renames(mesh)
    key = mesh.shape_keys
    key_eval = key
    if depsgraph is not None and key is not None:
        try:
            key_eval = key.evaluated_get(depsgraph)
        except (RuntimeError, ReferenceError):  # not in that depsgraph: the values as set
            key_eval = key
    if key_eval is not None:  # an edit that changed no value (a weight painted, a script): read the weights again
        values = [kb.value for kb in key_eval.key_blocks]
        if edited and values == live.values_seen:
            live.weights_edited(mesh)
        live.values_seen = values
    live.stale = live.check(mesh)
    mix_kb = None if key is None else key.key_blocks.get(LIVE_MIX_KEY)
    if mix_kb is None:
        return False

    def write(coords, correction=False):
        """Write ``coords`` into the mix key; ``correction``: they are a mix's (kept to find the key again)."""
        written = _write(mix_kb, coords)
        live.correction = coords if correction else None
        if written and key_eval is not key and depsgraph.mode == 'RENDER':
            _flush_values(key, key_eval)
        return written

    if live.stale:
        live.last = None
        return write(_zero_offset(mix_kb))  # Blender's linear mix, exactly
    w = live.weights(key_eval)
    exact = depsgraph is not None and depsgraph.mode == 'RENDER' and bool(getattr(mesh, EXACT_RENDERS_PROP, False))
    if (not force and live.last is not None and np.array_equal(w, live.last)
            and (live.result.polished or not exact)):
        # the same mix: only an edit of the mix key itself (a script, Edit Mode, sculpting) is written over
        return False if live.correction is None else write(live.correction, correction=True)
    try:
        res = live.mixer.mix(w, polish=exact)
    except Exception as exc:  # never a traceback from a handler: show the linear mix and say why
        live.error = f"the mix failed ({type(exc).__name__}: {exc}): showing the linear mix"
        live.last = None
        return write(_zero_offset(mix_kb))  # Blender's linear mix
    live.error = ""
    live.result, live.last, live.mix_seconds = res, w, float(res.seconds)
    offsets = w @ live.deltas  # Blender's linear sum of the mixer keys, minus the basis
    linear = (live.reference[0] + offsets).reshape(-1, 3)
    placed = rigid_align(np.asarray(res.vertices, np.float64), linear)  # placed like the in-betweens
    return write((placed.ravel() - offsets).astype(np.float32), correction=True)


def update_all(depsgraph=None, force=False, edited=()):
    """Update the mix key of every live mesh (the handlers' work; ``depsgraph`` None: the values as set; ``edited``:
    the names of the meshes whose data the update changed, :func:`_edited_meshes`).

    A render (its own depsgraph, possibly in the render thread) waits for an update running in the main
    thread; the viewport's updates skip while a render's runs (they come again with the next update)."""
    if not (_LIVE or _BROKEN) or _GUARD[0] and threading.current_thread() is threading.main_thread():
        return
    rendering = depsgraph is not None and depsgraph.mode == 'RENDER'
    if not _LOCK.acquire(blocking=rendering):
        return
    _GUARD[0] = True
    try:
        for name in list(_BROKEN):
            mesh = bpy.data.meshes.get(name)
            if mesh is None or MIXER_PROP not in mesh:
                _BROKEN.discard(name)
            elif _zero_mix_key(mesh):
                mesh.shape_keys.update_tag()
        for name in list(_LIVE):
            mesh = bpy.data.meshes.get(name)
            if mesh is None or MIXER_PROP not in mesh:
                _LIVE.pop(name, None)
                continue
            try:
                written = _update_mesh(mesh, depsgraph, force, name in edited)
            except Exception as exc:  # e.g. a linked (read-only) mesh: never a traceback from a handler
                live = _LIVE.get(name)
                if live is not None and not live.error:
                    print(f"Lengths & Angles: live mixing of '{name}' failed: {type(exc).__name__}: {exc}")
                    live.error = f"the mix could not be written ({type(exc).__name__}: {exc})"
                continue
            if written:  # the key (not the whole mesh) is evaluated again with the new coordinates
                mesh.shape_keys.update_tag()
    finally:
        _GUARD[0] = False
        _LOCK.release()


#: Seconds without an edit in Weight Paint mode after which the painted weights are read (:func:`settle_painting`).
PAINT_SETTLE = 0.25


def settle_painting():
    """Have the vertex-group weights read of the live meshes painted in Weight Paint mode whose painting paused for
    :data:`PAINT_SETTLE` seconds: their shape keys are tagged, and the update that follows reads the weights (stale if
    a mixed key's group was painted).  A timer (``bpy.app.timers``, registered by the first edit of a pause); returns
    the seconds until it is due again, None when no painting is pending."""
    now = time.monotonic()
    wait = []
    for name, live in list(_LIVE.items()):  # (a render's thread may drop an entry meanwhile)
        if live.painted_at is None:
            continue
        left = live.painted_at + PAINT_SETTLE - now
        if left > 0:
            wait.append(left)
            continue
        live.painted_at, live.check_masks = None, True
        mesh = bpy.data.meshes.get(name)
        if mesh is not None and mesh.shape_keys is not None:
            mesh.shape_keys.update_tag()
    return min(wait) if wait else None


def _register_updated(depsgraph):
    """Decode the mixers of the live meshes among ``depsgraph``'s updates that are new to the session: appended,
    linked, duplicated (Shift+D copies the mixer too) or made a library override.  A frame change is the first update
    that sees them when nothing else was evaluated in between (``frame_set`` right after the override is made)."""
    if depsgraph is None or depsgraph.mode == 'RENDER':  # (a render's thread: the viewport's updates register)
        return
    for u in depsgraph.updates:
        data = u.id.original
        if isinstance(data, bpy.types.Mesh) and data.name_full not in _LIVE and MIXER_PROP in data:
            _live(data)


def _edited_meshes(depsgraph):
    """Names of the live meshes whose data ``depsgraph``'s update changed (a key value, a vertex-group weight ...): the
    mesh's own geometry update, or in Weight Paint mode its object's (weight tools there may tag the object alone).
    An object's geometry update elsewhere comes from what it depends on (a rig posed, the object moved under an
    Armature modifier), not from an edit of the mesh: every edit of weights outside Weight Paint mode (scripts,
    the vertex-group operators, Data Transfer, leaving Edit Mode) updates the mesh itself."""
    if depsgraph is None or not _LIVE:
        return set()
    out = set()
    for u in depsgraph.updates:
        if not u.is_updated_geometry:
            continue
        data = u.id.original
        if isinstance(data, bpy.types.Object):
            data = data.data if data.mode == 'WEIGHT_PAINT' else None
        if isinstance(data, bpy.types.Mesh):
            out.add(data.name_full)
    return out


@persistent
def _on_depsgraph_update(scene, depsgraph=None):
    _register_updated(depsgraph)
    update_all(depsgraph, edited=_edited_meshes(depsgraph))


@persistent
def _on_frame_change(scene, depsgraph=None):
    _register_updated(depsgraph)
    update_all(depsgraph)


@persistent
def _on_load(*_args):
    _LIVE.clear()
    _BROKEN.clear()
    _MIXERS.clear()
    storage.release_orphans()  # payload texts of meshes deleted before the file was saved
    live_meshes()
    update_all(None)


@persistent
def _on_save(*_args):
    """Name back a mix key renamed and not yet named back by an update (in Edit Mode nothing is updated) before the
    file is written: the correction that finds it under another name is the session's, so in a reopened file only
    its name identifies it.  Likewise the record takes the new names of the user's keys renamed since the last update
    (:meth:`_Live.follow_renames`: the coordinates that find them are the session's), and the keys kept linear are
    stored with their present names and coordinates (:func:`linear_choice` finds them after a later rename)."""
    with _LOCK:
        for name, live in list(_LIVE.items()):
            mesh = bpy.data.meshes.get(name)
            if mesh is not None and not linked_from(mesh):
                _name_back(mesh, live)
                live.follow_renames(mesh)
    for mesh in bpy.data.meshes:  # the keys kept linear under their present names and coordinates
        if LINEAR_KEYS_PROP in mesh and not linked_from(mesh) and not override_from(mesh):
            _store_choice(mesh, linear_choice(mesh))


@persistent
def _on_undo(*_args):
    """Undo / redo restored the meshes (mix key included): forget the session's last mixes."""
    for live in list(_LIVE.values()):
        live.last = None
        live.check_masks = True  # (vertex-group weights restored too)
        live.renames_tried = None  # (keys' coordinates too)
    live_meshes()


_HANDLERS = (("depsgraph_update_post", _on_depsgraph_update), ("frame_change_post", _on_frame_change),
             ("load_post", _on_load), ("save_pre", _on_save), ("undo_post", _on_undo), ("redo_post", _on_undo))


def register_handlers():
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn not in handlers:
            handlers.append(fn)
    try:
        live_meshes()  # the add-on enabled with a file open
    except AttributeError:  # Blender starting (no data yet): load_post follows
        pass


def unregister_handlers():
    if bpy.app.timers.is_registered(settle_painting):
        bpy.app.timers.unregister(settle_painting)
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn in handlers:
            handlers.remove(fn)
    _LIVE.clear()
    _BROKEN.clear()
    _MIXERS.clear()


# ------------------------------------------------------------------------------------------- enable / disable
def _structure(obj, basis, nonlinear):
    """``(groups, relative, masks, relative_to)`` of the mixed keys ``nonlinear`` of ``obj``'s mesh: each key's
    vertex-group name and relative key's name (the record's), the weights Blender applies (K-1, V) and each relative
    key's index in ``[basis, *nonlinear]`` (the mixer's)."""
    blocks = obj.data.shape_keys.key_blocks
    groups = [blocks[n].vertex_group for n in nonlinear]
    relative = [blocks[n].relative_key.name for n in nonlinear]
    order = [basis, *nonlinear]
    masks = vertex_masks(obj.data, _group_indices(obj, groups))
    return groups, relative, masks, np.array([order.index(r) for r in relative], np.int64)


def _inputs(obj, max_keys=0):
    """Validated inputs of a mixer of ``obj`` taking at most ``max_keys`` keys besides the basis (0:
    :attr:`lacore.shapes.MixerOptions.max_keys`): ``(basis, nonlinear, linear, coords (K, V, 3), faces, structure)``
    (:func:`_structure`)."""
    mesh = require_mesh_object(obj)
    _require_local(mesh, "enable live mixing")
    if obj.mode == 'EDIT':
        raise LiveMixError(f"'{obj.name}' is in Edit Mode: switch to Object Mode to enable live mixing")
    _require_not_edited(mesh, "enable")
    if mesh.shape_keys is None:
        raise LiveMixError(f"mesh '{mesh.name}' has no shape keys: add a Basis and at least one key to mix")
    _require_no_user_mix_key(mesh)
    if not mesh.shape_keys.use_relative:
        raise LiveMixError(f"mesh '{mesh.name}': live mixing needs Relative shape keys (check Relative in the "
                           "Shape Keys panel)")
    basis, nonlinear, linear = split_keys(mesh)
    if not nonlinear:
        why = (f" ({', '.join(map(repr, linear[:3]))} are relative to themselves or to a key that is not mixed)"
               if linear else "")
        raise LiveMixError(f"mesh '{mesh.name}' has no shape key to mix besides the basis '{basis}'{why}: add a "
                           "key relative to the basis")
    limit = int(max_keys) or MixerOptions().max_keys
    if len(nonlinear) > limit:
        raise LiveMixError(f"mesh '{mesh.name}' has {len(nonlinear)} shape keys to mix and live mixing mixes at "
                           f"most {limit}: keep {len(nonlinear) - limit} of them linear (small local shapes such as "
                           "faces and correctives) with Keep Linear under Live Mixing, each selected in the key list, "
                           "or raise Most Keys there (each key about doubles the build's time and memory)")
    names, coords = read_shape_keys(mesh)
    triangulation = triangulate(mesh)
    faces = triangulation.faces
    mixed = [basis, *nonlinear]
    mixed_coords = coords[[names.index(n) for n in mixed]]
    try:
        require_nondegenerate_keys(mesh, triangulation, mixed, mixed_coords)  # Blender's face numbers
        keys, _ = check_keys(mixed_coords, faces, names=[f"shape key '{n}'" for n in mixed])
    except MeshError as exc:
        raise topology_error(mesh, "mixed live", exc) from None
    return basis, nonlinear, linear, keys, faces, _structure(obj, basis, nonlinear)


def _require_no_user_mix_key(mesh):
    """:class:`LiveMixError` if a shape key of ``mesh`` live mixing did not make is named :data:`LIVE_MIX_KEY` (its
    coordinates would be written over): checked when Enable starts and again when its build ends."""
    if MIXER_PROP not in mesh and mesh.shape_keys is not None and mesh.shape_keys.key_blocks.get(LIVE_MIX_KEY):
        raise LiveMixError(f"mesh '{mesh.name}' has a shape key named '{LIVE_MIX_KEY}' that live mixing did not make: "
                           "rename it (live mixing writes its correction into a key of that name)")


def enable_run(obj, reduced_size=0, max_keys=0):
    """A :class:`.runs.Run` building the mixer of ``obj``'s keys and making the mesh mix live (validated;
    raises InputError subclasses).  ``reduced_size`` 0: automatic, ``max_keys`` 0: the default
    (:class:`MixerOptions`)."""
    basis, nonlinear, linear, coords, faces, structure = _inputs(obj, max_keys)
    groups, relative, masks, relative_to = structure
    options = MixerOptions(reduced_size=int(reduced_size) or None, max_keys=int(max_keys) or MixerOptions().max_keys)
    extra = {"masks": masks.astype(np.float64), "relative_to": relative_to,
             "names": [f"shape key '{n}'" for n in (basis, *nonlinear)]}
    job = CallJob(lambda progress: ShapeMixer.build(coords, faces, options, progress=progress, **extra), "live mixer",
                  process=(build_mixer_bytes, (coords, faces, options), lambda data: ShapeMixer.load(io.BytesIO(data)),
                           extra))
    t0 = time.perf_counter()
    chosen = linear_choice(obj.data)
    reasons = {n: linear_reason(obj.data.shape_keys.key_blocks[n], obj.data.shape_keys.reference_key, nonlinear,
                                chosen) for n in linear}

    def write(obj, job):
        _require_no_user_mix_key(obj.data)  # (a key given that name during the build)
        if LINEAR_KEYS_PROP in obj.data:  # the choice under the keys' present names and coordinates
            _store_choice(obj.data, linear_choice(obj.data))
        seconds = time.perf_counter() - t0
        store_mixer(obj, job.result, basis, nonlinear, linear, seconds, int(reduced_size), groups, relative)
        return (f"live mixing of {len(nonlinear)} key{'s' if len(nonlinear) != 1 else ''} on '{obj.name}' "
                f"(built in {seconds:.2f} s)"
                + (f"; mixed linearly: {', '.join(f'{n} ({reasons[n]})' for n in linear)}" if linear else ""))
    watch = ObjectWatch(obj, [basis, *nonlinear], {
        f"The vertex-group weights or relative keys of the keys of '{obj.name}'":
            lambda: _structure_digest(obj, basis, nonlinear)})
    return Run(job, watch, write, what="mixer")


def _structure_digest(obj, basis, nonlinear):
    """What :func:`_structure` reads, comparable with ``==`` (the weights by digest)."""
    groups, relative, masks, _ = _structure(obj, basis, nonlinear)
    return groups, relative, hashlib.blake2b(masks.tobytes(), digest_size=16).hexdigest()


def store_mixer(obj, mixer, basis, nonlinear, linear, build_seconds, reduced_size=0, groups=None, relative=None):
    """Store ``mixer`` with ``obj``'s mesh, add the mix key (if missing) and show the mix of the current values.
    ``groups``, ``relative``: the vertex-group name and relative key name of each key of ``nonlinear`` (None: none,
    the basis)."""
    mesh = obj.data
    data = mixer_bytes(mixer)
    coords = _key_coords(mesh.shape_keys, [basis, *nonlinear], len(mesh.vertices))
    record = {"format_version": FORMAT_VERSION, "basis": basis, "keys": list(nonlinear), "linear": list(linear),
              "groups": list(groups or [""] * len(nonlinear)),
              "relative": list(relative or [basis] * len(nonlinear)),
              "n_vertices": len(mesh.vertices), "fingerprint": _digest(coords, _corners(mesh)),
              "build_seconds": float(build_seconds), "reduced_size": int(reduced_size)}
    token = storage.store_payload(mesh, MIXER_PROP, data, header=TEXT_HEADER, name=f"LA live mixer {mesh.name}",
                                  record=record)
    _MIXERS[token] = mixer
    key = mesh.shape_keys
    kb = key.key_blocks.get(LIVE_MIX_KEY)
    if kb is None:
        active = obj.active_shape_key_index
        kb = obj.shape_key_add(name=LIVE_MIX_KEY, from_mix=False)
        obj.active_shape_key_index = active
    kb.relative_key = key.reference_key
    kb.vertex_group = ""
    kb.slider_max = max(kb.slider_max, 1.0)
    kb.value = 1.0
    kb.mute = False
    _LIVE.pop(mesh.name_full, None)
    live = _live(mesh)
    if live is not None:
        with _LOCK:
            _GUARD[0] = True
            try:
                _update_mesh(mesh, None, force=True)
            finally:
                _GUARD[0] = False
    mesh.update()


def disable(obj):
    """Remove the mixer and the mix key of ``obj``'s mesh (Blender's linear mixing again); False if there was
    none.  The user's keys were never changed.  Waits for an update writing the mix key (a render's thread)."""
    mesh = obj.data
    if MIXER_PROP not in mesh:
        return False
    with _LOCK:
        meta = mesh[MIXER_PROP].to_dict()
        del mesh[MIXER_PROP]
        storage.release_payload(meta)
        _LIVE.pop(mesh.name_full, None)
        kb = mesh.shape_keys.key_blocks.get(LIVE_MIX_KEY) if mesh.shape_keys is not None else None
        if kb is not None:
            active = obj.active_shape_key_index
            index = list(mesh.shape_keys.key_blocks).index(kb)
            obj.shape_key_remove(kb)
            obj.active_shape_key_index = max(0, min(active - (active > index), len(mesh.shape_keys.key_blocks) - 1))
    mesh.update()
    return True


def mixer_for_keys(obj, keys):
    """``(mixer, key weights (len(keys), K-1), token, lock)`` of ``obj``'s live mixer for blends of ``keys``.

    The weights of the basis are all zero, those of the mixer's key ``k`` are ``e_k``, so an in-between of keys
    ``A`` and ``B`` at ``t`` is the mix of ``(1 - t) w_A + t w_B``.  Raises :class:`LiveMixError` saying why
    there is no usable mixer: none, unreadable, stale (the mesh or a key edited since the build), a key of
    ``keys`` that it does not mix, or one it mixes limited to a vertex group or relative to another key than the
    basis (its weight 1 is then not the key's shape).
    """
    mesh = require_mesh_object(obj)
    if not is_live(mesh):
        raise LiveMixError(f"mesh '{mesh.name}' has no live mixer (Live Mixing > Enable builds one)")
    live = _live(mesh)
    if live is None:
        raise LiveMixError(f"the live mixer of '{mesh.name}' cannot be read: Rebuild it")
    if not linked_from(mesh):
        live.follow_renames(mesh, write=False)  # (a key renamed since the last update; called in draw too)
    why = live.check(mesh)
    if why:  # (a linked mesh cannot be rebuilt here: ``why`` says to make it local; an override in its library)
        library = override_from(mesh)
        advice = "" if linked_from(mesh) else f": Rebuild it in '{library}'" if library else ": Rebuild it"
        raise LiveMixError(f"the live mixer of '{mesh.name}' is stale ({why}){advice}")
    order = [live.basis, *live.names]
    missing = [k for k in keys if k not in order]
    if missing:
        raise LiveMixError(f"the live mixer of '{mesh.name}' does not mix {', '.join(map(repr, missing))} (it mixes "
                           f"{', '.join(map(repr, live.names))} on the basis '{live.basis}')")
    derived = live.mixer.derived_keys
    for k in keys:
        i = order.index(k) - 1
        if i >= 0 and derived[i]:
            why = (f"is relative to '{live.relative[i]}'" if live.relative[i] != live.basis else
                   f"is limited to the vertex group '{live.groups[i]}'")
            raise LiveMixError(f"shape key '{k}' {why}: the live mixer of '{mesh.name}' mixes what its slider shows, "
                               "not the key's shape")
    eye = np.eye(len(order))[:, 1:]
    return live.mixer, eye[[order.index(k) for k in keys]], live.token, _LOCK


def require_live(obj):
    """The mesh of ``obj`` if it mixes live, else :class:`LiveMixError`."""
    mesh = require_mesh_object(obj)
    if MIXER_PROP not in mesh:
        raise LiveMixError(f"mesh '{mesh.name}' does not mix live: nothing to disable")
    _require_local(mesh, "disable live mixing")
    if obj.mode != 'EDIT':  # (the object's own Edit Mode is left for the change: operators_live_mix)
        _require_not_edited(mesh, "disable")
    return mesh


def _require_local(mesh, what):
    """:class:`LiveMixError` when ``mesh`` or its shape keys are linked from a library, or ``mesh`` is a library
    override (a change would not be saved: the library's keys and mixer come back when the file is opened again)."""
    try:
        require_writable_keys(mesh, what)
    except MeshAccessError as exc:
        raise LiveMixError(str(exc)) from None


def _require_not_edited(mesh, what):
    """:class:`LiveMixError` when ``mesh`` is in Edit Mode through another object sharing it (keys changed now would
    be overwritten from the edit mesh when that object leaves Edit Mode)."""
    if mesh.is_editmode:
        users = ", ".join(repr(o.name) for o in bpy.data.objects if o.data == mesh and o.mode == 'EDIT')
        raise LiveMixError(f"mesh '{mesh.name}' is in Edit Mode through {users or 'another object'}: switch that "
                           f"object to Object Mode to {what} live mixing")
