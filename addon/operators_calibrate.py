# SPDX-License-Identifier: GPL-3.0-or-later
"""Calibrate & Fit: from an imported marker take and a character to a played-back fit in one run (glue only).

``lengths_angles.calibrate_fit`` ("Calibrate & Fit") works on the active mesh object (the character:
a stored shape model, or pose shape keys to build one from) and the selected take (its take empty or
some of its marker empties; with none selected, the scene's only take).  One :class:`.runs.Run`
(modal with a progress bar and Esc from the UI, synchronous from scripts):

1. *Build Model* when the mesh has none (:meth:`lacore.models.ShapeModel.fit` on its shape keys);
2. *calibrate* (:func:`lacore.markers.calibrate` inside :func:`lacore.markers.fit_take`): placement and
   up axis, units, the performer's size, the starting pose and the binding of every marker where it is
   visible; points that are not markers are dropped (:func:`lacore.markers.drop_non_markers`), markers whose
   empties were deleted or whose animation was cleared (:func:`.operators_markers.unkeyed_markers`) left out,
   each noted;
3. *fit* every frame of the range (:func:`lacore.markers.fit_take`).

Placement (the object's Placement option, :mod:`.operators_pins`): standard marker-set names place a humanoid
(Automatic); a take without them is placed by the markers pinned to vertices (3 or more), else by the
character's transform as the user placed it over the markers at the take's first frame (As Placed: the
rest mesh in the character's space is the placement, ``x = metres_per_unit * X``).

Units and axes: the markers are handed to lacore in the character's object space, in metres
(:func:`.operators_fit.metres_per_unit`: the take's import Scale, else the scene's Unit Scale), and the
model declares that unit (``length_unit``) and the object-space direction of the world's up (+Z) axis (a
humanoid placed by marker names may face any way about it: lacore finds its forward; a character placed by
pins or as placed also declares the world's forward, -Y), so a take imported at the wrong scale or with the
wrong up axis is refused with lacore's one-line error instead of giving a crumpled fit.  The fitted poses come
back in object space: they are written as a PC2 point cache played by the Mesh Cache modifier
:data:`.naming.FIT_MODIFIER` (as Fit to Markers does), with the model (when built), the calibrated binding
and the fit's quality (:func:`.fit_quality.write_quality`: per-frame marker RMS curve, RMS / p95 in mm, prior
weight, flagged frames and markers).  A failed or cancelled run writes nothing.

The calibration is stored with the result (a payload of the mesh, :data:`CALIBRATION_PROP`, keyed by
:func:`calibration_key`: the take's markers as the run reads them in the character's space, the stored
model, the unit, axes, placement, pins and the fit's settings).  Calibrate & Fit again with all of them
unchanged reuses it and only fits (the report and the panel say so); any change calibrates afresh.
"""

import copy
import dataclasses
import hashlib
import io

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from ..lacore.errors import InputError
from ..lacore.markers.io import MarkerTake
from .compat import BLEND_RELATIVE_PATH
from .fit_quality import FIT_PROP, write_quality
from .jobs import CallJob
from .mesh_access import require_kept, require_mesh_object, triangulate, world_to_object
from .operators_fit import (BINDING_PROP, MODEL_PROP, FitSettings, FitSetupError, _build_model, _model_inputs,
                            _pc2_path, _prop_state, _store_built_model, _take_of, _take_state, _write_fit,
                            draw_fit_settings, draw_frame_range, fit_settings, marker_locations, metres_per_unit,
                            nonuniform_scale_note, read_model, recorded_settings, require_frame_range,
                            require_still, typed)
from .operators_markers import (TAKE_PROP, UNKEYED_REASON, marker_objects, read_take, take_frame_rate, unkeyed_markers,
                                unkeyed_note)
from .operators_pins import PLACEMENT_PROP, pins_of
from .runs import ObjectWatch, Run, RunOperator
from .storage import PayloadError, load_payload, payload_header, release_payload, saved_bytes, store_payload

__all__ = ["calibrate_fit_run", "find_take", "character", "object_axes", "fit_defaults", "classes",
           "CALIBRATION_PROP", "calibration_key", "stored_calibration", "remove_calibration"]

#: The mesh's record of the last Calibrate & Fit's calibration (a payload: :func:`.storage.store_payload`).
CALIBRATION_PROP = "lengths_angles_calibration"
CALIBRATION_HEADER = payload_header("Lengths & Angles calibration (do not edit)")


