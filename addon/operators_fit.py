# SPDX-License-Identifier: GPL-3.0-or-later
"""Shape model, marker binding and marker fitting in Blender (glue only: the mathematics is lacore's).

Operators
---------
``lengths_angles.build_model``
    Builds a :class:`..lacore.models.shape_model.ShapeModel` from the active mesh's shape
    keys (default all but the basis and the add-on's own ``"LA ..."`` keys; ``keys`` a
    comma-separated list chooses), on the fan triangulation of :func:`.mesh_access.triangulate`.
    The model is stored IN THE .blend: its ``.npz`` (:meth:`ShapeModel.save`) in a text datablock
    ``"LA shape model <mesh>"`` (:func:`.storage.store_payload`), ``mesh["lengths_angles_model"]`` the
    record (text, token, key names, vertex and mode counts); it survives save/reload and is read back by
    :func:`read_model`.  Files of earlier versions (the ``.npz`` inside the record) are read and migrated
    on the next save (:func:`migrate_models`).
Mode sliders
    Dragging a slider previews its pose: at most every :data:`PREVIEW_INTERVAL` seconds (a timer) the
    pose is synthesized (:meth:`ShapeModel.synthesize`, one reconstruction) into the shape key
    :data:`.naming.PREVIEW_KEY` at value 1.
``lengths_angles.model_pose_to_shape_key``
    Writes the pose of the mode sliders (``object.lengths_angles_mode_weights``, in
    standard deviations; the panel shows one slider per mode) as a new shape key.
``lengths_angles.bind_markers``
    Binds the take's marker empties (the active/selected take empty, or the selected
    marker empties) to the active mesh at the current frame: each marker to the
    nearest surface point of the mesh as its shape keys and leading deformers pose it, an earlier fit's
    modifier and keys and the sliders' preview key left out (:func:`_mesh_vertices`), with its signed normal offset
    (:func:`..lacore.markers.binding.bind_markers`, ``align=False`` by default: the
    markers are where the mesh is; *Align* runs ICP first, at most :data:`ALIGN_ITERATIONS`
    iterations, and the report says how many it ran).  Stored on the object in
    ``obj["lengths_angles_binding"]``; the panel lists each marker with a mesh vertex and vertex group
    (:func:`marker_locations`) and its offset, and the
    operator warns about markers farther than ``warn_distance`` from the surface.
``lengths_angles.fit_markers``
    Fits the frame range.  Marker positions are read from the empties' F-curves in
    bulk (:func:`.operators_markers.read_take`, no ``frame_set``), mapped into the
    object's space and passed to :func:`..lacore.markers.fitting.fit_markers`.  Output:

    * ``'PC2'`` (default, any length): a PC2 point cache (default ``//<object>_<take>.pc2``
      next to the .blend, which must be saved; ``//`` paths are relative to the .blend)
      played by a Mesh Cache modifier :data:`.naming.FIT_MODIFIER` with ``frame_start`` =
      the first fitted frame and ``frame_scale`` 1, so scene frame ``f`` shows fitted frame
      ``f``; the modifier goes after the deformers at the top of the stack and before the first other
      modifier (:func:`_fit_modifier`), so it replaces the motion of the deformers the binding saw (an
      Armature modifier, an armature parent with parent type Armature) and the evaluated mesh is the fit;
    * ``'SHAPE_KEYS'`` (clips of at most :data:`MAX_SHAPE_KEY_FRAMES` frames): one
      shape key per frame, keyed 0/1/0 around its frame (CONSTANT).  Refused up front when a
      deformer would move the keys again (:func:`shape_key_deformer`: an armature parent, an enabled
      deformer at the top of the stack).

Build, Bind and Fit run through the one background-run mechanism (:mod:`.runs`): from the UI
modal with a progress bar (model stages, ICP iterations, frames) and Esc; from scripts and in
background mode synchronously.  Before anything is written the object (mode, mesh, keys) and
what the run read (stored model, binding, take, posed mesh) are checked for changes.  A failed
or cancelled run changes nothing: no file, no modifier, no key, no stored model or binding.
"""

import base64
import hashlib
import io
import os

import bpy
import numpy as np
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, StringProperty

from ..lacore.errors import InputError
from ..lacore.geometry.topology import check_vertices
from ..lacore.io.atomic import check_writable
from ..lacore.io.point_cache import write_pc2
from ..lacore.markers.binding import MarkerBinding, bind_markers
from ..lacore.markers.fitting import FIT_DEFAULTS, fit_markers, fit_options
from ..lacore.models import FineLevel
from ..lacore.models.shape_model import ShapeModel
from ..lacore.multiresolution import coarsen
from . import storage
from .compat import BLEND_RELATIVE_PATH, animation_channels, ensure_animation_channels
from .jobs import CallJob
from .mesh_access import (key_names, not_kept, object_mode, read_shape_keys, require_kept, require_mesh_object,
                          require_nondegenerate_keys, require_whole_keys, require_writable_keys, triangulate,
                          world_to_object, dominant_vertex_groups)
from .bake import value_path
from .motion import animated, moving_transform
from .naming import FIT_MODIFIER, LIVE_MIX_KEY, PREVIEW_KEY, fit_key_name, is_fit_key, is_own_key, parse_key_list
from .operators_markers import (MARKER_PROP, TAKE_PROP, UNKEYED_REASON, marker_objects, read_take, take_frame_rate,
                                unkeyed_markers, unkeyed_note)
from .fit_quality import RMS_PROP, write_quality
from .runs import ObjectWatch, Run, RunOperator, object_state

__all__ = ["MODEL_PROP", "BINDING_PROP", "metres_per_unit", "MAX_MODES", "MAX_SHAPE_KEY_FRAMES", "ALIGN_ITERATIONS",
           "shape_key_deformer", "model_run",
           "bind_run", "marker_locations", "fit_run", "fit_inputs", "fit_settings", "recorded_settings", "FitSettings",
           "draw_fit_settings", "draw_frame_range", "typed", "SETTING_LABELS", "store_model", "read_model",
           "migrate_models", "read_binding", "remove_model", "classes"]

MODEL_PROP = "lengths_angles_model"
#: First line of the text datablock holding a shape model (followed by its token).
MODEL_HEADER = storage.payload_header("Lengths & Angles shape model (do not edit)")
BINDING_PROP = "lengths_angles_binding"
MAX_MODES = 32
#: Auto coarse level of Build Model: meshes of more than twice as many vertices get a model on a coarse mesh of
#: this many vertices (the fit runs there and is prolonged: the coarse CC0 body's size).
COARSE_MODEL_VERTICES = 2500
#: The Fit operators' prior weight default: lacore's (a number; "auto" is Calibrate & Fit's option).
_DEFAULT_PRIOR = 1.0 if isinstance(FIT_DEFAULTS.prior_weight, str) else float(FIT_DEFAULTS.prior_weight)
MAX_SHAPE_KEY_FRAMES = 100
#: Modes Near Markers Only and its two radii: lacore's default (on unless lacore's default is the modes everywhere).
_DEFAULT_NEAR_MARKERS = FIT_DEFAULTS.observed_radius is not None and np.ndim(FIT_DEFAULTS.observed_radius) == 1
_DEFAULT_RADII = tuple(map(float, FIT_DEFAULTS.observed_radius)) if _DEFAULT_NEAR_MARKERS else (0.0, 0.0)
#: The fit's settings as the operators name them (an error about a setting names it so).
SETTING_LABELS = {"prior_weight": "Prior Weight", "temporal_weight": "Temporal Weight",
                  "observed_radius": "Modes Near Markers Only", "penetration_weight": "Non-Penetration Weight",
                  "coefficient_weight": "Training Range Weight"}


class FitSetupError(InputError):
    """Input of the Blender fitting operators that cannot be used (no model, no binding, ...)."""


