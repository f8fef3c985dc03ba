# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: in-betweens of two shape keys, baked keyframe in-betweens and Clear Bake (thesis 4.2).

In-betweens and Bake read the shape keys, compute every frame with lacore (linear or cubic spline
in lengths and angles, then projection onto admissible lengths and angles by reconstruction:
:class:`.jobs.ProjectionJob`) and only then write to Blender, through one background-run mechanism
(:mod:`.runs`: modal with progress and Esc from the UI, synchronous from scripts; the object is
checked for changes before anything is written).  Any error is reported as ERROR and returns
CANCELLED with the object unchanged.  Names of the new keys: :mod:`.naming`; the bake's keys,
keyframes and record: :mod:`.bake`.

Results that fail their checks
------------------------------
A reconstruction whose result fails its checks (``success=False``: folded faces, or a minimizer
that did not converge) is still written -- it is the best shape the method found, Blender's undo
removes it, and hiding it would leave the user with nothing to inspect -- and the operator reports
a WARNING naming how many frames failed and the first failure (:func:`.runs.failure_warning`)
instead of the INFO line.  For 'PREVIEW' (the least-squares relaxation, which minimizes nothing) a
non-admissible target that is merely not reproduced is expected and not reported; folds are.

Output placement
----------------
A reconstruction is determined up to a rigid motion.  Every result is placed by a rigid (Kabsch)
fit to the *linear blend of the key coordinates* at the same time (``(1 - t) A + t B`` for
In-betweens, the piecewise-linear blend of the keyframed keys for Bake).  So the in-betweens follow
the keys without drifting or rotating about a single fixed triangle; at ``t = 0`` and ``t = 1``
they coincide with the keys themselves (up to float32 round-off).