def _fitting_api():
    """lacore's calibration and fitting (imported on use)."""
    from ..lacore.markers import FIT_DEFAULTS, calibrate, drop_non_markers, fit_take, model_pins
    return FIT_DEFAULTS, drop_non_markers, (calibrate, fit_take, model_pins)


def fit_defaults():
    """lacore's fitting defaults (one source of truth for the operator's defaults), or None without them."""
    try:
        return _fitting_api()[0]
    except ImportError:
        return None


def find_take(context):
    """The take to calibrate on: the selected one (:func:`.operators_fit._take_of`), else the scene's only take."""
    selected = list(context.selected_objects or [])
    if any(TAKE_PROP in o or "lengths_angles_marker" in o for o in selected):
        return _take_of(selected)[0]
    takes = [o for o in context.scene.objects if TAKE_PROP in o]
    if len(takes) != 1:
        raise FitSetupError(f"select the marker take to fit (its take empty or some marker empties): the scene has "
                            f"{len(takes)} takes" if takes else "the scene has no marker take: import one first "
                            "(File > Import > Motion Capture Markers)")
    return takes[0]


def character(context):
    """The character: the active object if it is a mesh, else the only selected mesh."""
    obj = context.active_object
    if obj is not None and obj.type == 'MESH':
        return obj
    meshes = [o for o in (context.selected_objects or []) if o.type == 'MESH']
    if len(meshes) != 1:
        raise FitSetupError("select the character (a mesh with a shape model or pose shape keys) and make it active")
    return meshes[0]


def _axis_name(v):
    """``"x"``, ``"-y"`` ... for a unit vector along an axis, None otherwise."""
    i = int(np.argmax(np.abs(v)))
    if abs(abs(v[i]) - 1.0) > 1e-3:
        return None
    return ("" if v[i] > 0 else "-") + "xyz"[i]


def _nearest_axes(obj):
    """``(up, forward)`` like :func:`object_axes`, rounded to the object-space axes nearest to the world's."""
    R = np.array(obj.matrix_world, np.float64)[:3, :3]
    inv = world_to_object(obj)[:3, :3] * np.cbrt(abs(np.linalg.det(R)))
    up, fwd = inv @ [0.0, 0.0, 1.0], inv @ [0.0, -1.0, 0.0]
    i = int(np.argmax(np.abs(up)))
    fwd[i] = 0.0
    j = int(np.argmax(np.abs(fwd)))
    return (("" if up[i] > 0 else "-") + "xyz"[i]), (("" if fwd[j] > 0 else "-") + "xyz"[j])


def object_axes(obj):
    """``(up, forward)`` of the world (+Z up, -Y forward: Blender's front view) in ``obj``'s space, as lacore's
    axis names (``"z"``, ``"-y"`` ...), None where the object is rotated off the axes."""
    R = np.array(obj.matrix_world, np.float64)[:3, :3]
    inv = world_to_object(obj)[:3, :3] * np.cbrt(abs(np.linalg.det(R)))
    return _axis_name(inv @ [0.0, 0.0, 1.0]), _axis_name(inv @ [0.0, -1.0, 0.0])


#: Advice for a unit mismatch, with the import Scale to use.
_UNIT_ADVICE = ("the markers and the character differ that much in size as they stand in the scene: import the take "
                "again with {scale} (Import Motion Capture Markers > Scale) or scale the character")

#: What to do in Blender about lacore's unit and axis mismatches (their own advice is for scripts).
_ADVICE = {
    "UnitMismatchError": _UNIT_ADVICE.format(scale="a Scale that matches the character"),
    "AxisMismatchError": "the character does not stand up along the scene's Z axis: rotate it upright, or import "
                         "the take again with its Up axis (Import Motion Capture Markers > Up)",
    "CalibrationError": "pin 3 or more markers seen at the take's first frames to vertices (Edit Mode: Pin Marker), "
                        "or place the character over the markers at the take's first frame and set Placement to As "
                        "Placed",
}