def fit_settings(options=None, allow_auto=False, **settings):
    """lacore's :class:`~lacore.markers.fitting.FitOptions`: ``options`` (default lacore's ``FIT_DEFAULTS``) with
    the ``settings`` that are not None replaced, checked.

    ``observed_radius`` is ``(r1, r2)`` (Modes Near Markers Only, fractions of the mesh's bounding-box diagonal) or
    ``0`` / False for the modes everywhere (lacore's None), as ``lacore fit --observed-radius R1 R2 | 0``.  A bad
    value raises :class:`FitSetupError`: the setting as the operators name it (:data:`SETTING_LABELS`) and lacore's
    message, one line.

    >>> fit_settings(observed_radius=0, penetration_weight=0.0).observed_radius is None
    True
    >>> try:
    ...     fit_settings(observed_radius=(0.3, 0.1))
    ... except FitSetupError as exc:
    ...     print(exc)
    Modes Near Markers Only: observed_radius must be None or two numbers 0 <= r1 < r2, got (0.3, 0.1)
    """
    given = {k: v for k, v in settings.items() if v is not None}
    r = given.get("observed_radius")
    if r is not None:
        if np.ndim(r) == 0 and not r:
            given["observed_radius"] = None  # the modes everywhere
        elif np.ndim(r) == 1:
            given["observed_radius"] = tuple(float(v) for v in r)
    try:
        return fit_options(options, allow_auto=allow_auto, **given)
    except InputError as exc:
        text = str(exc)
        label = next((label for name, label in SETTING_LABELS.items() if text.startswith(name)), None)
        raise FitSetupError(f"{label}: {text}" if label else text) from None


def recorded_settings(options):
    """What a fit run used, as stored with its quality (:func:`.fit_quality.write_quality`; ID properties: no
    None): the temporal, non-penetration and training-range weights, whether the modes act near the markers only
    and then their two radii."""
    r = options.observed_radius
    near = r is not None and np.ndim(r) == 1
    out = {"temporal_weight": float(options.temporal_weight), "penetration_weight": float(options.penetration_weight),
           "coefficient_weight": float(options.coefficient_weight), "modes_near_markers": bool(near)}
    if near:
        out["observed_radius"] = [float(v) for v in r]
    return out


def _digest(text):
    return hashlib.blake2b(str(text).encode(), digest_size=16).hexdigest()


def _prop_state(object_name, prop, on_mesh):
    """Getter of a digest of the ID property ``prop`` of an object (or of its mesh): a watch extra."""
    def state():
        obj = bpy.data.objects.get(object_name)
        owner = None if obj is None else (obj.data if on_mesh else obj)
        value = None if owner is None else owner.get(prop)
        return None if value is None else _digest(value.to_dict() if hasattr(value, "to_dict") else value)
    return state


# ---------------------------------------------------------------------------------------------- model
def coarse_vertices_for(n_vertices, requested=-1):
    """Vertices of the coarse level a model of a mesh of ``n_vertices`` is built on (0: none, the mesh itself).

    ``requested`` > 0 as given (if it coarsens), 0 none, -1 (Auto) :data:`COARSE_MODEL_VERTICES` for meshes of
    more than twice as many vertices.
    """
    requested = int(requested)
    if requested < 0:
        requested = COARSE_MODEL_VERTICES if n_vertices > 2 * COARSE_MODEL_VERTICES else 0
    return requested if 0 < requested < n_vertices else 0


def _model_inputs(obj, keys=None, n_modes=None, coarse_vertices=-1):
    """What building a model of ``obj`` reads (validated): ``dict(names, keys, poses, faces, reference, n_modes,
    coarse)`` (``coarse``: vertices of the coarse level, 0 for none; :func:`coarse_vertices_for`)."""
    mesh = require_mesh_object(obj)
    require_writable_keys(mesh, "build the shape model")  # the model is stored with the mesh
    if obj.mode == 'EDIT':
        obj.update_from_editmode()
    names, coords = read_shape_keys(mesh)
    if keys is None:
        keys = [k for k in names[1:] if not is_own_key(k)]
    missing = [k for k in keys if k not in names]
    if missing:
        raise FitSetupError(f"mesh '{mesh.name}' has no shape key(s) {', '.join(map(repr, missing))}")
    if len(keys) < 2:
        raise FitSetupError(f"mesh '{mesh.name}': a model needs at least 2 training shape keys, got {len(keys)}")
    require_whole_keys(mesh, keys, "Build Model")
    for k in keys:
        check_vertices(coords[names.index(k)], len(mesh.vertices), name=f"Shape key '{k}'")
    for i, a in enumerate(keys):
        same = next((b for b in keys[:i] if np.array_equal(coords[names.index(a)], coords[names.index(b)])), None)
        if same is not None:
            raise FitSetupError(f"shape keys '{same}' and '{a}' are identical: a model learns from the keys' "
                                "differences, so leave one out (Shape Keys)")
    n_modes = int(n_modes) if n_modes else min(len(keys) - 1, MAX_MODES)
    if n_modes > len(keys) - 1:
        raise FitSetupError(f"{n_modes} modes from {len(keys)} training keys: at most {len(keys) - 1}")
    triangulation = triangulate(mesh)
    poses = coords[[names.index(k) for k in keys]]
    require_nondegenerate_keys(mesh, triangulation, keys, poses)
    return {"names": names, "keys": list(keys), "poses": poses,
            "faces": triangulation.faces, "reference": coords[0], "n_modes": n_modes,
            "coarse": coarse_vertices_for(len(mesh.vertices), coarse_vertices)}


def _build_model(inputs, progress):
    """lacore's :meth:`ShapeModel.fit` on :func:`_model_inputs` (any thread): on the mesh, or on a coarse level
    (:func:`lacore.multiresolution.coarsen` of the reference and the training poses) carrying its
    :class:`lacore.models.FineLevel`, so fits run on the coarse mesh and are prolonged to this one."""
    poses, faces, reference = inputs["poses"], inputs["faces"], inputs["reference"]
    if not inputs["coarse"]:
        return ShapeModel.fit(poses, faces, reference_vertices=reference, n_modes=inputs["n_modes"],
                              progress=progress)
    half = staged_progress(progress, 2)
    try:
        c = coarsen(np.concatenate([reference[None], poses]), faces, inputs["coarse"], progress=half(0))
    except InputError as exc:
        raise FitSetupError(f"Coarse Vertices {inputs['coarse']}: {exc} (0: the full mesh, -1: Auto)") from None
    model = ShapeModel.fit(poses[:, c.vertex_indices], c.faces, reference_vertices=reference[c.vertex_indices],
                           n_modes=inputs["n_modes"], progress=half(1))
    model.fine_level = FineLevel.build(c, reference, poses, model.training_coefficients)
    return model


def staged_progress(progress, stages, scale=1000):
    """``stage -> progress callback`` mapping stage ``stage``'s ``(done, total)`` onto
    ``stage * scale + scale * done / total`` of ``stages * scale`` (one bar for several lacore calls)."""
    def stage(i):
        def report(done, total, message=""):
            if progress is None:
                return False
            return progress(i * scale + int(scale * min(done, total) / max(total, 1)), stages * scale, message)
        return report
    return stage


def model_vertices(model, coefficients):
    """Vertices of the model's pose with ``coefficients`` on the mesh it was built from (prolonged from the
    coarse level when there is one) and the pose's ReconstructionResult (``success`` False: the pose failed its
    checks, ``message`` says how)."""
    X, result = model.synthesize(coefficients, return_results=True)
    fine = getattr(model, "fine_level", None)
    return (X if fine is None else fine(X, coefficients)), result


def pose_problem(result):
    """The one-line message of a model pose that failed its checks (:func:`model_vertices`), else None."""
    if result.success:
        return None
    folded = result.checks.get("folded_faces", 0) if result.failure == "folded" else 0
    detail = f"{folded} folded faces" if folded else result.failure.replace("_", " ")
    return (f"the model's pose at these sliders failed its checks ({detail}); sliders closer to 0 stay nearer "
            "the training poses")