Script defaults
---------------
Called from a script with no arguments, both operators do what the dialog proposes: the reference
key and the active key (the first other key that is not an add-on key when the reference is
active), Bake from the current frame every *Frames Between Keys* frames.  Typed keys without typed
frames are placed the same way.
"""

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..lacore.errors import InputError
from ..lacore.reconstruction.settings import FAST
from ..lacore.shapes.mixing.path import PathOptions
from ..lacore.shapes.projection import ProjectionOptions
from . import bake, jobs, live_mix, mesh_access, session
from .naming import (OperatorInputError, inbetween_key_name, is_own_key, parse_factors, parse_frames,
                     parse_key_list)
from .runs import ObjectWatch, Run, RunOperator

__all__ = ["LENGTHS_ANGLES_OT_interpolate", "LENGTHS_ANGLES_OT_bake_keyframes", "LENGTHS_ANGLES_OT_clear_bake",
           "classes", "METHOD_ITEMS", "METHOD_OPTIONS", "inbetween_run", "bake_run", "interpolate_object",
           "bake_object", "inbetween_shapes", "read_mesh", "key_items", "key_flag_items", "default_pair",
           "default_method", "mixer_note"]

NO_KEY = "__NONE__"
MAX_NEW_KEYS = 1000

METHOD_ITEMS = [
    ('PREVIEW', "Preview", "Least-squares relaxation of the frame-based reconstruction only (one linear solve "
                           "over the whole mesh): quickest, edge lengths within ~1.5 % on strong blends"),
    ('FAST', "Fast", "Each in-between starts from the extrapolation of the ones before it and takes one "
                     "Gauss-Newton step, more where the step does not behave as predicted: the exact projection "
                     "on smooth motions at one solve per in-between (strongly mixed blends, such as a bend into a "
                     "twist, are closer with Gauss-Newton)"),
    ('GAUSS_NEWTON', "Gauss-Newton", "Energy-based projection: Gauss-Newton run to convergence (slowest, "
                                     "most accurate)"),
    ('PATH', "Path", "A reduced model of the path between the two keys: a few sparse solves for all in-betweens "
                     "(the default at 5,000 vertices and more), each with an error estimate; in-betweens whose "
                     "estimate is above 0.3 % of the mesh size are computed by Fast or Gauss-Newton instead. Not "
                     "with Spline"),
    ('MIXER', "Live Mixer", "One mix of the mesh's live mixer per in-between (the default when the mesh mixes "
                            "live and its mixer is up to date and mixes the keys): milliseconds per in-between, "
                            "close to Gauss-Newton within the keys' range"),
]
#: How each Method item computes its frames: lacore's projection options, or (``'MULTIRES'``, not offered in the
#: UI: coarse solve, prolongation, three fine Gauss-Newton steps, the hierarchy built once per keys) the keywords of
#: :meth:`lacore.multiresolution.MultiresolutionReconstruction.reconstruct`.  FAST is lacore's preset
#: :data:`lacore.reconstruction.settings.FAST` (also the CLI's and the library's default): continuation along t
#: and one Gauss-Newton step per in-between, more where a step does not agree with its quadratic model.
METHOD_OPTIONS = {
    'PREVIEW': ProjectionOptions(method="lsq"),
    'FAST': ProjectionOptions(FAST.name),
    'GAUSS_NEWTON': ProjectionOptions(method="gn"),
    'MULTIRES': {"fine_iterations": 3, "fine_solver": "exact"},
    'PATH': PathOptions(),
}

#: Path is the default method (when the mesh has no live mixer of the keys and the motion is piecewise linear)
#: from this many vertices: at 50,000 vertices it computes 10 in-betweens with two factorizations instead of
#: Fast's one or more per in-between (benchmarks/bench_blender_mixer_inbetweens.py).
PATH_MIN_VERTICES = 5000

PROCESSES_DESCRIPTION = (
    f"Frames computed side by side in this many processes, each starting next to a key (each process builds "
    f"its own solver, about 2-4 s and one more solver's memory at 50,000 vertices). 0 = Auto: one per CPU core "
    f"(at most 4) for meshes of {jobs.AUTO_WORKERS_MIN_VERTICES:,} vertices or more with at least "
    f"{jobs.AUTO_WORKERS_MIN_FRAMES} frames to compute, else 1")


# ----------------------------------------------------------------------------- plans (nothing written)
def read_mesh(obj):
    """Validated ``(mesh, names, coords (K, V, 3), topology)`` of a mesh object with shape keys (session cache)."""
    data = session.read_mesh(obj, "interpolated")
    return data.mesh, data.names, data.coords, data.topology


def _require_keys(names, wanted, what):
    missing = [w for w in wanted if w not in names]
    if missing:
        shown = ", ".join(f"'{m}'" for m in missing)
        have = ", ".join(f"'{n}'" for n in names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
        raise OperatorInputError(f"{what}: no shape key {shown} (the mesh has {have})")


def _job(data, keys, keyframes, times, smooth, method, workers=1, obj=None):
    if method == 'MIXER':
        try:
            mixer, weights, token, lock = live_mix.mixer_for_keys(obj, keys)
        except InputError as exc:
            raise OperatorInputError(f"Method Live Mixer: {exc}; or choose Fast or Gauss-Newton") from None
        return jobs.MixerJob(data, keys, keyframes, times, smooth, method, mixer, weights, token, lock)
    if method == 'PATH':
        if smooth:
            raise OperatorInputError("Method Path follows straight lines between the keys' lengths and angles: turn "
                                     "Spline off or choose Fast or Gauss-Newton")
        return jobs.PathJob(data, keys, keyframes, times, METHOD_OPTIONS['PATH'], method)
    lacore_method = jobs.MULTIRES if method == 'MULTIRES' else METHOD_OPTIONS[method].method
    return jobs.projection_job(data, keys, keyframes, times, smooth, lacore_method, METHOD_OPTIONS[method], method,
                               workers)


def _inbetween_plan(obj, key_from, key_to, factors, method, workers=1):
    """Validate and set up in-betweens: ``(data, names of the new keys, job)``; nothing written."""
    data = session.read_mesh(obj, "interpolated")
    mesh_access.require_writable_keys(data.mesh, "make the in-betweens")
    if not key_from or not key_to or NO_KEY in (key_from, key_to):
        raise OperatorInputError("Choose the two shape keys to interpolate between (From and To)")
    if key_from == key_to:
        raise OperatorInputError(f"From and To are the same shape key '{key_from}': choose two different keys")
    _require_keys(data.names, [key_from, key_to], f"Mesh '{data.mesh.name}'")
    mesh_access.require_whole_keys(data.mesh, [key_from, key_to], "In-betweens")
    out_names = [inbetween_key_name(key_from, key_to, t) for t in factors]
    seen = {}
    for t, n in zip(factors, out_names, strict=True):
        if n in seen and seen[n] != t:
            raise OperatorInputError(f"Factors {seen[n]:g} and {t:g} give the same key name '{n}' "
                                     "(3 decimals): use factors that differ in the first 3 decimals")
        seen[n] = t
    clash = [n for n in out_names if n in (key_from, key_to)]
    if clash:
        raise OperatorInputError(f"The result '{clash[0]}' would overwrite one of the input keys")
    unique = list(dict.fromkeys(out_names))
    if len(unique) > MAX_NEW_KEYS:
        raise OperatorInputError(f"{len(unique)} in-betweens requested; at most {MAX_NEW_KEYS}")
    job = _job(data, [key_from, key_to], [0.0, 1.0], [seen[n] for n in unique], False, method, workers, obj)
    return data, unique, job


def _bake_plan(obj, keys, frames, smooth, method, workers=1):
    """Validate a bake and set it up: ``(data, plan without shapes, job or None)``; nothing written."""
    mesh_access.require_writable_keys(mesh_access.require_mesh_object(obj), "bake")
    inbetween = bake.bake_frames(keys, frames)
    data = session.read_mesh(obj, "interpolated")
    plan = bake.check_bake(obj, data.names, keys, frames)
    mesh_access.require_whole_keys(data.mesh, keys, "Bake")
    job = _job(data, keys, frames, inbetween, smooth, method, workers, obj) if inbetween else None
    return data, plan, job


def _check_finite(results, what):
    for name, X in results:
        if not np.all(np.isfinite(X)):
            raise OperatorInputError(f"{what}: the reconstruction of '{name}' is not finite (the lengths "
                                     "and angles are too far from any shape; try smaller factors)")


def inbetween_run(obj, key_from, key_to, factors, method='FAST', workers=1):
    """A :class:`.runs.Run` of in-betweens (validated; raises InputError subclasses); ``workers``: processes
    (:func:`.jobs.job_workers`, 0 = Auto)."""
    _data, names, job = _inbetween_plan(obj, key_from, key_to, factors, method, workers)

    def write(obj, job):
        results = list(zip(names, job.results, strict=True))
        _check_finite(results, "Interpolate")
        existing = set(mesh_access.key_names(obj.data))
        with mesh_access.object_mode(obj):
            for name, X in results:
                mesh_access.set_shape_key(obj, name, X)
            obj.data.update()
        replaced = sum(name in existing for name, _ in results)
        summary = getattr(job, "summary", "")
        return (f"{len(results)} in-between key{'s' if len(results) != 1 else ''} '{key_from}' > '{key_to}'"
                + (f" ({replaced} replaced)" if replaced else "") + (f"; {summary}" if summary else ""))
    return Run(job, ObjectWatch(obj, [key_from, key_to]), write, what="in-between")


def bake_run(obj, keys, frames, smooth=False, method='FAST', playback='STEPPED', workers=1):
    """A :class:`.runs.Run` of a bake (validated; raises InputError subclasses); ``workers`` as in
    :func:`inbetween_run`."""
    _data, plan, job = _bake_plan(obj, keys, frames, smooth, method, workers)

    def write(obj, job):
        full = bake.complete_bake(plan, job.results)
        with mesh_access.object_mode(obj):
            bake.write_bake(obj, full, {"keys": list(keys), "frames": list(frames), "smooth": bool(smooth),
                                        "method": method, "playback": playback}, playback)
        return (f"Baked {len(full['keys'])} in-between keys for frames {frames[0]}..{frames[-1]} "
                f"({'cubic spline' if smooth else 'piecewise linear'} in lengths and angles, "
                f"{playback.lower()} playback)")
    watch = ObjectWatch(obj, keys, extras={f"The shape-key list of '{obj.name}'": _key_names_of(obj.name)})
    return Run(job or jobs.DoneJob(), watch, write, what="baked frame")


def _key_names_of(name):
    """Getter of the key names of the object ``name`` now (empty if it is gone)."""
    def names():
        obj = bpy.data.objects.get(name)
        return () if obj is None or obj.type != 'MESH' else tuple(mesh_access.key_names(obj.data))
    return names


def interpolate_object(obj, key_from, key_to, factors, method='FAST', progress=None, failures=None):
    """Compute in-betweens of two shape keys WITHOUT touching Blender data.

    Returns a list of ``(key name, (V, 3) float64 coordinates)``, one per factor, placed as described
    in the module docstring.  Raises :class:`lacore.errors.InputError` subclasses for unusable input.
    """
    _data, names, job = _inbetween_plan(obj, key_from, key_to, factors, method)
    results = list(zip(names, jobs.run_job(job, progress).results, strict=True))
    if failures is not None:
        failures.extend(job.failures)
    return results


def inbetween_shapes(topology, A, B, factors, method='FAST', progress=None, failures=None):
    """The placed in-betweens ``[(V, 3)]`` of the shapes ``A`` (t = 0) and ``B`` (t = 1) at ``factors``.

    ``failures`` (a list, optional) collects the frames failing their checks.
    """
    A, B = np.asarray(A, float), np.asarray(B, float)
    data = session.MeshData(mesh=None, names=["A", "B"], coords=np.stack([A, B]), topology=topology,
                            topology_hash=session.topology_hash(topology.faces, topology.edges, topology.n_vertices),
                            key_hashes=[session.coords_hash(A), session.coords_hash(B)])
    job = jobs.run_job(_job(data, ["A", "B"], [0.0, 1.0], factors, False, method), progress)
    if failures is not None:
        failures.extend(job.failures)
    return job.results


def bake_object(obj, keys, frames, smooth=False, method='FAST', progress=None, failures=None):
    """Compute a bake WITHOUT touching Blender data: the plan of :func:`.bake.check_bake` with ``keys``
    (``[(name, (V, 3) coordinates)]`` of the baked in-betweens, by frame).  Raises
    :class:`lacore.errors.InputError` subclasses for unusable input."""
    _data, plan, job = _bake_plan(obj, keys, frames, smooth, method)
    shapes = jobs.run_job(job, progress).results if job is not None else []
    if failures is not None and job is not None:
        failures.extend(job.failures)
    return bake.complete_bake(plan, shapes)


# ----------------------------------------------------------------------------- defaults and key pickers
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


def default_pair(obj):
    """(reference key, active key or the first other key that is not an add-on key), or None."""
    key = obj.data.shape_keys if obj is not None and obj.type == 'MESH' else None
    if key is None or key.reference_key is None or len(key.key_blocks) < 2:
        return None
    ref = key.reference_key.name
    active = obj.active_shape_key.name if obj.active_shape_key is not None else ref
    if active == ref or is_own_key(active):
        active = next((kb.name for kb in key.key_blocks if kb.name != ref and not is_own_key(kb.name)), None)
    return None if active is None else (ref, active)


def default_method(obj, keys, smooth=False):
    """'MIXER' when ``obj`` has an up-to-date live mixer that mixes ``keys``, else 'PATH' for a piecewise-linear
    motion of a mesh of at least :data:`PATH_MIN_VERTICES` vertices, else 'FAST'."""
    try:
        live_mix.mixer_for_keys(obj, keys)
    except InputError:
        big = obj is not None and obj.type == 'MESH' and len(obj.data.vertices) >= PATH_MIN_VERTICES
        return 'PATH' if big and not smooth else 'FAST'
    return 'MIXER'


def mixer_note(obj, keys):
    """Why a live mesh's mixer cannot compute these in-betweens (the dialog shows it under Method), else None."""
    if obj is None or obj.type != 'MESH' or not live_mix.is_live(obj.data):
        return None
    try:
        live_mix.mixer_for_keys(obj, keys)
    except InputError as exc:
        return f"Live Mixer not available: {exc}"
    return None