def import_scale_for(scale, ratio):
    """The import Scale (a power of ten) that brings a performer measuring ``ratio`` times the character at the
    take's import ``scale`` to about its size, or None if none differs from ``scale``.

    >>> import_scale_for(1.0, 0.0095), import_scale_for(10.0, 9.53), import_scale_for(1.0, 1.7)
    (100.0, 1.0, None)
    """
    if not (scale and ratio and scale > 0 and ratio > 0):
        return None
    suggested = float(10.0 ** np.round(np.log10(scale / ratio)))
    return None if abs(np.log10(suggested / scale)) < 0.5 else suggested


def _in_blender_terms(exc, import_scale=None):
    """lacore's unit and axis mismatch errors with advice for Blender (one line); other errors as they are.
    ``import_scale``: the take's import Scale (a unit mismatch names the Scale that fits)."""
    advice = _ADVICE.get(type(exc).__name__)
    if advice is None:
        return exc
    suggested = import_scale_for(import_scale, getattr(exc, "ratio", None))
    if suggested is not None:
        advice = _UNIT_ADVICE.format(scale=f"Scale {suggested:g} instead of {import_scale:g}")
    head = str(exc).split(": check")[0].split(": give pins")[0].split(";")[0]
    return FitSetupError(f"{head}: {advice}")


def has_hints(labels):
    """Whether any of ``labels`` is a standard marker-set name that places a humanoid."""
    from ..lacore.markers.marker_sets import match_label
    return any(match_label(lb) is not None for lb in labels)


def first_calibration_frame(visible):
    """Index of the first frame lacore's calibration places the model at: the first with >= 80 % of the most
    markers seen in one frame (:func:`lacore.markers.calibrate`)."""
    counts = np.asarray(visible).sum(1)
    return int(np.flatnonzero(counts >= 0.8 * counts.max())[0])


#: Largest median distance of the markers from the character's surface, in its bounding-box diagonals, for
#: the character to count as placed over them (As Placed).
MAX_PLACED_DISTANCE = 0.2


def _placement(obj, markers, labels, pins, mode, rest, frame_of, left_out=None):
    """How to place the character: ``(kind, pins)`` with kind ``'HINTS'`` (lacore, by marker names),
    ``'PINS'`` or ``'PLACED'`` (:data:`.operators_pins.PLACEMENT_ITEMS`), and the pins as
    ``{label: vertex}`` (validated: one-line FitSetupError naming what to do).  ``left_out``: ``{label: why}`` of
    the take's markers left out before (empty deleted, animation cleared)."""
    pinned = {}
    for label, v in pins.items():
        gone = (left_out or {}).get(label)
        if gone is not None:
            raise FitSetupError(f"pin '{label}' of '{obj.name}': {gone}, so it is left out: remove the pin (Pins in "
                                "the Lengths & Angles: Model and Markers panel) or re-import the take")
        if label not in markers.labels:
            why = "is not a marker (left out)" if label in labels else "is not a marker of the take"
            raise FitSetupError(f"pin '{label}' of '{obj.name}' {why}: remove it (Pins in the Lengths & Angles: "
                                "Model and Markers panel) or pin a marker of the take")
        if not 0 <= v < len(rest):
            raise FitSetupError(f"pin '{label}': '{obj.name}' has no vertex {v} (it has {len(rest)}): pin it again")
        pinned[label] = int(v)
    if mode == 'PLACED':
        return 'PLACED', pinned
    if has_hints(markers.labels):
        return 'HINTS', pinned
    if len(pinned) < 3:
        return 'PLACED', pinned
    f0 = first_calibration_frame(markers.visible)
    seen = [lb for lb in pinned if markers.visible[f0, markers.labels.index(lb)]]
    if len(seen) < 3:
        raise FitSetupError(f"{len(seen)} of the {len(pinned)} pinned markers are seen at frame {frame_of(f0)}, "
                            "where the character is placed: pin 3 or more markers seen there (Edit Mode: Pin "
                            "Marker), or place the character over the markers and set Placement to As Placed")
    return 'PINS', pinned


