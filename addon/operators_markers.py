# SPDX-License-Identifier: GPL-3.0-or-later
"""Import motion-capture markers (C3D, TRC) as animated empties, without an armature.

``lengths_angles.import_markers`` (also File > Import > Motion Capture Markers, and
drag and drop of .c3d/.trc files onto the 3D viewport)
reads a take with :mod:`..lacore.markers.io` (positions in metres, NaN where a
marker is occluded) and only then creates, in the active collection:

* one *take empty* named after the file (``PLAIN_AXES``), holding the take's
  metadata in the ID property :data:`TAKE_PROP` (rate, units, source, first
  frame, frame count, labels, the import options used, and ``not_markers``:
  ``[label, reason]`` of the points :func:`..lacore.markers.takes.drop_non_markers`
  finds are not skin markers -- imported like the others, left out by Calibrate & Fit);
* one *marker empty* per label (``SPHERE``), parented to the take empty, its
  label in the ID property :data:`MARKER_PROP`.  Its location is keyed at every
  frame where the marker was seen (LINEAR interpolation), in the take empty's
  space: metres times ``scale``, axes converted from the file's forward/up
  (default C3D's Y forward, Z up, i.e. unchanged) to Blender's.  The world
  position is ``take_empty.matrix_world @ location``.
* Occluded samples get NO location key; the float property ``["visible"]``
  (:data:`VISIBLE_PROP`) of each marker empty is keyed with CONSTANT
  interpolation at the first sample and wherever visibility changes, so its
  F-curve evaluates to 1.0 exactly on the frames with a measured position and
  to 0.0 elsewhere.

Timing: by default the scene's frame rate is set to the take's (``fps`` /
``fps_base``, e.g. 60 / 1.001 for 59.94 Hz), one sample per frame starting at
``frame_start``.  With ``rate_mode='RETIME'`` the scene keeps its rate and
sample ``i`` is keyed at ``frame_start + i * scene_fps / take_rate`` (fractional
frames): every sample is kept, none merged or dropped.  With ``'RESAMPLE'`` the take
is resampled to the scene's rate (:func:`..lacore.markers.takes.resample`: linear in
time; a frame between an occluded and a visible sample is occluded), one key
per frame; the take empty records both the file's rate and frame count and
the keyed ones (``keyed_rate``, ``keyed_samples``).

Keys are written in bulk (``keyframe_points.add`` + ``foreach_set``), never per
frame.  :func:`read_take` reads a take back from the empties' F-curves in bulk (for
fitting: no ``frame_set`` per frame), NaN where ``["visible"]`` is 0, and NaN throughout for a
marker whose location keys are gone (Object > Animation > Clear Keyframes: :func:`unkeyed_markers`,
named by the fitting operators with :func:`unkeyed_note`).  The take's own time per scene frame,
which changing the scene's frame rate later does not change, is :func:`take_frame_rate`.

Several files (``directory`` + ``files``: multi-select in the file browser, or a
drop of several files) are read first and imported together, all or nothing
(:func:`import_takes`); with ``rate_mode='SCENE'`` they must share one rate.

Any error is reported as ERROR with nothing created (objects made before a
failure are removed again).
"""

import os
import time

import bpy
import numpy as np
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper, axis_conversion, orientation_helper

from ..lacore.errors import InputError
from ..lacore.markers.io import MarkerTake, read_markers
from ..lacore.markers.takes import drop_non_markers, resample, sample_frames, visibility_keys
from .compat import ensure_animation_channels, id_fcurves

__all__ = ["LENGTHS_ANGLES_OT_import_markers", "LENGTHS_ANGLES_FH_markers", "classes", "import_take", "import_takes",
           "remove_take", "read_take", "take_frame_rate", "keyed_location", "unkeyed_markers", "unkeyed_note",
           "UNKEYED_REASON",
           "marker_objects", "menu_func_import", "register_menu", "unregister_menu", "TAKE_PROP", "MARKER_PROP",
           "VISIBLE_PROP"]

TAKE_PROP = "lengths_angles_take"
MARKER_PROP = "lengths_angles_marker"
VISIBLE_PROP = "visible"
_NAME_BYTES = 63


