# SPDX-License-Identifier: GPL-3.0-or-later
"""Shape model, marker binding and marker fitting in Blender (glue only: the mathematics is lacore's).

Operators
---------
``lengths_angles.build_model``
    Builds a :class:`..lacore.models.shape_model.ShapeModel` from the active mesh's shape
    keys (default all but the basis; ``keys`` a comma-separated list chooses), on the
    fan triangulation of :func:`.mesh_access.triangulate`.  The model is stored IN
    THE .blend: ``mesh["lengths_angles_model"]`` holds the model's ``.npz``
    (:meth:`ShapeModel.save`) base64-encoded in a string ID property, plus the key
    names and vertex count; it survives save/reload and is read back by
    :func:`read_model`.
Mode sliders
    Dragging a slider previews its pose: at most every :data:`PREVIEW_INTERVAL` seconds (a timer) the
    pose is synthesized (:meth:`ShapeModel.synthesize`, one reconstruction) into the shape key
    :data:`PREVIEW_KEY` at value 1 (keys named ``"LA ..."`` are never training keys).
``lengths_angles.model_pose_to_shape_key``
    Writes the pose of the mode sliders (``object.lengths_angles_mode_weights``, in
    standard deviations; the panel shows one slider per mode) as a new shape key,
    synthesized by :meth:`ShapeModel.synthesize`.
``lengths_angles.bind_markers``
    Binds the take's marker empties (the active/selected take empty, or the selected
    marker empties) to the active mesh at the current frame: each marker to the
    nearest surface point of the evaluated mesh with its signed normal offset
    (:func:`..lacore.markers.binding.bind_markers`, ``align=False`` by default: the
    markers are where the mesh is).  Stored on the object in
    ``obj["lengths_angles_binding"]`` (take, labels, empties, triangles of the fan
    triangulation, barycentric coordinates, offsets, distances); the panel lists
    each marker with its offset and warns about markers farther than
    ``warn_distance`` from the surface.
``lengths_angles.fit_markers``
    Fits the frame range.  Marker positions are read from the empties' F-curves in
    bulk (:func:`.operators_markers.read_take`, no ``frame_set``), mapped into the
    object's space and passed to :func:`..lacore.markers.fitting.fit_markers`.
    Interactively it runs MODAL: the fit runs in a worker thread (only lacore, no
    bpy), a timer updates the progress bar and Esc cancels through lacore's progress
    callback.  In background mode (``blender -b``) it runs synchronously.
    Output (``output``):

    * ``'PC2'`` (default, any length): a PC2 point cache ``//<object>_<take>.pc2``
      next to the .blend (the blend must be saved) played by a Mesh Cache modifier
      named ``"LA Fit"`` with ``frame_start`` = the first fitted frame and
      ``frame_scale`` 1, so scene frame ``f`` shows fitted frame ``f`` (the modifier is added last in
      the stack: move it first if other modifiers change the vertex count);
    * ``'SHAPE_KEYS'`` (clips of at most :data:`MAX_SHAPE_KEY_FRAMES` frames): one
      shape key per frame, keyed 0/1/0 around its frame (CONSTANT).

    The object's mesh data is untouched by the PC2 output.  A failed or cancelled
    fit changes nothing: no file, no modifier, no key (frames fitted before a cancel
    are discarded).
"""

import base64
import io
import os
import tempfile
import threading

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, StringProperty

from ..lacore.errors import InputError
from ..lacore.markers.binding import MarkerBinding, bind_markers
from ..lacore.markers.fitting import fit_markers
from ..lacore.io.point_cache import write_pc2
from ..lacore.progress import Cancelled
from ..lacore.models.shape_model import ShapeModel
from .compat import ensure_animation_channels
from .mesh_access import read_shape_keys, require_mesh_object, triangulate
from .operators_markers import MARKER_PROP, TAKE_PROP, marker_objects, read_take