def _check_placed(X, faces, markers, unit, take_name, frame_of):
    """FitSetupError unless the markers at the first calibration frame lie near the rest mesh ``X`` as placed."""
    from ..lacore.markers.binding import closest_surface_points
    f0 = first_calibration_frame(markers.visible)
    x = markers.positions[f0][markers.visible[f0]] / unit
    q = closest_surface_points(X, faces, x)[0]
    d = float(np.median(np.linalg.norm(q - x, axis=1)))
    diag = float(np.linalg.norm(np.ptp(X, axis=0)))
    if d > MAX_PLACED_DISTANCE * diag:
        named = has_hints(markers.labels)
        why = "Placement is As Placed" if named else "the take has no standard marker names"
        other = ("or set Placement to Automatic (the take's standard marker names place it)" if named
                 else "or pin 3 or more markers to vertices (Edit Mode: Pin Marker)")
        raise FitSetupError(
            f"{why} and the character is not over the markers of '{take_name}' at frame {frame_of(f0)} (median "
            f"distance {d * unit:.3g} m, {d / diag:.0%} of its size): move, rotate and scale it over the markers "
            f"there, {other}")


def calibrate_fit_run(context, obj, take, frame_start, frame_end, prior_weight=None, auto_prior=None,
                      temporal_weight=None, filepath="", placement=None, observed_radius=None,
                      penetration_weight=None, coefficient_weight=None):
    """A :class:`.runs.Run` building the model if needed, calibrating and fitting the frame range of ``take`` to
    the character ``obj`` and writing the result (validated; raises InputError subclasses).

    ``prior_weight``, ``auto_prior`` (the weight chosen per take by lacore), ``temporal_weight``,
    ``observed_radius`` (``(r1, r2)``, or 0 for the modes everywhere: :func:`.operators_fit.fit_settings`),
    ``penetration_weight`` and ``coefficient_weight`` default to lacore's :data:`FIT_DEFAULTS` (None); the settings
    used are stored with the fit's quality.  ``placement`` (``'AUTO'`` or ``'PLACED'``) defaults to the object's
    Placement option.
    """
    try:
        defaults, drop_non_markers, (calibrate, fit_take, model_pins) = _fitting_api()
    except ImportError as exc:
        raise FitSetupError(f"this build of Lengths & Angles has no marker calibration ({exc})") from exc
    options = fit_settings(defaults, allow_auto=True, prior_weight="auto" if auto_prior else prior_weight,
                           temporal_weight=temporal_weight, observed_radius=observed_radius,
                           penetration_weight=penetration_weight, coefficient_weight=coefficient_weight)
    if auto_prior is False and prior_weight is None and options.prior_weight == "auto":
        raise FitSetupError("give a prior weight (or use the automatic one)")
    mesh = require_mesh_object(obj)
    require_kept([obj, mesh], "calibrate and fit")  # the binding, the calibration and the fit's quality
    built = None
    if MODEL_PROP in mesh:
        model = read_model(obj)
    else:
        try:
            built = _model_inputs(obj)
        except InputError as exc:
            raise FitSetupError(f"'{obj.name}' has no shape model and cannot build one ({exc}): add pose shape "
                                "keys or run Build Model") from exc
        model = None
    frame_start, frame_end = require_frame_range(frame_start, frame_end)
    meta = take[TAKE_PROP]
    import_scale = float(meta.get("scale", 0.0))
    first = float(meta["frame_start"])
    last = first + (int(meta["keyed_samples"]) - 1) * float(meta["frame_step"])
    start, end = max(int(frame_start), int(np.ceil(first - 1e-6))), min(int(frame_end), int(np.floor(last + 1e-6)))
    if end < start:
        raise FitSetupError(f"take '{take.name}' covers frames {first:g}..{last:g}, outside the range "
                            f"{int(frame_start)}..{int(frame_end)}: set the frame range inside the take")
    frames = np.arange(start, end + 1)
    require_still(take, obj)
    take_name = take.name
    filepath, path = _pc2_path(filepath, obj, take)
    # left out: markers whose empties were deleted, and those whose animation was cleared (no keyed positions)
    unkeyed = unkeyed_markers(take)
    empties = {lb: o.name for lb, o in marker_objects(take, missing_ok=True) if lb not in unkeyed}
    labels = list(empties)
    deleted = [str(lb) for lb in meta["labels"] if lb not in labels and lb not in unkeyed]
    if not labels:
        raise FitSetupError(f"take '{take.name}' has no marker with keyed positions left (empties deleted or their "
                            "animation cleared): re-import the take")
    read = read_take(take, frames=frames, missing_ok=True)
    world = read.positions[:, [read.labels.index(lb) for lb in labels]]
    inv = world_to_object(obj)
    unit = metres_per_unit(obj, take, context.scene)
    local = world @ inv[:3, :3].T + inv[:3, 3]
    rate = take_frame_rate(take)  # one sample per scene frame, in the take's time
    not_markers = {str(lb): str(why) for lb, why in meta.get("not_markers", [])}
    keep = [m for m, lb in enumerate(labels) if lb not in not_markers]
    markers = drop_non_markers(MarkerTake(labels=tuple(labels[m] for m in keep), positions=local[:, keep] * unit,
                                          rate=rate, units="m", dropped=tuple(not_markers.items())))
    mode = placement or getattr(obj, PLACEMENT_PROP, 'AUTO')
    pins = pins_of(obj)
    rest = (mesh.shape_keys.reference_key.data if mesh.shape_keys else mesh.vertices)
    co = np.empty(3 * len(rest), np.float32)
    rest.foreach_get("co", co)
    rest = co.reshape(-1, 3).astype(np.float64)
    left_out = {**dict.fromkeys(deleted, "the marker's empty was deleted"), **dict.fromkeys(unkeyed, UNKEYED_REASON)}
    kind, pinned = _placement(obj, markers, labels, pins, mode, rest, lambda f: int(frames[f]), left_out)
    if kind == 'PLACED':
        _check_placed(rest, triangulate(mesh).faces, markers, unit, take.name, lambda f: int(frames[f]))
    # the world's up in the character's space: exact (checked by lacore) for a humanoid placed by marker names,
    # whose forward lacore finds (the character may face any way about the up axis), else the nearest axes of
    # the world's up and forward (the user placed or pinned the character)
    up, forward = (object_axes(obj)[0], None) if kind == 'HINTS' else _nearest_axes(obj)
    markers = dataclasses.replace(markers, up_axis=None if up is None else ("" if up.startswith("-") else "+") + up)
    pin_vertices = dict(pinned)

    def key_of(token):
        return calibration_key(str(token), markers, unit, up, forward, kind, pin_vertices, options)
    reused = None if built is not None else stored_calibration(mesh, key_of(mesh[MODEL_PROP].get("token", "")))

    stages = 1 + (built is not None) + (reused is None)   # build model, calibrate (unless reused), fit

    def compute(progress):
        scale = 1000

        def staged(stage):
            def report(done, total, message=""):
                return progress(stage * scale + int(scale * min(done, total) / max(total, 1)), stages * scale,
                                message)
            return report
        m = model
        if built is not None:
            m = _build_model(built, staged(0))
        fitted = copy.copy(m)  # the unit and axes of this scene, not stored with the model
        fitted.length_unit, fitted.up_axis, fitted.forward_axis = unit, up, forward
        # pins on the model's vertices: the same on the mesh, the coarse vertex that absorbed it on a coarse level
        on_model = model_pins(m, pin_vertices)
        # As Placed: the rest mesh in the character's space, in metres
        where = (unit, np.eye(3), np.zeros(3)) if kind == 'PLACED' else None
        try:
            cal = reused
            if cal is None:
                cal = calibrate(fitted, markers, fit=options, placement=where, pins=on_model or None,
                                progress=staged(stages - 2))
            result = fit_take(fitted, markers, cal, options=options, progress=staged(stages - 1))
        except InputError as exc:
            raise _in_blender_terms(exc, import_scale) from exc
        return m, result

    job = CallJob(compute, "calibrate & fit", total=1000 * stages)
    note = nonuniform_scale_note(obj)

    def write(obj, job):
        m, res = job.result
        X = res.fine_vertices if getattr(res, "fine_vertices", None) is not None else res.vertices
        text = _write_fit(obj, np.asarray(X, np.float64), frames, 'PC2', filepath, path)
        if built is not None:
            _store_built_model(obj, m, built["keys"])
        cal, b = res.calibration, res.binding
        if reused is None:
            _store_calibration(obj.data, cal, key_of(obj.data[MODEL_PROP].get("token", "")))
        bound = list(res.labels)
        dropped = list(getattr(markers, "dropped", ()))     # points that are not markers, with why
        not_marker = dict(dropped)
        not_bound = [lb for lb in labels if lb not in bound] + list(left_out)   # left out: deleted, no keys
        obj[BINDING_PROP] = {
            "take": take_name, "labels": bound, "empties": [empties[lb] for lb in bound],
            "frame": int(frames[0]), "calibrated": True,
            "faces": b.faces.tolist(), "barycentric": b.barycentric.ravel().tolist(), "offsets": b.offsets.tolist(),
            "n_vertices": len(obj.data.vertices), **marker_locations(obj, m, b),
            "metres_per_unit": unit, "warn_distance": 0.05, "not_bound": not_bound,
            "not_bound_reasons": [left_out.get(lb) or not_marker.get(lb, "left out by the calibration: see its report")
                                  for lb in not_bound],
            "performer_ratio": float(cal.performer_ratio),
        }
        quality = write_quality(obj, frames, res, bound, unit, take_name, recorded_settings(options))
        obj[FIT_PROP]["calibration_reused"] = reused is not None
        if note is not None:
            job.notes.append(note)
        if deleted:
            shown = ", ".join(deleted[:5]) + (" ..." if len(deleted) > 5 else "")
            job.notes.append(f"the empty of marker {shown} was deleted: left out" if len(deleted) == 1 else
                             f"the empties of {len(deleted)} markers were deleted, left out: {shown}")
        if unkeyed:
            job.notes.append(unkeyed_note(unkeyed))
        if dropped:
            job.notes.append(f"{len(dropped)} points are not markers and were left out: "
                             + ", ".join(f"{lb} ({why})" for lb, why in dropped[:5])
                             + (" ..." if len(dropped) > 5 else ""))
        job.notes.extend(quality["notes"])
        # the calibration's own notes, but its drops once (summarized above)
        # (the axes and unit lacore infers are no news in Blender, and its advice to declare them is lacore's)
        job.notes.extend(str(n) for n in getattr(cal, "notes", [])
                         if not str(n).startswith(("dropped ", "model forward axis inferred", "model axes inferred",
                                                   "model unit not declared")))
        placed = {'HINTS': "", 'PINS': f" by {len(pinned)} pins", 'PLACED': " as placed"}[kind]
        how = ("reused the stored calibration (take, model and placement unchanged)" if reused is not None
               else f"calibrated{placed}")
        return (f"{how} (performer {cal.performer_ratio:.2f}x the character) and {text}; "
                f"{quality['text']}")
    extras = {f"The take '{take_name}' or its marker empties": _take_state(take_name),
              f"The shape model of '{obj.name}'": _prop_state(obj.name, MODEL_PROP, on_mesh=True),
              f"The placement and pins of '{obj.name}'": _placement_state(obj.name)}
    keys = [built["names"][0], *built["keys"]] if built is not None else []
    return Run(job, ObjectWatch(obj, keys, extras), write, what="fitted frame")