def _fcurves_for(obj):
    """The F-curve collection of ``obj``'s assigned action (:func:`..compat.id_fcurves`), or None."""
    return id_fcurves(obj)


_INTERPOLATION = {}


def _interpolation_value(name):
    """Integer value of a keyframe interpolation enum item (for ``foreach_set``)."""
    if name not in _INTERPOLATION:
        items = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items
        _INTERPOLATION[name] = items[name].value
    return _INTERPOLATION[name]


def _write_curve(fcurves, data_path, index, frames, values, interpolation):
    """One F-curve with keys ``(frames[k], values[k])`` written in bulk."""
    fc = fcurves.new(data_path, index=index)
    n = len(frames)
    if n == 0:
        return fc
    kp = fc.keyframe_points
    kp.add(n)
    co = np.empty(2 * n, np.float32)
    co[0::2] = frames
    co[1::2] = values
    kp.foreach_set("co", co)
    # LINEAR/CONSTANT ignore handles; put them on the key so the curve is tidy without fc.update()
    kp.foreach_set("handle_left", co)
    kp.foreach_set("handle_right", co)
    kp.foreach_set("interpolation", np.full(n, _interpolation_value(interpolation), np.int32))
    return fc


def conversion_matrix(axis_forward='Y', axis_up='Z', scale=1.0):
    """(3, 3) float64: file axes -> Blender axes, times ``scale``."""
    rot = axis_conversion(from_forward=axis_forward, from_up=axis_up, to_forward='Y', to_up='Z')
    return np.array(rot, dtype=np.float64) * float(scale)


def _clip_name(name):
    data = name.encode("utf-8")[:_NAME_BYTES]
    return data.decode("utf-8", errors="ignore")


def require_frame_range_start(frame_start, set_frame_range):
    """:class:`InputError` (one line, what to do) for a take keyed from a negative ``frame_start`` when the scene's
    frame range is to be set to it: Blender's scene frame range starts at frame 0 at the earliest (keys and the
    current frame may be negative)."""
    if set_frame_range and frame_start < 0:
        raise InputError(f"Start Frame {frame_start:g} is before frame 0, and a scene's frame range cannot start "
                         f"before 0: turn off Set Frame Range to key the take from frame {frame_start:g} (Blender "
                         "shows negative frames with Preferences > Animation > Allow Negative Frames), or use a "
                         "Start Frame of 0 or more")