def _draw_mixer_note(layout, obj, keys):
    note = mixer_note(obj, keys)
    if note:
        layout.label(text=note, icon='INFO')


def _warn_transform(op, obj):
    """Lengths and angles are measured in the mesh's own coordinates; warn if the object scales non-uniformly."""
    if obj is None or obj.type != 'MESH':
        return
    s = [abs(v) for v in obj.matrix_world.to_scale()]
    if max(s) > 0 and (max(s) - min(s)) > 1e-4 * max(s):
        op.report({'WARNING'}, f"Object '{obj.name}' has a non-uniform scale ({s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g}): "
                               "lengths and angles are measured in the mesh's own coordinates, ignoring the object's "
                               "transform (Apply Scale, Ctrl+A, to use the displayed shape)")


# ----------------------------------------------------------------------------- operators
class LENGTHS_ANGLES_OT_interpolate(RunOperator, bpy.types.Operator):
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
                       default=3, min=1, soft_max=50, max=min(MAX_NEW_KEYS, 999))   # names keep 3 decimals
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
        _draw_mixer_note(layout, context.object, [self.key_from, self.key_to])
        layout.prop(self, "processes")

    def _fill_defaults(self, obj):
        pair = default_pair(obj)
        if pair is None:
            return
        if not self.properties.is_property_set("key_from"):
            self.key_from = pair[0]
        if not self.properties.is_property_set("key_to"):
            self.key_to = pair[1]
        if not self.properties.is_property_set("method"):
            self.method = default_method(obj, [self.key_from, self.key_to])

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

        def make(context):
            run = inbetween_run(context.object, self.key_from, self.key_to, self._factors(), self.method,
                                workers=self.processes)
            _warn_transform(self, context.object)
            return run
        return self.start_run(context, make)