def calibration_key(model_token, markers, unit, up, forward, kind, pins, options):
    """Digest of everything a calibration depends on: the stored model (its token), the markers (labels and
    positions in the character's space, metres), the unit, the axes, the placement kind and pins, and the
    fit's settings the calibration uses (all but the temporal ones, which only the fit of the frames uses)
    and the calibration's (lacore's defaults included: a new version calibrates afresh)."""
    from ..lacore.markers.calibration import CALIBRATION_DEFAULTS
    used = dataclasses.replace(options, temporal_weight=0.0, reference_rate=1.0, temporal_tolerance=None)
    h = hashlib.blake2b(digest_size=16)
    for part in (model_token, markers.labels, f"{unit!r}", up, forward, kind, sorted(pins.items()), repr(used),
                 repr(CALIBRATION_DEFAULTS), markers.positions.shape):
        h.update(repr(part).encode())
        h.update(b"\0")
    h.update(np.ascontiguousarray(markers.positions, np.float64).tobytes())
    return h.hexdigest()


def stored_calibration(mesh, key):
    """The calibration stored with ``mesh`` by the last Calibrate & Fit if its key is ``key`` (``seconds`` 0: none
    spent now), else None."""
    from ..lacore.markers import Calibration
    record = mesh.get(CALIBRATION_PROP)
    if record is None or str(record.get("key", "")) != key:
        return None
    try:
        cal = Calibration.load(io.BytesIO(load_payload(record, CALIBRATION_HEADER)))
    except (PayloadError, InputError):
        return None
    return dataclasses.replace(cal, seconds=0.0)   # no time spent calibrating in this run