def import_take(context, take, name, *, scale=1.0, axis_forward='Y', axis_up='Z', frame_start=1,
                rate_mode='SCENE', set_frame_range=True, marker_size=0.02):
    """Create the take empty and the animated marker empties for ``take`` (a lacore MarkerTake).

    Returns ``(take_object, marker_objects)``.  On any error everything created
    so far is removed before the exception propagates; the scene settings are
    changed only after all objects exist.  A negative ``frame_start`` keys the samples at negative frames;
    with ``set_frame_range`` it is refused (:func:`require_frame_range_start`).
    """
    require_frame_range_start(frame_start, set_frame_range)
    scene = context.scene
    collection = context.collection or scene.collection
    file_rate, file_frames = take.rate, take.n_frames
    if rate_mode == 'SCENE':
        fps = max(1, int(round(take.rate)))
        fps_base = fps / take.rate
        step_rate = None
    elif rate_mode in ('RETIME', 'RESAMPLE'):
        fps, fps_base = scene.render.fps, scene.render.fps_base
        step_rate = fps / fps_base
        if rate_mode == 'RESAMPLE':
            take = resample(take, step_rate)
            step_rate = None
    else:
        raise InputError(f"unknown rate mode {rate_mode!r} (SCENE, RETIME or RESAMPLE)")
    frames = sample_frames(take.n_frames, take.rate, frame_start, step_rate)
    matrix = conversion_matrix(axis_forward, axis_up, scale)
    positions = take.positions @ matrix.T  # (T, M, 3); NaN stays NaN
    visible = take.visible
    vis_keys = visibility_keys(visible)
    # points that are not skin markers (lacore's rules: the file's point groups and descriptions, never seen,
    # computed points) are imported too, and named for Calibrate & Fit, which leaves them out
    not_markers = [[label, reason] for label, reason in drop_non_markers(take).dropped]

    created_objects, created_actions = [], []
    try:
        take_obj = bpy.data.objects.new(_clip_name(name), None)
        created_objects.append(take_obj)
        take_obj.empty_display_type = 'PLAIN_AXES'
        take_obj.empty_display_size = max(10 * marker_size, 1e-3)
        take_obj[TAKE_PROP] = {
            "rate": float(file_rate), "units": take.units, "source": take.source,
            "first_frame": int(take.first_frame), "frame_count": int(file_frames), "labels": list(take.labels),
            "keyed_rate": float(take.rate), "keyed_samples": int(take.n_frames),
            "frame_start": float(frame_start), "frame_step": float(frames[1] - frames[0]) if take.n_frames > 1 else 1.0,
            "rate_mode": rate_mode, "scale": float(scale), "axis_forward": axis_forward, "axis_up": axis_up,
            "visible_samples": int(visible.sum()), "not_markers": not_markers,
        }
        collection.objects.link(take_obj)
        markers = []
        for m, label in enumerate(take.labels):
            obj = bpy.data.objects.new(_clip_name(label), None)
            created_objects.append(obj)
            obj.empty_display_type = 'SPHERE'
            obj.empty_display_size = marker_size
            obj.parent = take_obj
            obj[MARKER_PROP] = label
            obj[VISIBLE_PROP] = 1.0
            obj.id_properties_ui(VISIBLE_PROP).update(
                min=0.0, max=1.0, description="1 on frames where the marker was measured, 0 where it was occluded")
            collection.objects.link(obj)
            # a new object has no action: one is created with a slot for it (compat: 4.2 .. 5.2)
            owner, _created = ensure_animation_channels(obj, _clip_name(f"{obj.name} markers"))
            created_actions.append(obj.animation_data.action)
            fcurves = owner.fcurves
            seen = visible[:, m]
            key_frames = frames[seen]
            if seen.any():
                first = np.flatnonzero(seen)[0]
                obj.location = positions[first, m]
            for axis in range(3):
                _write_curve(fcurves, "location", axis, key_frames, positions[seen, m, axis], 'LINEAR')
            samples, values = vis_keys[m]
            obj[VISIBLE_PROP] = float(values[0])
            _write_curve(fcurves, f'["{VISIBLE_PROP}"]', 0, frames[samples], values, 'CONSTANT')
            markers.append(obj)
    except BaseException:
        for obj in reversed(created_objects):
            bpy.data.objects.remove(obj, do_unlink=True)
        for action in created_actions:
            bpy.data.actions.remove(action)
        raise

    # scene settings last: nothing above can fail any more
    if rate_mode == 'SCENE':
        scene.render.fps, scene.render.fps_base = fps, fps_base
    if set_frame_range:
        scene.frame_start = int(np.floor(frames[0]))
        scene.frame_end = max(int(np.ceil(frames[-1])), scene.frame_start)
    return take_obj, markers