class LENGTHS_ANGLES_OT_bake_keyframes(RunOperator, bpy.types.Operator):
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
                                     "overrides Keys")
    frames: StringProperty(name="Frames (typed)", options={'SKIP_SAVE'},
                           description="For scripts: the frame of every key, strictly increasing, e.g. \"1, 12, 24\"; "
                                       "overrides Start Frame and Frames Between Keys")
    smooth: BoolProperty(name="Spline", default=False,
                         description="Cubic spline through the keys' lengths and angles (otherwise piecewise linear)")
    playback: EnumProperty(name="Playback", items=bake.PLAYBACK_ITEMS, default='STEPPED',
                           description="Interpolation of the keyframes on the key values")
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default='FAST',
                         description="How the interpolated lengths and angles are turned into a shape")
    processes: IntProperty(name="Processes", default=0, min=0, max=8, description=PROCESSES_DESCRIPTION)

    @classmethod
    def poll(cls, context):
        return True

    def _fill_defaults(self, context):
        """What the dialog proposes, also for scripts: the reference and the active key, the current frame."""
        pair = default_pair(context.object)
        if not self.keys.strip() and not self.properties.is_property_set("key_set") and pair is not None:
            self.key_set = set(pair)
        if not self.properties.is_property_set("frame_start"):
            self.frame_start = context.scene.frame_current

    def bake_inputs(self, obj):
        """``(keys, frames)`` of this bake: typed keys, else the picked keys (in key-list order); typed frames,
        else from Start Frame every Frames Between Keys."""
        if self.keys.strip():
            names = parse_key_list(self.keys, mesh_access.key_names(obj.data)
                                    if obj is not None and obj.type == 'MESH' else ())
        else:
            names = [n for n in (mesh_access.key_names(obj.data) if obj is not None and obj.type == 'MESH' else [])
                     if n in self.key_set]
        if self.frames.strip():
            return names, parse_frames(self.frames)
        return names, [self.frame_start + i * self.frame_step for i in range(len(names))]

    def summary(self, obj):
        try:
            keys, frames = self.bake_inputs(obj)
        except InputError as exc:
            return str(exc)
        return bake.bake_summary(obj, keys, frames)

    def draw(self, context):
        layout = self.layout
        if self.keys.strip():
            layout.prop(self, "keys")
        else:
            layout.label(text="Keys")
            layout.column(align=True).prop(self, "key_set")
        if self.frames.strip():
            layout.prop(self, "frames")
        else:
            layout.prop(self, "frame_start")
            layout.prop(self, "frame_step")
        layout.prop(self, "smooth")
        layout.prop(self, "playback")
        layout.prop(self, "method")
        try:
            _draw_mixer_note(layout, context.object, self.bake_inputs(context.object)[0])
        except InputError:
            pass
        layout.prop(self, "processes")
        layout.label(text=self.summary(context.object), icon='INFO')

    def invoke(self, context, event):
        self._fill_defaults(context)
        self.interactive = True
        return context.window_manager.invoke_props_dialog(self, width=420)

    def execute(self, context):
        self._fill_defaults(context)

        def make(context):
            keys, frames = self.bake_inputs(context.object)
            if not self.properties.is_property_set("method"):
                self.method = default_method(context.object, keys, self.smooth)
            run = bake_run(context.object, keys, frames, smooth=self.smooth, method=self.method,
                           playback=self.playback, workers=self.processes)
            _warn_transform(self, context.object)
            return run
        return self.start_run(context, make)


class LENGTHS_ANGLES_OT_clear_bake(bpy.types.Operator):
    """Remove the keys and keyframes made by Bake In-betweens (your own keys stay)"""

    bl_idname = "lengths_angles.clear_bake"
    bl_label = "Clear Lengths & Angles Bake"
    bl_description = "Remove the shape keys and keyframes made by Bake In-betweens, even if renamed (your keys stay)"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return True  # execute() says what there is to clear (or what is wrong)

    def execute(self, context):
        obj = context.object
        try:
            mesh_access.require_writable_keys(mesh_access.require_mesh_object(obj), "clear the bake")
        except InputError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        if not bake.has_bake(obj):
            self.report({'INFO'}, f"'{obj.name}' has no Lengths & Angles bake: nothing to clear")
            return {'CANCELLED'}
        with mesh_access.object_mode(obj):
            n = bake.remove_bake(obj)
            obj.data.update()
        self.report({'INFO'}, f"Removed the bake ({n} keys)")
        return {'FINISHED'}


classes = (LENGTHS_ANGLES_OT_interpolate, LENGTHS_ANGLES_OT_bake_keyframes, LENGTHS_ANGLES_OT_clear_bake)