def model_mesh_vertices(model, X):
    """The model's vertices of a pose ``X`` of the mesh it was built from (the coarse level's, if any)."""
    fine = getattr(model, "fine_level", None)
    return X if fine is None else X[fine.coarsening.vertex_indices]


def marker_locations(obj, model, binding):
    """Where the markers of ``binding`` (a :class:`..lacore.markers.binding.MarkerBinding` on ``model``'s triangles)
    sit on the mesh of ``obj``, in the terms Blender shows: ``{"vertices": [...], "regions": [...]}``, for each
    marker the corner of its triangle of largest barycentric weight as a vertex index of the mesh (also when the
    model is on a coarse level) and that vertex's dominant vertex group (``""`` if none,
    :func:`.mesh_access.dominant_vertex_groups`)."""
    faces = np.asarray(model.faces, np.int64)[np.asarray(binding.faces, np.int64)]
    corner = faces[np.arange(len(faces)), np.argmax(np.asarray(binding.barycentric), axis=1)]
    vertices = model_mesh_vertices(model, np.arange(len(obj.data.vertices)))[corner].tolist()
    return {"vertices": vertices, "regions": dominant_vertex_groups(obj, vertices)}


def model_run(obj, keys=None, n_modes=None, coarse_vertices=-1):
    """A :class:`.runs.Run` building a ShapeModel of the mesh ``obj`` from shape keys ``keys`` (default all but
    the basis and the add-on's own keys), on a coarse level for large meshes (:func:`coarse_vertices_for`), and
    storing it (validated; raises InputError subclasses)."""
    inputs = _model_inputs(obj, keys, n_modes, coarse_vertices)
    job = CallJob(lambda progress: _build_model(inputs, progress), "shape model",
                  total=2000 if inputs["coarse"] else 4)
    keys = inputs["keys"]

    def write(obj, job):
        _store_built_model(obj, job.result, keys)
        return f"shape model of {len(keys)} keys, {job.result.n_modes} modes"
    return Run(job, ObjectWatch(obj, [inputs["names"][0], *keys]), write, what="model")


def _store_built_model(obj, model, keys):
    store_model(obj.data, model, keys)
    _PENDING_PREVIEWS.add(obj.name)  # the sliders' reset previews nothing
    obj.lengths_angles_mode_weights = [0.0] * MAX_MODES
    _PENDING_PREVIEWS.discard(obj.name)
    PREVIEW_PROBLEMS.pop(obj.name, None)


def store_model(mesh, model, keys):
    """Store ``model`` with ``mesh`` (saved with the .blend): its ``.npz`` a payload of
    :func:`.storage.store_payload` (text ``"LA shape model <mesh>"``), ``mesh[MODEL_PROP]`` the record (key names,
    vertex and mode counts)."""
    data = storage.saved_bytes(model.save, "model.npz")
    storage.store_payload(mesh, MODEL_PROP, data, header=MODEL_HEADER, name=f"LA shape model {mesh.name}",
                          record={"keys": list(keys), "n_vertices": len(mesh.vertices),
                                  "n_modes": int(model.n_modes)})


def migrate_models():
    """Move every model stored inside its mesh record (``"npz_base64"``, add-on versions before the text
    datablocks) into a payload text (:func:`store_model`'s layout); returns the meshes migrated."""
    moved = []
    for mesh in bpy.data.meshes:
        meta = mesh.get(MODEL_PROP)
        if meta is None or "npz_base64" not in meta:
            continue
        record = meta.to_dict()
        data = base64.b64decode(record.pop("npz_base64"))
        storage.store_payload(mesh, MODEL_PROP, data, header=MODEL_HEADER, name=f"LA shape model {mesh.name}",
                              record=record)
        moved.append(mesh.name)
    return moved


@persistent
def _on_save_pre(*_args):
    migrate_models()


def remove_model(obj):
    """Remove the stored model of ``obj``'s mesh, its preview key and the slider values; True if there was one."""
    mesh = obj.data
    meta = mesh.get(MODEL_PROP)
    had = meta is not None
    if had:
        meta = meta.to_dict()
        del mesh[MODEL_PROP]
        storage.release_payload(meta)
    kb = mesh.shape_keys.key_blocks.get(PREVIEW_KEY) if mesh.shape_keys is not None else None
    if kb is not None:
        obj.shape_key_remove(kb)
    obj.property_unset("lengths_angles_mode_weights")  # back to the defaults, nothing stored (no preview either)
    PREVIEW_PROBLEMS.pop(obj.name, None)
    return had


_MODEL_CACHE = {}


def _model_npz(mesh, meta):
    """The stored model's ``.npz`` bytes (a payload text, or inside the record in files of earlier versions)."""
    legacy = meta.get("npz_base64")
    if legacy is not None:
        return base64.b64decode(legacy)
    try:
        return storage.load_payload(meta, MODEL_HEADER)
    except storage.PayloadError as exc:
        raise FitSetupError(f"the shape model of mesh '{mesh.name}' cannot be read ({exc}): run Build Model "
                            "again") from None


def read_model(obj):
    """The ShapeModel stored on ``obj``'s mesh, checked against the mesh as it is now."""
    mesh = require_mesh_object(obj)
    meta = mesh.get(MODEL_PROP)
    if meta is None:
        raise FitSetupError(f"mesh '{mesh.name}' has no shape model: run Build Model first")
    legacy = meta.get("npz_base64")
    key = (mesh.name_full, str(meta.get("token")) if legacy is None else hash(legacy))
    model = _MODEL_CACHE.get(key)
    if model is None:  # decoded once per stored model (the sliders' preview reads it often)
        model = ShapeModel.load(io.BytesIO(_model_npz(mesh, meta)))
        _MODEL_CACHE.clear()
        _MODEL_CACHE[key] = model
    faces = triangulate(mesh).faces
    fine = getattr(model, "fine_level", None)
    if len(mesh.vertices) != int(meta["n_vertices"]) or not np.array_equal(
            faces, model.faces if fine is None else fine.fine_faces):
        raise FitSetupError(f"mesh '{mesh.name}' was edited after its model was built ({len(mesh.vertices)} vertices "
                            f"now, {int(meta['n_vertices'])} then, or other faces): build the model again")
    return model


def _deformers_on_top(modifiers):
    """How many of ``modifiers`` (a stack, in order) are deformers (:data:`DEFORM_MODIFIERS`) before the first that
    is not (Subdivision Surface, Mirror ...)."""
    return next((i for i, m in enumerate(modifiers) if m.type not in DEFORM_MODIFIERS), len(modifiers))


def _bound_modifiers_off(obj):
    """The modifiers of ``obj`` a binding leaves out, those shown in the viewport: an earlier fit's Mesh Cache
    modifier (:data:`.naming.FIT_MODIFIER`), and from the first modifier that is no deformer
    (:func:`_deformers_on_top`) to the end of the stack."""
    mods = list(obj.modifiers)
    top = _deformers_on_top(mods)
    return [m for i, m in enumerate(mods) if m.show_viewport and (i >= top or m.name == FIT_MODIFIER)]


def _bound_keys_off(obj):
    """The shape keys of ``obj`` a binding leaves out, those not muted: an earlier fit's keys
    (:func:`.naming.is_fit_key`) and the mode sliders' preview key (:data:`.naming.PREVIEW_KEY`: at 1 it adds the
    model's pose to the character's)."""
    key = obj.data.shape_keys
    return [] if key is None else [kb for kb in key.key_blocks
                                   if (is_fit_key(kb.name) or kb.name == PREVIEW_KEY) and not kb.mute]