def marker_objects(take_obj, missing_ok=False):
    """``[(label, marker empty)]`` of a take empty, in the order of its ``labels``.

    Raises InputError if ``take_obj`` is not a take empty or (unless ``missing_ok``: the markers whose empties
    are there) a marker's empty is gone.
    """
    meta = take_obj.get(TAKE_PROP) if take_obj is not None else None
    if meta is None:
        name = take_obj.name if take_obj is not None else "None"
        raise InputError(f"'{name}' is not a marker take (no '{TAKE_PROP}' property): import markers first")
    by_label = {c[MARKER_PROP]: c for c in take_obj.children if MARKER_PROP in c}
    labels = list(meta["labels"])
    missing = [lb for lb in labels if lb not in by_label]
    if missing and missing_ok:
        return [(lb, by_label[lb]) for lb in labels if lb in by_label]
    if missing:
        shown = ", ".join(repr(m) for m in missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        what = f"the empties of markers {shown} are" if len(missing) > 1 else f"the empty of marker {shown} is"
        raise InputError(f"take '{take_obj.name}': {what} missing (deleted or unparented): re-import the take")
    return [(lb, by_label[lb]) for lb in labels]


def take_frame_rate(take_obj):
    """Scene frames per second of the take's own time (float): ``keyed_rate * frame_step`` of its metadata.

    Sample ``i`` (``keyed_rate`` samples a second) is keyed at scene frame ``frame_start + i * frame_step``: with
    Set Scene Rate the take's rate (one sample per frame), with Map by Time and Resample the scene's rate at
    import.  The keys stay where they are when the scene's frame rate is changed afterwards, and so does this.
    """
    meta = take_obj[TAKE_PROP]
    return float(meta["keyed_rate"]) * float(meta["frame_step"])


def keyed_location(obj):
    """The three location F-curves of a marker empty, or None when one is gone (its animation cleared: no
    action, or a location channel deleted)."""
    fcurves = _fcurves_for(obj)
    curves = [fcurves.find("location", index=axis) for axis in range(3)] if fcurves is not None else [None]
    return None if any(fc is None for fc in curves) else curves


def unkeyed_markers(take_obj, labels=None):
    """Labels (of ``labels``, default all whose empties are there) of the take's markers without keyed positions
    (:func:`keyed_location`), in a take of more than one sample: :func:`read_take` gives them NaN throughout (a
    marker standing still at its empty's location would corrupt a fit).  A one-sample take is read at the
    empties' locations and has none."""
    if int(take_obj[TAKE_PROP]["keyed_samples"]) < 2:
        return []
    markers = marker_objects(take_obj, missing_ok=True)
    return [lb for lb, obj in markers if (labels is None or lb in labels) and keyed_location(obj) is None]


#: Why a marker without keyed positions (:func:`unkeyed_markers`) is not bound or fitted (the panel's list).
UNKEYED_REASON = "the marker has no keyed positions (its animation was cleared)"


def unkeyed_note(labels):
    """The one-line note naming markers left out for having no keyed positions (:func:`unkeyed_markers`), or
    None if there are none.

    >>> unkeyed_note(["LASI"])
    "marker 'LASI' has no keyed positions (its animation was cleared): left out; re-import the take to restore it"
    """
    if not labels:
        return None
    if len(labels) == 1:
        return (f"marker '{labels[0]}' has no keyed positions (its animation was cleared): left out; re-import the "
                "take to restore it")
    shown = ", ".join(f"'{lb}'" for lb in labels[:5]) + (f" and {len(labels) - 5} more" if len(labels) > 5 else "")
    return (f"{len(labels)} markers have no keyed positions (their animation was cleared): {shown} left out; "
            "re-import the take to restore them")


def _curve_keys(fc):
    n = len(fc.keyframe_points)
    co = np.empty(2 * n, np.float32)
    fc.keyframe_points.foreach_get("co", co)
    return co[0::2], co[1::2]


def _only(fc, interpolation):
    """True if every key of ``fc`` has ``interpolation`` and nothing else shapes the curve."""
    n = len(fc.keyframe_points)
    if n == 0 or len(fc.modifiers) or fc.extrapolation != 'CONSTANT':
        return False
    got = np.empty(n, np.int32)
    fc.keyframe_points.foreach_get("interpolation", got)
    return bool((got == _interpolation_value(interpolation)).all())


def _evaluate_linear(fc, frames):
    """Values of ``fc`` at ``frames``: np.interp on the keys when the curve is plain LINEAR, else evaluate()."""
    if _only(fc, 'LINEAR'):
        kf, kv = _curve_keys(fc)
        return np.interp(frames.astype(np.float32), kf, kv).astype(np.float64)
    return np.array([fc.evaluate(f) for f in frames], np.float64)


def _evaluate_step(fc, frames):
    """Values of a CONSTANT-interpolated ``fc`` at ``frames`` (keys compared in float32, as stored)."""
    if _only(fc, 'CONSTANT'):
        kf, kv = _curve_keys(fc)
        idx = np.searchsorted(kf, frames.astype(np.float32), side="right") - 1
        return kv[np.maximum(idx, 0)].astype(np.float64)
    return np.array([fc.evaluate(f) for f in frames], np.float64)


def read_take(take_obj, frames=None, rate=None, space='WORLD', missing_ok=False):
    """The marker positions of an imported take, read from the empties' F-curves (no ``frame_set``).

    Parameters
    ----------
    take_obj : bpy.types.Object
        A take empty made by :func:`import_take`.
    frames : (F,) array_like of float, optional
        Scene frames to sample; default: the keyed samples (``frame_start + i * frame_step``).
    rate : float, optional
        Rate of the returned take; default: the keyed rate (default frames) or the take's scene frames per
        second (:func:`take_frame_rate`).
    space : {'WORLD', 'LOCAL'}
        World positions (through the take empty's current ``matrix_world``) or the
        empties' own locations in the take empty's space.
    missing_ok : bool
        Read the markers whose empties are there (:func:`marker_objects`), leaving out deleted ones.

    Returns
    -------
    MarkerTake
        positions (F, M, 3) (Blender units), NaN where the keyed ``["visible"]`` is 0, and at every frame for
        a marker without keyed positions in a take of more than one sample (:func:`unkeyed_markers`).
        Plain LINEAR / CONSTANT curves (as imported) are read in bulk; edited curves
        (other interpolation, modifiers) are evaluated key by key, so edits count.
    """
    markers = marker_objects(take_obj, missing_ok)
    meta = take_obj[TAKE_PROP]
    if frames is None:
        frames = meta["frame_start"] + np.arange(int(meta["keyed_samples"])) * meta["frame_step"]
        rate = meta["keyed_rate"] if rate is None else rate
    elif rate is None:
        rate = take_frame_rate(take_obj)
    frames = np.asarray(frames, np.float64).ravel()
    F, M = len(frames), len(markers)
    local = np.full((F, M, 3), np.nan)
    several = int(meta["keyed_samples"]) > 1
    for m, (_label, obj) in enumerate(markers):
        curves = keyed_location(obj)
        if curves is None and several:
            continue  # no keyed positions: never visible (unkeyed_markers)
        if curves is not None and any(len(fc.keyframe_points) == 0 for fc in curves):
            continue  # never seen (imported so), whatever its ["visible"] says
        fcurves = _fcurves_for(obj)
        vis_fc = fcurves.find(f'["{VISIBLE_PROP}"]') if fcurves is not None else None
        seen = (_evaluate_step(vis_fc, frames) >= 0.5) if vis_fc is not None else np.full(F, True)
        for axis in range(3):
            fc = curves[axis] if curves is not None else (
                fcurves.find("location", index=axis) if fcurves is not None else None)
            values = _evaluate_linear(fc, frames) if fc is not None else np.full(F, obj.location[axis])
            local[seen, m, axis] = values[seen]
        if space == 'WORLD':  # the marker's origin: take matrix_world @ matrix_parent_inverse @ location
            mat = np.array(take_obj.matrix_world, np.float64) @ np.array(obj.matrix_parent_inverse, np.float64)
            local[:, m] = local[:, m] @ mat[:3, :3].T + mat[:3, 3]
        elif space != 'LOCAL':
            raise InputError(f"space must be 'WORLD' or 'LOCAL', got {space!r}")
    return MarkerTake(labels=[lb for lb, _ in markers], positions=local, rate=float(rate),
                      first_frame=int(meta["first_frame"]), units=str(meta["units"]), source=str(meta["source"]))


def remove_take(take_obj):
    """Delete a take empty, its marker empties and their actions."""
    for obj in list(take_obj.children):
        action = obj.animation_data.action if obj.animation_data is not None else None
        bpy.data.objects.remove(obj, do_unlink=True)
        if action is not None and action.users == 0:
            bpy.data.actions.remove(action)
    bpy.data.objects.remove(take_obj, do_unlink=True)


def import_takes(context, takes, names, set_frame_range=True, **options):
    """:func:`import_take` for several takes; all or nothing.  The frame range covers them all.

    Returns ``[(take_object, marker_objects)]``.
    """
    require_frame_range_start(options.get("frame_start", 1), set_frame_range)
    made = []
    try:
        for take, name in zip(takes, names, strict=True):
            made.append(import_take(context, take, name, set_frame_range=False, **options))
    except BaseException:
        for take_obj, _ in reversed(made):
            remove_take(take_obj)
        raise
    if set_frame_range:
        scene = context.scene
        firsts, lasts = [], []
        for take_obj, _ in made:
            meta = take_obj[TAKE_PROP]
            firsts.append(meta["frame_start"])
            lasts.append(meta["frame_start"] + (meta["keyed_samples"] - 1) * meta["frame_step"])
        scene.frame_start = int(np.floor(min(firsts)))
        scene.frame_end = max(int(np.ceil(max(lasts))), scene.frame_start)
    return made


@orientation_helper(axis_forward='Y', axis_up='Z')
class LENGTHS_ANGLES_OT_import_markers(bpy.types.Operator, ImportHelper):
    """Import motion-capture markers (C3D or TRC) as animated empties parented to one take empty;
    occluded samples are left unkeyed and recorded in each empty's keyed "visible" property"""

    bl_idname = "lengths_angles.import_markers"
    bl_label = "Import Motion Capture Markers"
    bl_description = ("Import motion-capture markers (C3D or TRC) as animated empties parented to one take empty; "
                      "occluded samples stay unkeyed")
    bl_options = {'REGISTER', 'UNDO'}

    filename_ext = ".c3d"
    filter_glob: StringProperty(default="*.c3d;*.trc", options={'HIDDEN'})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement, options={'HIDDEN', 'SKIP_SAVE'})
    directory: StringProperty(subtype='DIR_PATH', options={'HIDDEN', 'SKIP_SAVE'})

    scale: FloatProperty(name="Scale", description="Multiply the positions (in metres) by this factor (default: "
                         "metres in the scene's unit scale, 1 / Unit Scale)",
                         default=1.0, min=1e-6, max=1e6, soft_min=1e-3, soft_max=1e3)
    frame_start: IntProperty(name="Start Frame", default=1,
                             description="Frame of the take's first sample (negative: only without Set Frame Range, "
                                         "a scene's frame range starts at 0 at the earliest)")
    rate_mode: EnumProperty(
        name="Frame Rate", description="How the take's samples map to the scene's frames",
        items=[('SCENE', "Set Scene Rate", "Set the scene's frame rate to the take's: one sample per frame"),
               ('RETIME', "Map by Time", "Keep the scene's frame rate; key every sample at its time "
                                         "(fractional frames, no sample dropped)"),
               ('RESAMPLE', "Resample", "Keep the scene's frame rate; resample the take to it (linear in time, "
                                        "one key per frame; a frame next to an occluded sample stays occluded)")],
        default='SCENE')
    set_frame_range: BoolProperty(name="Set Frame Range", description="Set the scene's start and end frames "
                                  "to the take's", default=True)
    marker_size: FloatProperty(name="Marker Size", description="Display size of the marker empties",
                               default=0.02, min=1e-5, soft_max=1.0, subtype='DISTANCE')

    def invoke(self, context, event):
        # a file dropped on the viewport (LENGTHS_ANGLES_FH_markers) comes with its path: show the options;
        # otherwise the file browser
        self.scale = self.metres_scale(context)
        return self.invoke_popup(context)

    def metres_scale(self, context):
        """``scale`` as set, else metres in the scene's units: ``1 / scale_length`` (a centimetre scene, Unit
        Scale 0.01: 100)."""
        if self.properties.is_property_set("scale"):
            return self.scale
        return 1.0 / (context.scene.unit_settings.scale_length or 1.0)

    def paths(self):
        """The selected files (several from the file browser or a drop), else ``filepath``."""
        names = [f.name for f in self.files if f.name]
        if names and self.directory:
            return [os.path.join(bpy.path.abspath(self.directory), n) for n in names]
        return [bpy.path.abspath(self.filepath)]

    def execute(self, context):
        start = time.perf_counter()
        paths = self.paths()
        try:
            if self.axis_forward[-1] == self.axis_up[-1]:
                raise InputError(f"Forward ({self.axis_forward}) and Up ({self.axis_up}) must be different axes")
            require_frame_range_start(self.frame_start, self.set_frame_range)  # before reading the files
            takes = [read_markers(p) for p in paths]  # every file read before anything is created
            rates = sorted({t.rate for t in takes})
            if self.rate_mode == 'SCENE' and len(rates) > 1:
                raise InputError(f"The takes have different rates ({', '.join(f'{r:g}' for r in rates)} Hz) and the "
                                 "scene has one: import them one by one, or choose Map by Time or Resample")
            made = import_takes(context, takes, [os.path.splitext(os.path.basename(p))[0] or "Take" for p in paths],
                                scale=self.metres_scale(context), axis_forward=self.axis_forward, axis_up=self.axis_up,
                                frame_start=self.frame_start, rate_mode=self.rate_mode,
                                set_frame_range=self.set_frame_range, marker_size=self.marker_size)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        if context.mode != 'OBJECT' and bpy.ops.object.mode_set.poll():  # as Blender's importers: the active
            bpy.ops.object.mode_set(mode='OBJECT')  # object leaves Edit (or Pose) Mode before the take becomes active
        for obj in context.view_layer.objects.selected:
            obj.select_set(False)
        for take_obj, _markers in made:
            take_obj.select_set(True)
        context.view_layer.objects.active = made[0][0]
        seconds = time.perf_counter() - start
        if len(takes) > 1:
            self.report({'INFO'}, f"Imported {len(takes)} takes ({sum(len(m) for _, m in made)} markers) "
                                  f"in {seconds:.2f} s")
            return {'FINISHED'}
        take, (take_obj, markers) = takes[0], made[0]
        occluded = take.n_frames * take.n_markers - int(take.visible.sum())
        meta = take_obj[TAKE_PROP]
        resampled = (f", resampled to {meta['keyed_samples']} frames at {meta['keyed_rate']:g} fps"
                     if self.rate_mode == 'RESAMPLE' else "")
        self.report({'INFO'}, f"Imported {len(markers)} markers x {take.n_frames} frames at {take.rate:g} Hz from "
                              f"'{os.path.basename(paths[0])}' ({occluded} occluded samples{resampled}, "
                              f"{seconds:.2f} s)")
        return {'FINISHED'}