__all__ = ["MODEL_PROP", "BINDING_PROP", "MAX_MODES", "MAX_SHAPE_KEY_FRAMES", "MODIFIER_NAME", "build_model",
           "store_model", "read_model", "read_binding", "bind", "FitJob", "classes"]

MODEL_PROP = "lengths_angles_model"
BINDING_PROP = "lengths_angles_binding"
MAX_MODES = 32
MAX_SHAPE_KEY_FRAMES = 100
MODIFIER_NAME = "LA Fit"


class FitSetupError(InputError):
    """Input of the Blender fitting operators that cannot be used (no model, no binding, ...)."""


# ---------------------------------------------------------------------------------------------- model
def build_model(obj, keys=None, n_modes=None):
    """A ShapeModel of the mesh ``obj`` from shape keys ``keys`` (default all but the basis)."""
    mesh = require_mesh_object(obj)
    names, coords = read_shape_keys(mesh)
    if keys is None:  # all but the basis and the add-on's own keys ("LA model preview", "LA fit <f>")
        keys = [k for k in names[1:] if not k.startswith("LA ")]
    missing = [k for k in keys if k not in names]
    if missing:
        raise FitSetupError(f"mesh '{mesh.name}' has no shape key(s) {', '.join(map(repr, missing))}")
    if len(keys) < 2:
        raise FitSetupError(f"mesh '{mesh.name}': a model needs at least 2 training shape keys, got {len(keys)}")
    tri = triangulate(mesh)
    poses = coords[[names.index(k) for k in keys]]
    model = ShapeModel.fit(poses, tri.faces, reference_vertices=coords[0], n_modes=n_modes)
    return model, list(keys)


def store_model(mesh, model, keys):
    """Store ``model`` in ``mesh[MODEL_PROP]`` (base64 .npz; saved with the .blend)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "model.npz")
        model.save(path)
        with open(path, "rb") as fh:
            data = base64.b64encode(fh.read()).decode("ascii")
    mesh[MODEL_PROP] = {"npz_base64": data, "keys": list(keys), "n_vertices": len(mesh.vertices),
                        "n_modes": int(model.n_modes)}


_MODEL_CACHE = {}


def read_model(obj):
    """The ShapeModel stored on ``obj``'s mesh, checked against the mesh as it is now."""
    mesh = require_mesh_object(obj)
    meta = mesh.get(MODEL_PROP)
    if meta is None:
        raise FitSetupError(f"mesh '{mesh.name}' has no shape model: run Build Model first")
    data = meta["npz_base64"]
    key = (mesh.name_full, hash(data))
    model = _MODEL_CACHE.get(key)
    if model is None:  # decoded once per stored model (the sliders' preview reads it often)
        model = ShapeModel.load(io.BytesIO(base64.b64decode(data)))
        _MODEL_CACHE.clear()
        _MODEL_CACHE[key] = model
    faces = triangulate(mesh).faces
    if len(mesh.vertices) != int(meta["n_vertices"]) or not np.array_equal(faces, model.faces):
        raise FitSetupError(f"mesh '{mesh.name}' was edited after its model was built ({len(mesh.vertices)} vertices "
                            f"now, {int(meta['n_vertices'])} then, or other faces): build the model again")
    return model