def _evaluated_co(obj, depsgraph):
    """(V, 3) float32 vertex positions of the evaluated ``obj``."""
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        co = np.empty(3 * len(me.vertices), np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    return co.reshape(-1, 3)


def _mesh_vertices(obj, context=None):
    """(V, 3) float64 positions of ``obj`` in its own space (V of its mesh data) as its shape keys and the
    deformers at the top of its modifier stack pose it: the mesh the fit's Mesh Cache modifier replaces
    (:func:`_fit_modifier`), without an earlier fit or the sliders' preview.  The modifiers from the first other one
    on and an earlier fit's modifier (:func:`_bound_modifiers_off`) are off in the viewport, and an earlier fit's keys
    and the preview key (:func:`_bound_keys_off`) muted, while it is evaluated, and on again after it, also on
    error."""
    context = context or bpy.context
    off, muted = _bound_modifiers_off(obj), _bound_keys_off(obj)
    try:
        for m in off:
            m.show_viewport = False
        for kb in muted:
            kb.mute = True
        co = _evaluated_co(obj, context.evaluated_depsgraph_get())
    finally:
        for m in off:
            m.show_viewport = True
        for kb in muted:
            kb.mute = False
    V = len(co)
    if V != len(obj.data.vertices):
        raise FitSetupError(f"object '{obj.name}': its modifiers change the vertex count ({V} evaluated, "
                            f"{len(obj.data.vertices)} in the mesh): bind with those modifiers off")
    return co.astype(np.float64)


# -------------------------------------------------------------------------------------------- preview
PREVIEW_INTERVAL = 0.2  # seconds: the slider preview is recomputed at most this often
_PENDING_PREVIEWS = set()
#: ``{object name: message}`` of previews showing a pose that failed its checks (the panel shows the message).
PREVIEW_PROBLEMS = {}


def preview_pose(obj):
    """Write the mode sliders' pose (``ShapeModel.synthesize``) into the shape key :data:`PREVIEW_KEY` (at 1)."""
    model = read_model(obj)
    w = np.array(obj.lengths_angles_mode_weights[:model.n_modes], np.float64)
    X, result = model_vertices(model, w * model.standard_deviations)
    problem = pose_problem(result)
    if problem is None:
        PREVIEW_PROBLEMS.pop(obj.name, None)
    else:
        PREVIEW_PROBLEMS[obj.name] = problem
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    kb = obj.data.shape_keys.key_blocks.get(PREVIEW_KEY) or obj.shape_key_add(name=PREVIEW_KEY, from_mix=False)
    kb.data.foreach_set("co", np.asarray(X, np.float32).ravel())
    kb.value = 1.0
    obj.data.update()
    return X


def update_previews():
    """Timer callback: recompute the previews of the objects whose sliders moved (rate limit).  An object in Edit
    Mode stays pending until it leaves it (leaving Edit Mode writes back the keys as they were on entering it, so a
    preview written there would be lost); the timer then runs again after :data:`PREVIEW_INTERVAL`."""
    names = sorted(_PENDING_PREVIEWS)
    _PENDING_PREVIEWS.clear()
    for name in names:
        obj = bpy.data.objects.get(name)
        if obj is not None and obj.type == 'MESH' and MODEL_PROP in obj.data:
            if obj.mode == 'EDIT':
                _PENDING_PREVIEWS.add(name)
                continue
            try:
                preview_pose(obj)
            except InputError as exc:  # e.g. mesh edited since the model: no preview
                print(f"Lengths & Angles preview of '{name}': {exc}")
    return PREVIEW_INTERVAL if _PENDING_PREVIEWS else None


def _mode_weights_changed(obj, _context):
    if obj.type != 'MESH' or MODEL_PROP not in obj.data:
        return
    if not _PENDING_PREVIEWS and not bpy.app.background:
        bpy.app.timers.register(update_previews, first_interval=PREVIEW_INTERVAL)
    _PENDING_PREVIEWS.add(obj.name)


# -------------------------------------------------------------------------------------------- binding
def _take_of(objects):
    """The take empty among ``objects`` or the parent of marker empties among them, and the marker subset."""
    takes = {o for o in objects if o is not None and TAKE_PROP in o}
    marker_objs = [o for o in objects if o is not None and MARKER_PROP in o]
    takes |= {o.parent for o in marker_objs if o.parent is not None and TAKE_PROP in o.parent}
    if len(takes) != 1:
        raise FitSetupError("select one marker take (its take empty or some of its marker empties); "
                            f"{len(takes)} takes are selected")
    take = takes.pop()
    labels = [o[MARKER_PROP] for o in marker_objs if o.parent == take] or None
    return take, labels


def _take_state(take_name):
    """Getter of the take's identity and its marker empties' (a watch extra)."""
    def state():
        take = bpy.data.objects.get(take_name)
        if take is None:
            return None
        return (take.as_pointer(), tuple(sorted(object_state(c.name) for c in take.children if MARKER_PROP in c)))
    return state


def _posed_mesh_state(obj_name):
    """Getter of a digest of the evaluated mesh at the current frame (a watch extra of Bind)."""
    def state():
        obj = bpy.data.objects.get(obj_name)
        if obj is None:
            return None
        X = _mesh_vertices(obj)
        return bpy.context.scene.frame_current, hashlib.blake2b(X.tobytes(), digest_size=16).hexdigest()
    return state


def metres_per_unit(obj, take=None, scene=None):
    """Metres per unit of length in ``obj``'s own space (where meshes, bindings and fits are computed).

    A take empty imported by :func:`.operators_markers.import_take` knows it exactly: its markers are the file's
    metres times the import *Scale*, in the take empty's space; otherwise the scene's Unit Scale
    (``scene.unit_settings.scale_length``: metres per Blender unit).  Object scales count (their mean
    factor, the cube root of the determinant of the world matrix).
    """
    def factor(ob):
        return abs(float(np.linalg.det(np.array(ob.matrix_world, np.float64)[:3, :3]))) ** (1.0 / 3.0)
    meta = take.get(TAKE_PROP) if take is not None else None
    if meta is not None and float(meta.get("scale", 0.0)) > 0 and factor(take) > 0:
        world = 1.0 / (float(meta["scale"]) * factor(take))
    else:
        scene = scene or bpy.context.scene
        world = float(scene.unit_settings.scale_length) or 1.0
    return world * (factor(obj) or 1.0)


def nonuniform_scale_note(obj):
    """The warning for markers fitted to ``obj`` when its world matrix scales non-uniformly (its own scale or a
    parent's), else None: markers are bound and fitted in the mesh's own coordinates, so the scale stretches them
    there, and distances in millimetres are measured with the mean factor (:func:`metres_per_unit`)."""
    s = np.linalg.svd(np.array(obj.matrix_world, np.float64)[:3, :3], compute_uv=False)
    if not s[0] - s[-1] > 1e-4 * s[0]:
        return None
    return (f"'{obj.name}' is scaled non-uniformly (factors {', '.join(f'{v:.3g}' for v in s)}: its scale or a "
            "parent's): the markers are fitted in the mesh's own coordinates, stretched by it, and the distances in "
            "mm are approximate; apply the scale (Ctrl+A) for an exact fit")


def keys_on_note(obj):
    """The warning for a fit written as shape keys when other keys of ``obj`` are on, else None: a key with a value
    other than 0, keyed or driven (not muted) adds to the fitted keys, so the mesh shown is not the fit.  The live
    mix key is left out (its correction is 0 while the keys it mixes are at 0; those that are not are named)."""
    key = obj.data.shape_keys
    if key is None:
        return None
    on = []
    for kb in key.key_blocks:
        if kb == key.reference_key or kb.mute or is_fit_key(kb.name) or kb.name == LIVE_MIX_KEY:
            continue
        if kb.value != 0.0 or animated(key, value_path(kb.name).__eq__) is not None:
            on.append(kb.name)
    if not on:
        return None
    names = ", ".join(f"'{n}'" for n in on[:4]) + (f" and {len(on) - 4} more" if len(on) > 4 else "")
    return (f"the shape keys {names} of '{obj.name}' are on (a value other than 0, keyed or driven) and add to the "
            "fitted keys, so the mesh shown is not the fit: set them to 0 or mute them")


#: Markers needed to bind (and to place a pose by them).
MIN_BOUND_MARKERS = 3
#: Bind Markers' *Align*: at most this many ICP iterations (lacore's ICP stops earlier once the placement no longer
#: improves).
ALIGN_ITERATIONS = 100


def bind_run(context, obj, take, labels=None, align=False, warn_distance=0.05):
    """A :class:`.runs.Run` binding markers of ``take`` (``labels`` or all) to ``obj`` at the current frame and
    storing the binding (validated; raises InputError subclasses).

    Markers occluded at the current frame are not bound (the report names them; Calibrate & Fit binds every
    marker where it is visible), nor markers without keyed positions (:func:`.operators_markers.unkeyed_markers`:
    named too); both are stored as not bound with why (the panel lists them).  At least :data:`MIN_BOUND_MARKERS`
    must be visible.  The mesh is the one the fit replaces: shape keys and the deformers at the top of the stack
    (:func:`_mesh_vertices`; Subdivision Surface, Mirror and what follows them, an earlier fit's modifier and keys,
    and the sliders' preview key are left out: binding again after a fit binds as without it).  ``warn_distance``
    is in metres (:func:`metres_per_unit`).
    """
    require_mesh_object(obj)
    require_kept([obj], "bind the markers")  # the binding is stored on the object
    model = read_model(obj)
    all_labels = [lb for lb, _ in marker_objects(take)]
    labels = all_labels if labels is None else [lb for lb in all_labels if lb in labels]
    idx = [all_labels.index(lb) for lb in labels]
    frame = context.scene.frame_current
    world = read_take(take, frames=[frame]).positions[0][idx]
    seen = np.isfinite(world).all(1)
    unkeyed = unkeyed_markers(take, labels)     # read as never visible: named, not counted as occluded
    hidden = [lb for lb, s in zip(labels, seen, strict=True) if not s and lb not in unkeyed]
    if seen.sum() < MIN_BOUND_MARKERS:
        why = [f"{what}: {', '.join(map(repr, lbs[:5]))}{' ...' if len(lbs) > 5 else ''}"
               for what, lbs in (("occluded", hidden), ("no keyed positions", unkeyed)) if lbs]
        raise FitSetupError(f"only {int(seen.sum())} of the {len(labels)} markers are visible at frame {frame} "
                            f"({'; '.join(why)}): bind at a frame where at least {MIN_BOUND_MARKERS} are visible, or "
                            "use Calibrate & Fit")
    labels = [lb for lb, s in zip(labels, seen, strict=True) if s]
    world = world[seen]
    inv = world_to_object(obj)
    local = world @ inv[:3, :3].T + inv[:3, 3]
    X = model_mesh_vertices(model, _mesh_vertices(obj, context))
    faces = model.faces
    job = CallJob(lambda progress: bind_markers(X, faces, local, align=align, iterations=ALIGN_ITERATIONS,
                                                progress=progress), "binding", total=ALIGN_ITERATIONS if align else 1)
    empties = {lb: o.name for lb, o in marker_objects(take)}
    take_name = take.name
    unit = metres_per_unit(obj, take, context.scene)
    warn_distance = float(warn_distance)
    note = nonuniform_scale_note(obj)

    def write(obj, job):
        binding, info = job.result
        obj[BINDING_PROP] = {
            "take": take_name, "labels": labels, "empties": [empties[lb] for lb in labels], "frame": frame,
            "faces": binding.faces.tolist(), "barycentric": binding.barycentric.ravel().tolist(),
            "offsets": binding.offsets.tolist(), "n_vertices": len(obj.data.vertices),
            **marker_locations(obj, model, binding),
            "metres_per_unit": unit, "warn_distance": warn_distance, "not_bound": hidden + unkeyed,
            "not_bound_reasons": [f"occluded at frame {frame}"] * len(hidden) + [UNKEYED_REASON] * len(unkeyed),
        }
        if note is not None:
            job.notes.append(note)
        if unkeyed:
            job.notes.append(unkeyed_note(unkeyed))
        if hidden:
            job.notes.append(f"{len(hidden)} markers occluded at frame {frame} were not bound: "
                             + ", ".join(hidden[:8]) + (" ..." if len(hidden) > 8 else ""))
        far = np.flatnonzero(np.abs(binding.offsets) * unit > warn_distance)
        if far.size:
            job.notes.append(f"{far.size} markers are farther than {1000 * warn_distance:g} mm from the surface: "
                             + ", ".join(f"{labels[i]} ({1000 * abs(binding.offsets[i]) * unit:.0f} mm)"
                                         for i in far[:8]))
        if not align:
            return f"bound {binding.n_markers} markers"
        if info["iterations"] >= ALIGN_ITERATIONS:
            job.notes.append(f"the alignment ran to its limit of {ALIGN_ITERATIONS} ICP iterations: place the take "
                             "nearer the character and bind again")
        return f"bound {binding.n_markers} markers, aligned in {info['iterations']} ICP iterations"
    extras = {f"The shape model of '{obj.name}'": _prop_state(obj.name, MODEL_PROP, on_mesh=True),
              f"The take '{take_name}' or its marker empties": _take_state(take_name),
              f"The posed mesh of '{obj.name}' (frame, shape keys, modifiers)": _posed_mesh_state(obj.name)}
    return Run(job, ObjectWatch(obj, extras=extras), write, what="binding")


def read_binding(obj):
    """``(MarkerBinding, take object, labels)`` stored on ``obj``, checked against the scene."""
    meta = obj.get(BINDING_PROP)
    if meta is None:
        raise FitSetupError(f"object '{obj.name}' has no marker binding: run Bind Markers first")
    take = bpy.data.objects.get(meta["take"])
    if take is None or TAKE_PROP not in take:
        raise FitSetupError(f"object '{obj.name}': the bound take '{meta['take']}' is gone (deleted or renamed): "
                            f"name the take empty '{meta['take']}' again or bind again")
    # the markers by their labels (what the fit reads): renaming an empty changes nothing
    present = {c[MARKER_PROP] for c in take.children if MARKER_PROP in c}
    labels = list(meta["labels"])
    missing = [lb for lb in labels if lb not in present]
    if missing:
        raise FitSetupError(f"object '{obj.name}': the empties of bound markers {', '.join(map(repr, missing[:5]))} "
                            "were deleted or unparented: bind again")
    binding = MarkerBinding.from_surface(np.asarray(meta["faces"], np.int64),
                                         np.asarray(meta["barycentric"], np.float64).reshape(-1, 3),
                                         np.asarray(meta["offsets"], np.float64))
    return binding, take, labels


# ------------------------------------------------------------------------------------------------ fit
def require_still(take, obj):
    """FitSetupError if the take empty or the character moves over time (itself or a parent: keyed, driven,
    played by the NLA or constrained, or parented to a bone that is posed or to vertices that are deformed over time:
    :func:`.motion.moving_transform`): the markers are mapped into the character's space with their transforms at
    the current frame."""
    for what, ob in (("take empty", take), ("character", obj)):
        found = moving_transform(ob)
        if found is not None:
            moving, reason, advice, link = found
            whose = f" with {link}" if link else ("" if moving is ob else f" with its parent '{moving.name}'")
            raise FitSetupError(f"the {what} '{ob.name}' moves{whose} ({reason}): the fit uses one placement of it, "
                                f"so {advice} and place it once")


def _pc2_path(filepath, obj, take):
    """``(path as given, absolute path)`` of the point cache; ``//`` is relative to the saved .blend."""
    if not filepath:
        if not bpy.data.filepath:
            raise FitSetupError("save the .blend first: the point cache is written next to it")
        filepath = f"//{bpy.path.clean_name(obj.name)}_{bpy.path.clean_name(take.name)}.pc2"
    if filepath.startswith("//") and not bpy.data.filepath:
        raise FitSetupError(f"Cache File '{filepath}' is relative to the .blend ('//'): save the .blend first or "
                            "give an absolute path")
    path = os.path.abspath(bpy.path.abspath(filepath))
    if os.path.isdir(path):
        raise FitSetupError(f"Cache File '{filepath}' is a folder: give a file name, e.g. '//fit.pc2'")
    folder = os.path.dirname(path)
    if not os.path.isdir(folder):
        raise FitSetupError(f"Cache File '{filepath}': the folder {folder} does not exist")
    try:
        check_writable(path)                          # before the fit, not after it
    except OSError as exc:
        raise FitSetupError(f"Cache File: {exc}") from None
    return filepath, path


def require_frame_range(frame_start, frame_end):
    """``(frame_start, frame_end)`` as integers; :class:`FitSetupError` saying what to do when End is before
    Start."""
    frame_start, frame_end = int(frame_start), int(frame_end)
    if frame_end < frame_start:
        raise FitSetupError(f"End {frame_end} is before Start {frame_start}: set End at or after Start, or use "
                            "Scene Frame Range")
    return frame_start, frame_end


def fit_inputs(context, obj, frame_start, frame_end, output='PC2', filepath=""):
    """What a fit reads from Blender (validated): ``dict(model, binding, take, markers (T, M, 3) in the object's
    space, frames, filepath, path, labels, unkeyed)`` (``unkeyed``: the bound markers without keyed positions,
    NaN in ``markers``)."""
    mesh = require_mesh_object(obj)
    if obj.library is not None:  # neither the modifier, nor the keys, nor the fit's quality would be kept
        require_kept([obj], "fit to the markers")
    if output == 'SHAPE_KEYS':
        require_writable_keys(mesh, "fit to shape keys")
    model = read_model(obj)
    binding, take, labels = read_binding(obj)
    frame_start, frame_end = require_frame_range(frame_start, frame_end)
    if output == 'SHAPE_KEYS' and frame_end - frame_start + 1 > MAX_SHAPE_KEY_FRAMES:
        raise FitSetupError(f"{frame_end - frame_start + 1} frames: shape keys are for clips of at most "
                            f"{MAX_SHAPE_KEY_FRAMES} frames, use the PC2 output")
    meta = take[TAKE_PROP]
    first = float(meta["frame_start"])
    last = first + (int(meta["keyed_samples"]) - 1) * float(meta["frame_step"])
    if frame_start < first - 1e-6 or frame_end > last + 1e-6:
        raise FitSetupError(f"take '{take.name}' covers frames {first:g}..{last:g}, fewer than the range "
                            f"{frame_start}..{frame_end}: set the frame range inside the take")
    frames = np.arange(frame_start, frame_end + 1)
    require_still(take, obj)
    if output == 'SHAPE_KEYS':
        deformer = shape_key_deformer(obj)
        if deformer is not None:
            raise FitSetupError(f"Output Shape Keys: {deformer}")
    filepath, path = _pc2_path(filepath, obj, take) if output == 'PC2' else ("", "")
    unkeyed = unkeyed_markers(take, labels)       # read as never visible: left out by the fit, named
    if len(unkeyed) == len(labels):
        raise FitSetupError(f"none of the markers bound to '{obj.name}' has keyed positions in take '{take.name}' "
                            "(their animation was cleared): re-import the take and bind again")
    all_labels = [lb for lb, _ in marker_objects(take)]
    world = read_take(take, frames=frames).positions[:, [all_labels.index(lb) for lb in labels]]
    inv = world_to_object(obj)
    return {"model": model, "binding": binding, "take": take, "markers": world @ inv[:3, :3].T + inv[:3, 3],
            "frames": frames, "filepath": filepath, "path": path, "labels": labels, "unkeyed": unkeyed}


def fit_run(context, obj, frame_start, frame_end, output='PC2', prior_weight=None, temporal_weight=None, filepath="",
            observed_radius=None, penetration_weight=None, coefficient_weight=None):
    """A :class:`.runs.Run` fitting the shape model to the bound markers over the frame range and writing the
    PC2 + Mesh Cache modifier or the shape keys (validated; raises InputError subclasses).

    The fit's settings default to lacore's (None); ``observed_radius`` ``(r1, r2)`` or 0 for the modes everywhere
    (:func:`fit_settings`).  The settings used are stored with the fit's quality.
    """
    options = fit_settings(prior_weight=prior_weight, temporal_weight=temporal_weight,
                           observed_radius=observed_radius, penetration_weight=penetration_weight,
                           coefficient_weight=coefficient_weight)
    inputs = fit_inputs(context, obj, frame_start, frame_end, output, filepath)
    model, markers, binding, frames = inputs["model"], inputs["markers"], inputs["binding"], inputs["frames"]
    rate = take_frame_rate(inputs["take"])  # one sample per scene frame, in the take's time (the temporal weight)
    fine = getattr(model, "fine_level", None)
    job = CallJob(lambda progress: fit_markers(model, markers, binding, options, rate=rate, prolongation=fine,
                                               progress=progress), "marker fit", total=len(frames))
    job.inputs = inputs
    job.options = options

    unit = metres_per_unit(obj, inputs["take"], context.scene)
    labels = inputs["labels"]
    note = nonuniform_scale_note(obj)

    def write(obj, job):
        X = job.result.vertices if fine is None else job.result.fine_vertices
        text = _write_fit(obj, X, frames, output, inputs["filepath"], inputs["path"])
        quality = write_quality(obj, frames, job.result, labels, unit, take_name, recorded_settings(options))
        job.notes.extend([note] if note is not None else [])
        keys_on = keys_on_note(obj) if output == 'SHAPE_KEYS' else None
        job.notes.extend([keys_on] if keys_on is not None else [])
        if inputs["unkeyed"]:
            job.notes.append(unkeyed_note(inputs["unkeyed"]))
        job.notes.extend(quality["notes"])
        lost = not_kept(obj)  # a library override: the fit's output is kept, its quality record is not
        if lost:
            job.notes.append(f"the fit's quality shown in the panel, and the '{RMS_PROP}' property its curve keys, "
                             f"are not kept when the shot is opened again: {lost}")
        return f"{text}; {quality['text']}"
    take_name = inputs["take"].name
    extras = {f"The shape model of '{obj.name}'": _prop_state(obj.name, MODEL_PROP, on_mesh=True),
              f"The marker binding of '{obj.name}'": _prop_state(obj.name, BINDING_PROP, on_mesh=False),
              f"The take '{take_name}' or its marker empties": _take_state(take_name)}
    return Run(job, ObjectWatch(obj, extras=extras), write, what="fitted frame")


def remove_fit_keys(obj):
    """Remove the fitted frames' keys (:func:`.naming.is_fit_key`) of ``obj`` with their F-curves; returns how
    many."""
    key = obj.data.shape_keys
    if key is None:
        return 0
    names = [kb.name for kb in key.key_blocks if is_fit_key(kb.name)]
    owner = animation_channels(key)
    if owner is not None:
        paths = {f'key_blocks["{n}"].value' for n in names}
        for fc in [fc for fc in owner.fcurves if fc.data_path in paths]:
            owner.fcurves.remove(fc)
    for name in names:
        obj.shape_key_remove(key.key_blocks[name])
    return len(names)


#: Modifier types that only move the vertices they are given (the fit's Mesh Cache modifier replaces their motion).
DEFORM_MODIFIERS = frozenset({'ARMATURE', 'CAST', 'CORRECTIVE_SMOOTH', 'CURVE', 'DISPLACE', 'HOOK', 'LAPLACIANDEFORM',
                              'LAPLACIANSMOOTH', 'LATTICE', 'MESH_CACHE', 'MESH_DEFORM', 'SHRINKWRAP', 'SIMPLE_DEFORM',
                              'SMOOTH', 'SURFACE_DEFORM', 'WARP', 'WAVE'})


#: Parent types whose parent deforms the child's mesh: Blender evaluates such a parent (an armature with parent type
#: Armature, a lattice with parent type Lattice) as a modifier before the stack.
DEFORMING_PARENT_TYPES = frozenset({'ARMATURE', 'LATTICE'})


def _fit_modifier(obj):
    """The fit's Mesh Cache modifier (made if there is none), placed after the deformers at the top of ``obj``'s
    stack and before the first modifier that is no deformer: it replaces the deformers' motion (the fit is of the
    mesh they pose, :func:`_mesh_vertices`; a deformer after it would deform the fit again), and the modifiers from
    the first other one on (Subdivision Surface, Mirror, physics ...) apply to the fit (placed after one that changes
    the vertex count, the cache would not play).  A deforming parent (parent type Armature) is evaluated before the
    whole stack, so the cache replaces its motion too."""
    mod = obj.modifiers.get(FIT_MODIFIER) or obj.modifiers.new(FIT_MODIFIER, 'MESH_CACHE')
    here = list(obj.modifiers).index(mod)
    place = _deformers_on_top([m for m in obj.modifiers if m != mod])
    if place != here:
        obj.modifiers.move(here, place)
    return mod


def shape_key_deformer(obj):
    """What deforms the fitted frames if they are written as shape keys of ``obj``, as a phrase naming it and what
    to do, else None.

    Shape keys are the mesh before every modifier: a deforming parent (parent type Armature or Lattice, evaluated
    before the stack) and every deformer at the top of the stack that is on in the viewport or the render (an Armature,
    Lattice, a Mesh Cache ... other than the fit's own, which the shape-key output removes) would move them again
    -- the fit is of the mesh they pose already (:func:`_mesh_vertices`).  The point-cache output replaces their
    motion (:func:`_fit_modifier`).
    """
    parent = obj.parent
    if parent is not None and obj.parent_type in DEFORMING_PARENT_TYPES and parent.type == obj.parent_type:
        kind = parent.type.lower()
        return (f"the {kind} '{parent.name}' (parent of '{obj.name}' with parent type {kind.title()}) deforms its "
                f"shape keys and would deform the fitted keys again: use the Point Cache output, or parent "
                f"'{obj.name}' to '{parent.name}' as an object")
    mods = list(obj.modifiers)
    for m in mods[:_deformers_on_top(mods)]:
        if m.name == FIT_MODIFIER or not (m.show_viewport or m.show_render):
            continue
        target = getattr(m, "object", None)
        by = f" (armature '{target.name}')" if m.type == 'ARMATURE' and target is not None else ""
        return (f"the modifier '{m.name}' of '{obj.name}'{by} deforms its shape keys and would deform the fitted "
                f"keys again: use the Point Cache output, or disable the modifier '{m.name}'")
    return None


def _write_fit(obj, X, frames, output, filepath, path):
    """Write the fitted frames: PC2 + Mesh Cache modifier, or one keyed shape key per frame.  Either replaces a
    previous fit's output in both forms (its keys and keyframes, its modifier), so fitting again never adds up."""
    remove_fit_keys(obj)
    if output == 'PC2':
        write_pc2(path, X, start=float(frames[0]), sampling=1.0)
        mod = _fit_modifier(obj)
        mod.cache_format = 'PC2'
        mod.filepath = filepath
        mod.time_mode = 'FRAME'
        mod.play_mode = 'SCENE'
        mod.frame_start = float(frames[0])  # scene frame f shows sample f - frame_start
        mod.frame_scale = 1.0
        mod.deform_mode = 'OVERWRITE'
        mod.interpolation = 'NONE'
        return f"fitted {len(frames)} frames to {filepath}"
    mod = obj.modifiers.get(FIT_MODIFIER)
    if mod is not None:       # a previous fit's point cache would overwrite the keys
        obj.modifiers.remove(mod)
    mesh = obj.data
    if mesh.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    owner, _ = ensure_animation_channels(mesh.shape_keys, f"{obj.name} LA fit")
    for t, f in enumerate(frames):
        kb = obj.shape_key_add(name=fit_key_name(f), from_mix=False)
        kb.data.foreach_set("co", X[t].astype(np.float32).ravel())
        fc = owner.fcurves.new(f'key_blocks["{kb.name}"].value')
        kf = [(f - 1, 0.0), (f, 1.0), (f + 1, 0.0)]
        fc.keyframe_points.add(len(kf))
        fc.keyframe_points.foreach_set("co", np.array(kf, np.float32).ravel())
        for k in fc.keyframe_points:
            k.interpolation = 'CONSTANT'
    return f"fitted {len(frames)} frames as shape keys"


# ---------------------------------------------------------------------------------------------- operators
class FitSettings:
    """The fit's settings Fit to Markers and Calibrate & Fit share beyond the prior and temporal weights (operator
    properties; defaults: lacore's ``FIT_DEFAULTS``); :meth:`fit_settings` hands them to the run functions."""

    use_observed_radius: BoolProperty(
        name="Modes Near Markers Only", default=_DEFAULT_NEAR_MARKERS,
        description="The shape model reshapes the mesh only near the markers; regions far from every marker keep "
                    "the model's average shape instead of a guess. Turn off for a creature or prop whose few "
                    "markers are spread over a bend of the whole mesh")
    observed_radius: FloatVectorProperty(
        name="Near Markers", size=2, default=_DEFAULT_RADII, min=0.0, soft_max=1.0, precision=3, step=1,
        description="How near the markers the model acts: fully within the first distance, not at all beyond the "
                    "second, measured along the surface as fractions of the mesh's size (its bounding-box "
                    "diagonal)")
    penetration_weight: FloatProperty(
        name="Non-Penetration Weight", default=float(FIT_DEFAULTS.penetration_weight), min=0.0, soft_max=100.0,
        description="Keeps the surface from passing through itself where the markers do not (an arm into the "
                    "torso): frames that do are fitted again holding the faces apart; 0: off (faster on takes with "
                    "many such frames)")
    coefficient_weight: FloatProperty(
        name="Training Range Weight", default=float(FIT_DEFAULTS.coefficient_weight), min=0.0, soft_max=10.0,
        description="Keeps poses within the range of the training shape keys: poses the model would push beyond "
                    "its most extreme training poses are pulled back; 0: no limit")

    def fit_settings(self):
        """The settings as keyword arguments of :func:`fit_run` / :func:`.operators_calibrate.calibrate_fit_run`
        (as typed: :func:`typed`)."""
        return {"observed_radius": tuple(map(typed, self.observed_radius)) if self.use_observed_radius else 0,
                "penetration_weight": typed(self.penetration_weight),
                "coefficient_weight": typed(self.coefficient_weight)}


def typed(value):
    """A float property's value as typed: Blender keeps single precision, so 0.1 is read back as 0.10000000149...;
    this is the shortest decimal that single precision reads as the same value (lacore's defaults exactly, and
    messages and records without the noise).

    >>> typed(np.float32(0.1)), typed(10.0)
    (0.1, 10.0)
    """
    return float(str(np.float32(value)))


def draw_frame_range(layout, props):
    """Draw Use Scene Range and the frame range of the operator properties ``props`` (greyed out when the scene's
    range is used)."""
    layout.prop(props, "use_scene_range")
    col = layout.column(align=True)
    col.active = not props.use_scene_range
    col.prop(props, "frame_start")
    col.prop(props, "frame_end")


def draw_fit_settings(layout, props):
    """Draw the :class:`FitSettings` of the operator properties ``props`` (the radii greyed out when the modes act
    everywhere)."""
    layout.prop(props, "penetration_weight")
    layout.prop(props, "coefficient_weight")
    layout.prop(props, "use_observed_radius")
    col = layout.column(align=True)
    col.active = bool(props.use_observed_radius)
    col.prop(props, "observed_radius", index=0, text="Fully Within")
    col.prop(props, "observed_radius", index=1, text="Not Beyond")


class _Interactive:
    """From the UI (a button): modal with progress and Esc; ``execute`` alone (scripts) runs at once."""

    def invoke(self, context, event):
        self.interactive = True
        return self.execute(context)


class LENGTHS_ANGLES_OT_build_model(_Interactive, RunOperator, bpy.types.Operator):
    """Build a shape model (lengths-and-angles PCA) from the mesh's shape keys and store it in the .blend"""
    bl_idname = "lengths_angles.build_model"
    bl_label = "Build Shape Model"
    bl_options = {'REGISTER', 'UNDO'}

    keys: StringProperty(name="Shape Keys", description="Training shape keys separated by commas; empty: every key "
                                                        "but the basis and the add-on's own 'LA ...' keys")
    n_modes: IntProperty(name="Modes", default=0, min=0, max=MAX_MODES,
                         description=f"Modes of variation to keep; 0: as many as the keys allow (at most {MAX_MODES})")
    coarse_vertices: IntProperty(name="Coarse Vertices", default=-1, min=-1,
                                 description="Build the model on a coarse version of the mesh with this many "
                                             "vertices (fits run there and are carried to the full mesh: much "
                                             f"faster); -1: Auto ({COARSE_MODEL_VERTICES} for meshes of more than "
                                             f"{2 * COARSE_MODEL_VERTICES} vertices); 0: the full mesh")

    def execute(self, context):
        def make(context):
            obj = context.active_object
            keys = (parse_key_list(self.keys, key_names(obj.data) if obj is not None and obj.type == 'MESH'
                                   else ()) if self.keys.strip() else None)
            return model_run(context.active_object, keys, self.n_modes or None, self.coarse_vertices)
        return self.start_run(context, make)


class LENGTHS_ANGLES_OT_model_pose_to_shape_key(bpy.types.Operator):
    """Write the pose of the mode sliders as a new shape key"""
    bl_idname = "lengths_angles.model_pose_to_shape_key"
    bl_label = "Model Pose to Shape Key"
    bl_options = {'REGISTER', 'UNDO'}

    name: StringProperty(name="Name", default="Model pose", description="Name of the new shape key")

    def execute(self, context):
        obj = context.active_object
        if obj is None or obj.type != 'MESH':
            return self.add_pose_key(obj)
        with object_mode(obj):  # Edit Mode's edits reach the mesh first, and the new key stays on leaving it
            return self.add_pose_key(obj)

    def add_pose_key(self, obj):
        """Add the pose of the sliders as a new key of ``obj`` (at value 0); an ERROR report if it cannot."""
        try:
            model = read_model(obj)
            require_writable_keys(obj.data, "add the model pose as a shape key")
            w = np.array(obj.lengths_angles_mode_weights[:model.n_modes], np.float64)
            X, result = model_vertices(model, w * model.standard_deviations)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        problem = pose_problem(result)
        if problem is not None:  # written all the same: it is the pose the preview shows
            self.report({'WARNING'}, problem[0].upper() + problem[1:])
        if obj.data.shape_keys is None:
            obj.shape_key_add(name="Basis", from_mix=False)
        kb = obj.shape_key_add(name=self.name, from_mix=False)
        kb.value = 0.0  # as in Blender 4.2 (Blender 5 adds keys at 1: the pose on top of the preview's)
        kb.data.foreach_set("co", np.asarray(X, np.float32).ravel())
        obj.data.update()
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_bind_markers(_Interactive, RunOperator, bpy.types.Operator):
    """Bind the selected take's markers to the nearest surface points of the active mesh at this frame"""
    bl_idname = "lengths_angles.bind_markers"
    bl_label = "Bind Markers"
    bl_options = {'REGISTER', 'UNDO'}

    align: BoolProperty(name="Align", default=False,
                        description="Rigidly align the markers to the mesh first (iterative closest points, up to "
                                    f"{ALIGN_ITERATIONS} iterations); off: bind them where they are")
    warn_distance: FloatProperty(name="Warn Distance (m)", default=0.05, min=0.0, soft_max=0.5, precision=3,
                                 step=0.1,
                                 description="Warn about markers farther than this from the surface, in metres of "
                                             "the performer (the take's import Scale says how long a metre is; "
                                             "without it the scene's Unit Scale)")

    def execute(self, context):
        def make(context):
            take, labels = _take_of(list(context.selected_objects))
            return bind_run(context, context.active_object, take, labels, align=self.align,
                            warn_distance=self.warn_distance)
        return self.start_run(context, make)


class LENGTHS_ANGLES_OT_fit_markers(_Interactive, FitSettings, RunOperator, bpy.types.Operator):
    """Fit the shape model to the bound markers over the frame range (Esc cancels)"""
    bl_idname = "lengths_angles.fit_markers"
    bl_label = "Fit to Markers"
    bl_options = {'REGISTER', 'UNDO'}

    output: EnumProperty(name="Output", default='PC2', description="Where the fitted frames go", items=[
        ('PC2', "Point Cache", "PC2 file next to the .blend played by a Mesh Cache modifier (any length)"),
        ('SHAPE_KEYS', "Shape Keys", f"One keyed shape key per frame (at most {MAX_SHAPE_KEY_FRAMES} frames)")])
    use_scene_range: BoolProperty(name="Scene Frame Range", default=True,
                                  description="Fit the scene's frame range (off: Start to End)")
    frame_start: IntProperty(name="Start", default=1, description="First frame to fit (without Scene Frame Range)")
    frame_end: IntProperty(name="End", default=250, description="Last frame to fit (without Scene Frame Range)")
    prior_weight: FloatProperty(name="Prior Weight", default=_DEFAULT_PRIOR, min=1e-9, soft_max=100.0,
                                description="How strongly poses are held to the shape model against the markers "
                                            "(scale-free: the same in any unit); larger gives more model-like poses")
    temporal_weight: FloatProperty(name="Temporal Weight", default=float(FIT_DEFAULTS.temporal_weight), min=0.0,
                                   soft_max=100.0,
                                   description="Damps jitter between frames (the previous pose extrapolated; no lag "
                                               "on steady motion); 0: none")
    filepath: StringProperty(name="Cache File", default="", subtype='FILE_PATH', options=BLEND_RELATIVE_PATH,
                             description="Point cache to write ('//' is the folder of the .blend); empty: "
                                         "//<object>_<take>.pc2 next to the .blend")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "output")
        draw_frame_range(layout, self)
        layout.prop(self, "prior_weight")
        layout.prop(self, "temporal_weight")
        draw_fit_settings(layout, self)
        row = layout.row()
        row.active = self.output == 'PC2'
        row.prop(self, "filepath")

    def execute(self, context):
        def make(context):
            scene = context.scene
            start, end = ((scene.frame_start, scene.frame_end) if self.use_scene_range
                          else (self.frame_start, self.frame_end))
            return fit_run(context, context.active_object, start, end, output=self.output,
                           prior_weight=typed(self.prior_weight), temporal_weight=typed(self.temporal_weight),
                           filepath=self.filepath, **self.fit_settings())
        return self.start_run(context, make)


classes = (LENGTHS_ANGLES_OT_build_model, LENGTHS_ANGLES_OT_model_pose_to_shape_key, LENGTHS_ANGLES_OT_bind_markers,
           LENGTHS_ANGLES_OT_fit_markers)


def register_properties():
    bpy.types.Object.lengths_angles_mode_weights = FloatVectorProperty(
        name="Mode Weights", size=MAX_MODES, default=[0.0] * MAX_MODES, soft_min=-3.0, soft_max=3.0,
        update=_mode_weights_changed, override={'LIBRARY_OVERRIDABLE'},
        description="Shape-model coefficients in standard deviations: dragging previews the pose in the "
                    f"shape key '{PREVIEW_KEY}' (at most every {PREVIEW_INTERVAL} s); Model Pose to Shape Key keeps it")
    if _on_save_pre not in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.append(_on_save_pre)


def unregister_properties():
    if _on_save_pre in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.remove(_on_save_pre)
    del bpy.types.Object.lengths_angles_mode_weights