def _store_calibration(mesh, cal, key):
    data = saved_bytes(cal.save, "calibration.npz")
    store_payload(mesh, CALIBRATION_PROP, data, header=CALIBRATION_HEADER, name=f"LA calibration {mesh.name}",
                  record={"key": key})


def remove_calibration(mesh):
    """Remove the calibration stored with ``mesh``; True if there was one."""
    record = mesh.get(CALIBRATION_PROP)
    if record is None:
        return False
    record = record.to_dict()
    del mesh[CALIBRATION_PROP]
    release_payload(record)
    return True


def _placement_state(obj_name):
    """Getter of the character's transform and pins (a watch extra: the placement the run used)."""
    def state():
        obj = bpy.data.objects.get(obj_name)
        if obj is None:
            return None
        return tuple(map(tuple, obj.matrix_world)), tuple(sorted(pins_of(obj).items()))
    return state


_DEFAULTS = fit_defaults()
_DEFAULT_PRIOR = (1.0 if _DEFAULTS is None or isinstance(_DEFAULTS.prior_weight, str)
                  else float(_DEFAULTS.prior_weight))
_DEFAULT_AUTO = _DEFAULTS is not None and _DEFAULTS.prior_weight == "auto"
_DEFAULT_TEMPORAL = 10.0 if _DEFAULTS is None else float(_DEFAULTS.temporal_weight)