def _describe(cls, name, description):
    """Give the property ``name`` that a decorator added to ``cls`` (Blender's axis pickers) a tooltip."""
    prop = cls.__annotations__[name]
    cls.__annotations__[name] = prop.function(**{**prop.keywords, "description": description})


_describe(LENGTHS_ANGLES_OT_import_markers, "axis_forward", "Axis of the file that points forward in Blender (C3D: "
          "usually Y)")
_describe(LENGTHS_ANGLES_OT_import_markers, "axis_up", "Axis of the file that points up in Blender (C3D: usually Z; "
          "some labs record Y up)")


class LENGTHS_ANGLES_FH_markers(bpy.types.FileHandler):
    """Drag and drop of .c3d / .trc files onto the 3D viewport or the outliner imports markers."""

    bl_idname = "LENGTHS_ANGLES_FH_markers"
    bl_label = "Motion Capture Markers (Lengths & Angles)"
    bl_import_operator = "lengths_angles.import_markers"
    bl_file_extensions = ".c3d;.trc"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type in {'VIEW_3D', 'OUTLINER'}


def menu_func_import(self, context):
    self.layout.operator(LENGTHS_ANGLES_OT_import_markers.bl_idname,
                         text="Motion Capture Markers (.c3d, .trc) [Lengths & Angles]")


def register_menu():
    bpy.types.TOPBAR_MT_file_import.append(menu_func_import)


def unregister_menu():
    bpy.types.TOPBAR_MT_file_import.remove(menu_func_import)


classes = (LENGTHS_ANGLES_OT_import_markers, LENGTHS_ANGLES_FH_markers)