def _mesh_vertices(obj, depsgraph):
    """(V, 3) float64 positions of the evaluated ``obj`` in its own space (V of its mesh data)."""
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        V = len(me.vertices)
        co = np.empty(3 * V, np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    if V != len(obj.data.vertices):
        raise FitSetupError(f"object '{obj.name}': its modifiers change the vertex count ({V} evaluated, "
                            f"{len(obj.data.vertices)} in the mesh): bind with those modifiers off")
    return co.reshape(V, 3).astype(np.float64)


# -------------------------------------------------------------------------------------------- preview
PREVIEW_KEY = "LA model preview"
PREVIEW_INTERVAL = 0.2  # seconds: the slider preview is recomputed at most this often
_PENDING_PREVIEWS = set()


def preview_pose(obj):
    """Write the mode sliders' pose (``ShapeModel.synthesize``) into the shape key :data:`PREVIEW_KEY` (at 1)."""
    model = read_model(obj)
    w = np.array(obj.lengths_angles_mode_weights[:model.n_modes], np.float64)
    X = model.synthesize(w * model.standard_deviations)
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    kb = obj.data.shape_keys.key_blocks.get(PREVIEW_KEY) or obj.shape_key_add(name=PREVIEW_KEY, from_mix=False)
    kb.data.foreach_set("co", np.asarray(X, np.float32).ravel())
    kb.value = 1.0
    obj.data.update()
    return X


def update_previews():
    """Timer callback: recompute the previews of the objects whose sliders moved (rate limit)."""
    names = sorted(_PENDING_PREVIEWS)
    _PENDING_PREVIEWS.clear()
    for name in names:
        obj = bpy.data.objects.get(name)
        if obj is not None and obj.type == 'MESH' and MODEL_PROP in obj.data:
            try:
                preview_pose(obj)
            except InputError as exc:  # e.g. mesh edited since the model: no preview
                print(f"Lengths & Angles preview of '{name}': {exc}")
    return None


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


def bind(context, obj, take, labels=None, align=False):
    """Bind markers of ``take`` (``labels`` or all) to ``obj`` at the current frame; stores the binding."""
    mesh = require_mesh_object(obj)
    model = read_model(obj)
    all_labels = [lb for lb, _ in marker_objects(take)]
    labels = all_labels if labels is None else [lb for lb in all_labels if lb in labels]
    idx = [all_labels.index(lb) for lb in labels]
    frame = context.scene.frame_current
    world = read_take(take, frames=[frame]).positions[0][idx]
    hidden = [lb for lb, x in zip(labels, world, strict=True) if not np.isfinite(x).all()]
    if hidden:
        raise FitSetupError(f"markers {', '.join(map(repr, hidden[:5]))} are occluded at frame {frame}: "
                            "bind at a frame where all are visible (or select the visible ones)")
    inv = np.linalg.inv(np.array(obj.matrix_world, np.float64))
    local = world @ inv[:3, :3].T + inv[:3, 3]
    X = _mesh_vertices(obj, context.evaluated_depsgraph_get())
    binding, info = bind_markers(X, model.faces, local, align=align)
    empties = {lb: o.name for lb, o in marker_objects(take)}
    obj[BINDING_PROP] = {
        "take": take.name, "labels": labels, "empties": [empties[lb] for lb in labels], "frame": frame,
        "faces": binding.faces.tolist(), "barycentric": binding.barycentric.ravel().tolist(),
        "offsets": binding.offsets.tolist(), "n_vertices": len(mesh.vertices),
    }
    return binding, info


def read_binding(obj):
    """``(MarkerBinding, take object, labels)`` stored on ``obj``, checked against the scene."""
    meta = obj.get(BINDING_PROP)
    if meta is None:
        raise FitSetupError(f"object '{obj.name}' has no marker binding: run Bind Markers first")
    take = bpy.data.objects.get(meta["take"])
    if take is None or TAKE_PROP not in take:
        raise FitSetupError(f"object '{obj.name}': the bound take '{meta['take']}' is gone: bind again")
    present = {lb for lb, _ in _marker_pairs(take)}
    labels = list(meta["labels"])
    missing = [lb for lb, name in zip(labels, meta["empties"], strict=True)
               if lb not in present or name not in bpy.data.objects]
    if missing:
        raise FitSetupError(f"object '{obj.name}': the empties of bound markers {', '.join(map(repr, missing[:5]))} "
                            "were deleted: bind again")
    binding = MarkerBinding.from_surface(np.asarray(meta["faces"], np.int64),
                                         np.asarray(meta["barycentric"], np.float64).reshape(-1, 3),
                                         np.asarray(meta["offsets"], np.float64))
    return binding, take, labels


def _marker_pairs(take):
    return [(c[MARKER_PROP], c) for c in take.children if MARKER_PROP in c]


# ------------------------------------------------------------------------------------------------ fit
class FitJob:
    """One marker fit: set up in the main thread (reads Blender), solved by :meth:`run` (lacore only,
    any thread), written back by :meth:`finish` (main thread).  ``progress`` is ``(done, total)``;
    setting ``cancel`` stops :meth:`run` at the next frame (lacore.progress.Cancelled)."""

    def __init__(self, context, obj, frame_start, frame_end, output='PC2', prior_weight=1.0, temporal_weight=0.0,
                 filepath=""):
        self.obj = obj
        mesh = require_mesh_object(obj)
        self.model = read_model(obj)
        binding, take, labels = read_binding(obj)
        self.binding = binding
        frame_start, frame_end = int(frame_start), int(frame_end)
        if frame_end < frame_start:
            raise FitSetupError(f"empty frame range {frame_start}..{frame_end}")
        if output == 'SHAPE_KEYS' and frame_end - frame_start + 1 > MAX_SHAPE_KEY_FRAMES:
            raise FitSetupError(f"{frame_end - frame_start + 1} frames: shape keys are for clips of at most "
                                f"{MAX_SHAPE_KEY_FRAMES} frames, use the PC2 output")
        meta = take[TAKE_PROP]
        first = float(meta["frame_start"])
        last = first + (int(meta["keyed_samples"]) - 1) * float(meta["frame_step"])
        if frame_start < first - 1e-6 or frame_end > last + 1e-6:
            raise FitSetupError(f"take '{take.name}' covers frames {first:g}..{last:g}, fewer than the range "
                                f"{frame_start}..{frame_end}: set the frame range inside the take")
        self.frames = np.arange(frame_start, frame_end + 1)
        if output == 'PC2':
            if not filepath:
                if not bpy.data.filepath:
                    raise FitSetupError("save the .blend first: the point cache is written next to it")
                filepath = f"//{bpy.path.clean_name(obj.name)}_{bpy.path.clean_name(take.name)}.pc2"
            self.filepath = filepath
        all_labels = [lb for lb, _ in marker_objects(take)]
        world = read_take(take, frames=self.frames).positions[:, [all_labels.index(lb) for lb in labels]]
        inv = np.linalg.inv(np.array(obj.matrix_world, np.float64))
        self.markers = world @ inv[:3, :3].T + inv[:3, 3]
        self.output = output
        self.options = {"prior_weight": prior_weight, "temporal_weight": temporal_weight}
        self.n_vertices = len(mesh.vertices)
        self.progress = (0, len(self.frames))
        self.cancel = False
        self.result = None
        self.error = None

    def _progress(self, done, total, message=""):
        self.progress = (done, total)
        return self.cancel

    def run(self):
        """Solve (lacore only); errors and cancellation end up in ``self.error``."""
        try:
            self.result = fit_markers(self.model, self.markers, self.binding, progress=self._progress,
                                      **self.options)
        except Cancelled:
            self.error = "cancelled"
        except Exception as exc:  # reported by the operator, nothing written
            self.error = f"{type(exc).__name__}: {exc}"

    def finish(self, context):
        """Write the result to Blender (PC2 + Mesh Cache modifier, or shape keys); returns a message."""
        X = self.result.vertices
        obj = self.obj
        if self.output == 'PC2':
            path = bpy.path.abspath(self.filepath)
            write_pc2(path, X, start=float(self.frames[0]), sampling=1.0)
            mod = obj.modifiers.get(MODIFIER_NAME) or obj.modifiers.new(MODIFIER_NAME, 'MESH_CACHE')
            mod.cache_format = 'PC2'
            mod.filepath = self.filepath
            mod.time_mode = 'FRAME'
            mod.play_mode = 'SCENE'
            mod.frame_start = float(self.frames[0])  # scene frame f shows sample f - frame_start
            mod.frame_scale = 1.0
            mod.deform_mode = 'OVERWRITE'
            mod.interpolation = 'NONE'
            return f"fitted {len(self.frames)} frames to {self.filepath}"
        mesh = obj.data
        if mesh.shape_keys is None:
            obj.shape_key_add(name="Basis", from_mix=False)
        owner, _ = ensure_animation_channels(mesh.shape_keys, f"{obj.name} LA fit")
        for t, f in enumerate(self.frames):
            kb = obj.shape_key_add(name=f"LA fit {int(f)}", from_mix=False)
            kb.data.foreach_set("co", X[t].astype(np.float32).ravel())
            fc = owner.fcurves.new(f'key_blocks["{kb.name}"].value')
            kf = [(f - 1, 0.0), (f, 1.0), (f + 1, 0.0)]
            fc.keyframe_points.add(len(kf))
            fc.keyframe_points.foreach_set("co", np.array(kf, np.float32).ravel())
            for k in fc.keyframe_points:
                k.interpolation = 'CONSTANT'
        return f"fitted {len(self.frames)} frames as shape keys"


# ---------------------------------------------------------------------------------------------- operators
class LENGTHS_ANGLES_OT_build_model(bpy.types.Operator):
    """Build a shape model (lengths-and-angles PCA) from the mesh's shape keys and store it in the .blend"""
    bl_idname = "lengths_angles.build_model"
    bl_label = "Build Shape Model"
    bl_options = {'REGISTER', 'UNDO'}

    keys: StringProperty(name="Shape Keys", description="Comma-separated training keys; empty: all but the basis")
    n_modes: IntProperty(name="Modes", default=0, min=0, max=MAX_MODES, description="0: all (at most 32)")

    def execute(self, context):
        obj = context.active_object
        try:
            keys = [k.strip() for k in self.keys.split(",") if k.strip()] or None
            model, keys = build_model(obj, keys, n_modes=(self.n_modes or None))
            if model.n_modes > MAX_MODES:
                model, keys = build_model(obj, keys, n_modes=MAX_MODES)
            store_model(obj.data, model, keys)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        _PENDING_PREVIEWS.add(obj.name)
        obj.lengths_angles_mode_weights = [0.0] * MAX_MODES
        _PENDING_PREVIEWS.discard(obj.name)
        self.report({'INFO'}, f"shape model of {len(keys)} keys, {model.n_modes} modes")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_model_pose_to_shape_key(bpy.types.Operator):
    """Write the pose of the mode sliders as a new shape key"""
    bl_idname = "lengths_angles.model_pose_to_shape_key"
    bl_label = "Model Pose to Shape Key"
    bl_options = {'REGISTER', 'UNDO'}

    name: StringProperty(name="Name", default="Model pose")

    def execute(self, context):
        obj = context.active_object
        try:
            model = read_model(obj)
            w = np.array(obj.lengths_angles_mode_weights[:model.n_modes], np.float64)
            X = model.synthesize(w * model.standard_deviations)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        if obj.data.shape_keys is None:
            obj.shape_key_add(name="Basis", from_mix=False)
        kb = obj.shape_key_add(name=self.name, from_mix=False)
        kb.data.foreach_set("co", np.asarray(X, np.float32).ravel())
        obj.data.update()
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_bind_markers(bpy.types.Operator):
    """Bind the selected take's markers to the nearest surface points of the active mesh at this frame"""
    bl_idname = "lengths_angles.bind_markers"
    bl_label = "Bind Markers"
    bl_options = {'REGISTER', 'UNDO'}

    align: BoolProperty(name="Align", default=False, description="Rigidly align the markers to the mesh first (ICP)")
    warn_distance: FloatProperty(name="Warn Distance", default=0.05, min=0.0, subtype='DISTANCE',
                                 description="Warn about markers farther than this from the surface")

    def execute(self, context):
        obj = context.active_object
        try:
            take, labels = _take_of(list(context.selected_objects))
            binding, info = bind(context, obj, take, labels, align=self.align)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        far = np.flatnonzero(np.abs(binding.offsets) > self.warn_distance)
        names = obj[BINDING_PROP]["labels"]
        if far.size:
            self.report({'WARNING'}, f"{far.size} markers are farther than {self.warn_distance:g} from the surface: "
                        + ", ".join(names[i] for i in far[:8]))
        else:
            self.report({'INFO'}, f"bound {binding.n_markers} markers")
        return {'FINISHED'}


class LENGTHS_ANGLES_OT_fit_markers(bpy.types.Operator):
    """Fit the shape model to the bound markers over the frame range (Esc cancels)"""
    bl_idname = "lengths_angles.fit_markers"
    bl_label = "Fit to Markers"
    bl_options = {'REGISTER', 'UNDO'}

    output: EnumProperty(name="Output", default='PC2', items=[
        ('PC2', "Point Cache", "PC2 file next to the .blend played by a Mesh Cache modifier (any length)"),
        ('SHAPE_KEYS', "Shape Keys", f"One keyed shape key per frame (at most {MAX_SHAPE_KEY_FRAMES} frames)")])
    use_scene_range: BoolProperty(name="Scene Frame Range", default=True)
    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=250)
    prior_weight: FloatProperty(name="Prior Weight", default=1.0, min=1e-9)
    temporal_weight: FloatProperty(name="Temporal Weight", default=0.0, min=0.0)
    filepath: StringProperty(name="Cache File", default="", subtype='FILE_PATH',
                             description="Empty: //<object>_<take>.pc2 next to the .blend")

    _timer = None
    _thread = None
    _job = None

    def _make_job(self, context):
        scene = context.scene
        start, end = ((scene.frame_start, scene.frame_end) if self.use_scene_range
                      else (self.frame_start, self.frame_end))
        return FitJob(context, context.active_object, start, end, output=self.output,
                      prior_weight=self.prior_weight, temporal_weight=self.temporal_weight, filepath=self.filepath)

    def _finish(self, context, job):
        if job.error is not None:
            self.report({'WARNING'} if job.error == "cancelled" else {'ERROR'},
                        f"fit {job.error}: nothing changed")
            return {'CANCELLED'}
        try:
            self.report({'INFO'}, job.finish(context))
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        return {'FINISHED'}

    def execute(self, context):
        try:
            job = self._make_job(context)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        job.run()
        return self._finish(context, job)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            self._job = self._make_job(context)
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        self._thread = threading.Thread(target=self._job.run, daemon=True)
        self._thread.start()
        wm = context.window_manager
        wm.progress_begin(0, self._job.progress[1])
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        return {'RUNNING_MODAL'}

    def modal(self, context, event):
        wm = context.window_manager
        if event.type == 'ESC':
            self._job.cancel = True
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        wm.progress_update(self._job.progress[0])
        if self._thread.is_alive():
            return {'RUNNING_MODAL'}
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
        wm.progress_end()
        return self._finish(context, self._job)


classes = (LENGTHS_ANGLES_OT_build_model, LENGTHS_ANGLES_OT_model_pose_to_shape_key, LENGTHS_ANGLES_OT_bind_markers,
           LENGTHS_ANGLES_OT_fit_markers)


def register_properties():
    bpy.types.Object.lengths_angles_mode_weights = FloatVectorProperty(
        name="Mode Weights", size=MAX_MODES, default=[0.0] * MAX_MODES, soft_min=-3.0, soft_max=3.0,
        update=_mode_weights_changed,
        description="Shape-model coefficients in standard deviations: dragging previews the pose in the "
                    f"shape key '{PREVIEW_KEY}' (at most every {PREVIEW_INTERVAL} s); Model Pose to Shape Key keeps it")


def unregister_properties():
    del bpy.types.Object.lengths_angles_mode_weights