class LENGTHS_ANGLES_OT_calibrate_fit(FitSettings, RunOperator, bpy.types.Operator):
    """Fit the active character to the selected marker take: build its shape model if needed, calibrate (units,
    placement, performer size, marker binding) and fit every frame, played back by a Mesh Cache modifier
    (Esc cancels)"""
    bl_idname = "lengths_angles.calibrate_fit"
    bl_label = "Calibrate & Fit"
    bl_description = ("Fit the active character to the selected marker take: build its shape model if needed, "
                      "calibrate (units, placement, performer size, marker binding) and fit every frame, played "
                      "back by a Mesh Cache modifier (Esc cancels)")
    bl_options = {'REGISTER', 'UNDO'}

    use_scene_range: BoolProperty(name="Scene Frame Range", default=True,
                                  description="Fit the scene's frame range (off: Start to End); frames outside the "
                                              "take are left out")
    frame_start: IntProperty(name="Start", default=1, description="First frame to fit (without Scene Frame Range)")
    frame_end: IntProperty(name="End", default=250, description="Last frame to fit (without Scene Frame Range)")
    auto_prior: BoolProperty(name="Automatic Prior Weight", default=_DEFAULT_AUTO,
                             description="Choose the prior weight for this take from the data (held-out markers); "
                                         "the report gives the weight used")
    prior_weight: FloatProperty(name="Prior Weight", default=_DEFAULT_PRIOR, min=1e-9, soft_max=100.0,
                                description="How strongly poses are held to the shape model against the markers "
                                            "(scale-free: the same in any unit); larger gives more model-like poses")
    temporal_weight: FloatProperty(name="Temporal Weight", default=_DEFAULT_TEMPORAL, min=0.0, soft_max=100.0,
                                   description="Damps jitter between frames (the previous pose extrapolated; no lag "
                                               "on steady motion); 0: none")
    filepath: StringProperty(name="Cache File", default="", subtype='FILE_PATH', options=BLEND_RELATIVE_PATH,
                             description="Point cache to write ('//' is the folder of the .blend); empty: "
                                         "//<object>_<take>.pc2 next to the .blend")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        draw_frame_range(layout, self)
        layout.prop(self, "auto_prior")
        row = layout.row()
        row.active = not self.auto_prior
        row.prop(self, "prior_weight")
        layout.prop(self, "temporal_weight")
        draw_fit_settings(layout, self)
        layout.prop(self, "filepath")

    def invoke(self, context, event):
        self.interactive = True
        return self.execute(context)

    def execute(self, context):
        def make(context):
            scene = context.scene
            start, end = ((scene.frame_start, scene.frame_end) if self.use_scene_range
                          else (self.frame_start, self.frame_end))
            return calibrate_fit_run(context, character(context), find_take(context), start, end,
                                     prior_weight=typed(self.prior_weight), auto_prior=self.auto_prior,
                                     temporal_weight=typed(self.temporal_weight), filepath=self.filepath,
                                     **self.fit_settings())
        return self.start_run(context, make)


classes = (LENGTHS_ANGLES_OT_calibrate_fit,)
