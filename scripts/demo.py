#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""`make demo`: run the main jobs headless on sample data and write visible results.

Each step is a function ``step(out_dir) -> dict`` registered in :data:`STEPS`;
its dict goes into ``demo_output/summary.json`` and a line of
``demo_output/summary.md``.  To extend the demo (reconstruction, interpolation,
...) add a step function and append it to :data:`STEPS`.

Steps now:

1. ``cli_encode``: ``lacore encode`` on a shared mesh (finger0) -> ``finger0_encoded.npz`` + JSON.
2. ``cli_interpolate``: ``lacore interpolate`` finger0 -> finger1 (and beyond) -> ``finger_inbetween_*.ply``.
3. ``cli_human_model``: ``lacore model`` on the rest pose (the reference) and 20 seeded random poses of the
   coarse CC0 human (5 modes) and
   ``lacore model-sweep`` of mode 0 -> ``human_model.npz``, ``human_model.json``, ``human_mode0*.ply``.
4. ``cli_human_fit``: the 41 standard markers of a 20-frame held-out take -> ``human_take_markers.npz``;
   ``lacore fit`` -> ``human_fit.npz``, ``human_fit.json`` (with the mean per-vertex error vs the true poses)
   and ``human_fit.png`` (true mesh + markers vs the fit coloured by error, scripts/render_marker_fit.py).
5. ``blender_encode``: the add-on's Encode operator on a generated scene (cube, bar,
   grid with shape keys) -> ``demo_scene.blend`` (encodings stored in the meshes),
   ``demo_scene.json``, ``demo_scene.npz`` and a rendered picture of every key
   ``demo_scene_keys.png`` (runs in a subprocess: bpy can be imported once).
6. ``blender_interpolate``: the Interpolate and Bake Keyframes operators on a box bar bent
   180 degrees by Simple Deform -> ``bar_blend_comparison.png`` (linear shape-key blend vs
   lengths-and-angles in-between vs Blender's 90-degree bend), ``bar_blend_comparison.json``
   and ``bar_inbetweens.blend`` (in-between keys + a baked motion), via scripts/render_comparison.py.
7. ``blender_mocap_fit``: the take of step 4 as ``human_take.c3d``; the add-on's Build Shape Model (from shape
   keys), Import Markers, Bind Markers and Fit to Markers operators (scripts/demo_mocap_blender.py) ->
   ``human_mocap_fit.blend`` with a Mesh Cache modifier playing its PC2 next to it, ``human_mocap_fit.json``.
8. ``blender_live_mix``: the full CC0 human (13,380 vertices) with three pose keys; the add-on's Enable Live Mixing,
   the arm's slider at 0.5 compared with Blender's linear mix and the body skinned at half the key's angle,
   keyframed sliders played (scripts/demo_live_mix.py) -> ``human_live_mix.blend`` (press Play),
   ``human_live_mix.json`` and ``human_live_mix.png``.
9. ``blender_panel``: the add-on's panels and the In-betweens dialog drawn from their own ``draw()`` calls
   (scripts/draw_panel.py) -> ``panel.png`` and ``inbetweens_dialog.png`` (the README's panel picture).

Steps 5-8 save .blend files, so they run in the oldest supported Blender (``make demo``: bpy 4.2): Blender 4.2
cannot open a .blend saved by 5.x, and every newer Blender opens 4.2's.  Step 9 draws in the newest (bpy 5.2).
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def shared_meshes_dir():
    env = os.environ.get("LACORE_SHARED_DATA")
    path = env if env else os.path.join(REPO, "..", "shared", "data")
    path = os.path.abspath(path)
    return path if os.path.basename(path) == "meshes" else os.path.join(path, "meshes")


def missing_shared_data():
    """The first file of the shared data the demo reads that is not there, or None."""
    meshes = shared_meshes_dir()
    for path in (os.path.join(meshes, "finger", "finger0.ply"),
                 os.path.join(os.path.dirname(meshes), "human", "base.obj")):
        if not os.path.isfile(path):
            return path
    return None


def failed(cmd, returncode, stderr=None):
    """Stop the demo with one line naming the command that failed (after its own stderr, if it was captured)."""
    if stderr:
        sys.stderr.write(stderr if stderr.endswith("\n") else stderr + "\n")
    raise SystemExit(f"demo: {' '.join(os.path.basename(c) if i == 0 else c for i, c in enumerate(cmd))} "
                     f"exited with code {returncode}")


def run(cmd, **kwargs):
    print("+", " ".join(cmd), flush=True)
    proc = subprocess.run(cmd, cwd=REPO, **kwargs)
    if proc.returncode != 0:
        failed(cmd, proc.returncode, proc.stderr)
    return proc


# Blender's GPU set-up tries EGL configurations one after another on a machine without a display; the
# configurations it rejects print this line (three per process) although the render then succeeds.
_EGL_PROBE = re.compile(r"^EGL Error \(0x3009\): EGL_BAD_MATCH\b")


def run_blender(cmd, env, stdout=None):
    """Run a Blender script (bpy) like :func:`run`, its stderr passed on without the EGL probing lines."""
    print("+", " ".join(cmd), flush=True)
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=stdout, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if not _EGL_PROBE.match(line):
            sys.stderr.write(line)
    if proc.wait() != 0:
        failed(cmd, proc.returncode)


def cli_encode(out_dir):
    mesh = os.path.join(shared_meshes_dir(), "finger", "finger0.ply")
    out = os.path.join(out_dir, "finger0_encoded.npz")
    proc = run([sys.executable, "-m", "lacore.cli", "encode", mesh, "-o", out, "--json"],
               capture_output=True, text=True)
    result = json.loads(proc.stdout)
    with open(os.path.join(out_dir, "finger0_encode.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    return {
        "outputs": ["finger0_encoded.npz", "finger0_encode.json"],
        "text": (f"`lacore encode` finger0.ply: {result['vertices']} vertices, {result['edges']} edges, "
                 f"{result['faces']} faces; max integrability violation "
                 f"{result['max_integrability_violation']['local']:.2e} (local); "
                 f"{result['seconds']:.2f} s"),
        "result": result,
    }


# The Blender steps run in bpy interpreters, each with its *_PYTHONPATH (where that Python finds SciPy & co.):
#   LACORE_DEMO_BLENDER_PYTHON        the steps that save .blend files (`make demo`: bpy 4.2, the oldest supported
#                                     Blender, whose files every supported Blender opens); unset: this interpreter
#   LACORE_DEMO_PANEL_BLENDER_PYTHON  the panel pictures (`make demo`: bpy 5.2, the newest); unset: the one above
SAVING, DRAWING = "LACORE_DEMO_BLENDER", "LACORE_DEMO_PANEL_BLENDER"


def blender_python(role=SAVING):
    """``(interpreter, PYTHONPATH or None)`` of the Blender that runs the steps of ``role`` (SAVING or DRAWING)."""
    if role == DRAWING and os.environ.get(DRAWING + "_PYTHON"):
        return os.environ[DRAWING + "_PYTHON"], os.environ.get(DRAWING + "_PYTHONPATH")
    return os.environ.get(SAVING + "_PYTHON") or sys.executable, os.environ.get(SAVING + "_PYTHONPATH")


def run_blender_script(args, user_dir, role=SAVING, stdout=None):
    """Run ``python args...`` in the Blender of ``role`` (:func:`blender_python`), its Blender config in
    ``user_dir`` (the user's is not touched)."""
    python, path = blender_python(role)
    env = dict(os.environ, BLENDER_USER_RESOURCES=user_dir)
    if path:
        env["PYTHONPATH"] = path
    run_blender([python, *args], env=env, stdout=stdout)


def blender_encode(out_dir):
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        run_blender_script([os.path.join(HERE, "demo_blender.py"), out_dir], user_dir)
    with open(os.path.join(out_dir, "demo_scene.json")) as fh:
        result = json.load(fh)
    parts = []
    for name, obj in result["objects"].items():
        worst = max(k["max_integrability_violation"] for k in obj["keys"].values())
        parts.append(f"{name} ({obj['polygons']} polygons -> {obj['triangles']} triangles, {len(obj['keys'])} keys, "
                     f"max violation {worst:.1e})")
    outputs = ["demo_scene.blend", "demo_scene.json", "demo_scene.npz"]
    if result.get("picture"):
        outputs.append(os.path.basename(result["picture"]))
    return {
        "outputs": outputs,
        "text": "Blender add-on Encode operator: " + "; ".join(parts) + f"; saved by Blender {result['saved_by']}",
        "result": result,
    }


def blender_interpolate(out_dir):
    """Lengths-and-angles in-betweens in Blender vs the linear shape-key blend (scripts/render_comparison.py)."""
    picture = os.path.join(out_dir, "bar_blend_comparison.png")
    blend = os.path.join(out_dir, "bar_inbetweens.blend")
    numbers = os.path.join(out_dir, "bar_blend_comparison.json")
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        run_blender_script([os.path.join(HERE, "render_comparison.py"), "--output", picture, "--blend", blend,
                            "--json", numbers, "--bake"], user_dir, stdout=subprocess.DEVNULL)
    with open(numbers) as fh:
        result = json.load(fh)
    la, lin = result["lengths_and_angles"], result["linear_blend"]
    outputs = [os.path.basename(p) for p in (numbers, blend, picture) if os.path.exists(p)]
    return {
        "outputs": outputs,
        "text": (f"Interpolate operator, bar ({result['mesh']['vertices']} vertices) straight -> 180-degree Simple "
                 f"Deform bend, t = 0.5 vs Blender's 90-degree bend: RMS error "
                 f"{100 * la['rms_error_per_diagonal']:.3f} % of the diagonal (linear shape-key blend "
                 f"{100 * lin['rms_error_per_diagonal']:.2f} %); edge lengths off by up to "
                 f"{100 * la['max_edge_error_vs_reference']:.3f} % "
                 f"(linear {100 * lin['max_edge_error_vs_reference']:.0f} %); bar_inbetweens.blend has the "
                 f"in-between keys and a baked motion ({result['bake']['baked_keys']} "
                 f"keys, frames 1-48, press Play), saved by Blender {result['saved_by']}"),
        "result": result,
    }


def cli_interpolate(out_dir):
    """`lacore interpolate`: finger0 -> finger1 in lengths and angles, with extrapolation, as PLY files."""
    meshes = [os.path.join(shared_meshes_dir(), "finger", f"finger{i}.ply") for i in (0, 1)]
    prefix = os.path.join(out_dir, "finger_inbetween")
    factors = ["-0.25", "0", "0.25", "0.5", "0.75", "1", "1.25"]
    proc = run([sys.executable, "-m", "lacore.cli", "interpolate", *meshes, "--t", *factors, "-o", prefix, "--json"],
               capture_output=True, text=True)
    result = json.loads(proc.stdout)
    with open(os.path.join(out_dir, "finger_inbetween.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    outputs = sorted(f for f in os.listdir(out_dir) if f.startswith("finger_inbetween"))
    return {
        "outputs": outputs,
        "text": (f"`lacore interpolate` finger0 -> finger1 at t = {', '.join(factors)} (outside [0, 1] "
                 f"extrapolates; the default projection, Fast): {len(factors)} PLY files; "
                 "open them in any mesh viewer"),
        "result": result,
    }


def _human_data():
    """Coarse CC0 human (2,500 vertices): 20 seeded training poses and a 20-frame held-out take."""
    from lacore.samples.human import load_human
    body = load_human(coarse=True)
    train, _ = body.random_poses(20, seed=1)
    take, _, root_rotation, _ = body.take(20, seed=2)
    return body, train, take, root_rotation


def _write_ply(path, vertices, faces):
    import trimesh
    trimesh.Trimesh(vertices, faces, process=False).export(path)


def cli_human_model(out_dir):
    """`lacore model` on the rest pose and 20 random poses of the coarse human, then `lacore model-sweep` of mode 0.

    The rest pose comes first, so it is the reference (weights (3.20) of the energy): with a skinned pose as
    the reference, whose crushed triangles set the weights, the sweep's +-2 standard-deviation frames fold.
    """
    body, train, _, _ = _human_data()
    shapes = [body.vertices, *train]
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as tmp:
        meshes = [os.path.join(tmp, f"human_train_{i:02d}.ply") for i in range(len(shapes))]
        for path, X in zip(meshes, shapes, strict=True):
            _write_ply(path, X, body.faces)
        model = os.path.join(out_dir, "human_model.npz")
        proc = run([sys.executable, "-m", "lacore.cli", "model", *meshes, "-o", model, "--modes", "5", "--json"],
                   capture_output=True, text=True)
    result = {"model": json.loads(proc.stdout)}
    prefix = os.path.join(out_dir, "human_mode0")
    proc = run([sys.executable, "-m", "lacore.cli", "model-sweep", model, "--mode", "0", "--range", "-2", "2",
                "--frames", "5", "-o", prefix, "--allow-failure", "--json"], capture_output=True, text=True)
    result["sweep"] = json.loads(proc.stdout)
    with open(os.path.join(out_dir, "human_model.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    sweep = sorted(f for f in os.listdir(out_dir) if f.startswith("human_mode0"))
    failures = [o["failure"] for o in result["sweep"]["outputs"] if not o["success"]]
    return {
        "outputs": ["human_model.npz", "human_model.json", *sweep],
        "text": (f"`lacore model` on the rest pose (the reference) and {len(train)} random poses (seed 1) of the "
                 f"coarse CC0 human "
                 f"({body.n_vertices} vertices, {len(body.faces)} faces), 5 modes; `lacore model-sweep` of mode 0 "
                 f"from -2 to 2 standard deviations: {len(sweep)} PLY files, "
                 f"{len(sweep) - len(failures)} of them pass the reconstruction checks "
                 f"(failed: {', '.join(failures) or 'none'})"),
        "result": result,
    }


def cli_human_fit(out_dir):
    """`lacore fit` of human_model.npz to the 41 standard markers of a 20-frame held-out take + a picture."""
    sys.path.insert(0, HERE)
    import numpy as np
    from render_marker_fit import TRUE_COLOR, error_colors, figure, front_view, write_png

    from lacore.samples.markers import observe_markers, place_markers
    body, _, take, root_rotation = _human_data()
    _, binding = place_markers(body)
    positions = observe_markers(take, body.faces, binding, seed=3)
    markers = os.path.join(out_dir, "human_take_markers.npz")
    np.savez(markers, positions=positions, faces=binding.faces, barycentric=binding.barycentric,
             offsets=binding.offsets)
    fit = os.path.join(out_dir, "human_fit.npz")
    proc = run([sys.executable, "-m", "lacore.cli", "fit", os.path.join(out_dir, "human_model.npz"),
                "--markers", markers, "-o", fit, "--json"], capture_output=True, text=True)
    result = json.loads(proc.stdout)
    fitted = np.load(fit)["vertices"]
    err_mm = np.linalg.norm(fitted - take, axis=2) * 100.0     # the body is in decimetres
    result["mean_vertex_error_mm"] = float(err_mm.mean())
    result["max_vertex_error_mm"] = float(err_mm.max())
    with open(os.path.join(out_dir, "human_fit.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    # one frame, front view: true mesh + markers (left), fit coloured by per-vertex error (right), legend below
    t = len(take) // 2
    view = front_view(root_rotation[t] @ np.array([0.0, 0.0, 1.0]))
    X = take[t]
    centre = 0.5 * (X.min(0) + X.max(0))
    panels = [(0, 0, X, np.tile(TRUE_COLOR, (len(X), 1)), positions[t], view, centre),
              (0, 1, fitted[t], error_colors(err_mm[t]), positions[t], view, centre)]
    image = figure(panels, 1, 2, body.faces, cell=(400, 260),
                   col_titles=["true pose + markers", "lengths & angles fit"],
                   title=f"held-out frame {t}: mean error {err_mm[t].mean():.1f} mm")
    write_png(os.path.join(out_dir, "human_fit.png"), (np.clip(image, 0, 1) * 255).astype(np.uint8))
    return {
        "outputs": ["human_take_markers.npz", "human_fit.npz", "human_fit.json", "human_fit.png"],
        "text": (f"`lacore fit` human_model.npz to {result['markers']} markers (0.5 mm noise, occlusions) of a "
                 f"{result['frames']}-frame held-out take (seed 2): marker RMS {100 * result['marker_rms']:.1f} mm, "
                 f"mean per-vertex error vs the true poses {result['mean_vertex_error_mm']:.1f} mm (max "
                 f"{result['max_vertex_error_mm']:.0f} mm), {result['seconds']:.1f} s; human_fit.png frame {t}: "
                 "true mesh + markers (left), fit coloured by error, white 0 -> red >= 50 mm (right), with a legend"),
        "result": result,
    }


def blender_mocap_fit(out_dir):
    """The add-on's Build Shape Model / Import Markers (C3D) / Bind Markers / Fit to Markers on the coarse human."""
    import numpy as np

    from lacore.markers.io import MarkerTake, write_c3d
    from lacore.samples.markers import observe_markers, place_markers
    body, train, take, _ = _human_data()
    names, binding = place_markers(body)
    x = observe_markers(take, body.faces, binding, seed=3)
    x[0] = observe_markers(take[:1], body.faces, binding, occlusion=0.0, seed=3)[0]  # all seen at the bind frame
    c3d = os.path.join(out_dir, "human_take.c3d")
    # 20 poses far apart (median 12 cm per frame): at 10 Hz a brisk motion (at a capture rate such as 100 Hz the
    # markers' own prediction would miss by 1-3 mean edge lengths and the fit's temporal term would give way)
    write_c3d(c3d, MarkerTake(labels=tuple(names), positions=x / 10.0, rate=10.0, units="m"), units="mm")
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        inputs = os.path.join(user_dir, "inputs.npz")
        np.savez(inputs, faces=body.faces, basis=body.vertices, training=train, true=take)
        run_blender_script([os.path.join(HERE, "demo_mocap_blender.py"), out_dir, inputs, c3d], user_dir,
                           stdout=subprocess.DEVNULL)
    with open(os.path.join(out_dir, "human_mocap_fit.json")) as fh:
        result = json.load(fh)
    s = result["seconds"]
    return {
        "outputs": ["human_take.c3d", "human_mocap_fit.blend", result["pc2"], "human_mocap_fit.json"],
        "text": (f"Blender add-on on the coarse human: Build Shape Model from {len(train)} shape keys "
                 f"({s['build_model']:.1f} s), Import Markers human_take.c3d ({result['markers']} markers, "
                 f"{result['frames']} frames), Bind Markers, Fit to Markers ({s['fit_markers']:.1f} s) -> "
                 f"{result['pc2']} played by a Mesh Cache modifier: mean per-vertex error vs the true poses "
                 f"{result['mean_vertex_error_mm']:.1f} mm (max {result['max_vertex_error_mm']:.0f} mm); "
                 f"open human_mocap_fit.blend (saved by Blender {result['saved_by']}) and press Play"),
        "result": result,
    }


def blender_live_mix(out_dir):
    """Live mixing on the full CC0 human: Blender's slider at 0.5 vs its linear mix and the skinned pose."""
    import numpy as np

    from lacore.samples.human import POSE_KEYS, dof_angles, limb_ends, load_human, pose_keys
    body = load_human()
    names, keys = pose_keys(body)
    half = body.pose(dof_angles({dof: degrees / 2 for dof, degrees in POSE_KEYS[0][1].items()}))  # the arm's key
    shoulder, fingertip = limb_ends(body, "left_arm")
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        inputs = os.path.join(user_dir, "inputs.npz")
        np.savez(inputs, faces=body.faces, keys=keys, names=np.array(names), half=half, shoulder=shoulder,
                 fingertip=fingertip)
        run_blender_script([os.path.join(HERE, "demo_live_mix.py"), out_dir, inputs], user_dir,
                           stdout=subprocess.DEVNULL)
    with open(os.path.join(out_dir, "human_live_mix.json")) as fh:
        result = json.load(fh)
    n = result["at_half_arm"]
    lin, live, ref = n["blender_linear"], n["live_mix"], n["skinned_half_angle"]
    outputs = ["human_live_mix.blend", "human_live_mix.json"]
    if result["picture"]:
        outputs.append("human_live_mix.png")
    return {
        "outputs": outputs,
        "text": (f"Enable Live Mixing on the CC0 human ({result['vertices']} vertices, keys "
                 f"{', '.join(result['keys'][1:])}; built in {result['enable_seconds']:.1f} s, reduced size "
                 f"{result['reduced_size']}): with {result['keys'][1]} at 0.5 the arm measures "
                 f"{live['arm_length_cm']:.1f} cm shoulder to fingertip (Blender's linear mix "
                 f"{lin['arm_length_cm']:.1f} cm, the body skinned at half the angle {ref['arm_length_cm']:.1f} cm, "
                 f"at rest {n['rest']['arm_length_cm']:.1f} cm) and lies {100 * live['rms_per_diagonal']:.2f} % of the "
                 f"diagonal from that skinned pose (linear {100 * lin['rms_per_diagonal']:.2f} %); the keyframed "
                 f"sliders played at {result['playback_fps']:.0f} fps here; open human_live_mix.blend (saved by "
                 f"Blender {result['saved_by']}) and press Play"),
        "result": result,
    }


def blender_panel(out_dir):
    """The README's picture of the panels (and of the In-betweens dialog), drawn in headless Blender."""
    panel = os.path.join(out_dir, "panel.png")
    dialog = os.path.join(out_dir, "inbetweens_dialog.png")
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        run_blender_script([os.path.join(HERE, "draw_panel.py"), "--output", panel, "--dialog", dialog], user_dir,
                           role=DRAWING, stdout=subprocess.DEVNULL)
    return {
        "outputs": ["panel.png", "inbetweens_dialog.png"],
        "text": ("the add-on's panels (a bar with shape keys, an in-between, a shape model and a bound take) and the "
                 "In-betweens dialog, drawn from their draw() calls: panel.png, inbetweens_dialog.png"),
    }


STEPS = [cli_encode, cli_interpolate, cli_human_model, cli_human_fit, blender_encode, blender_interpolate,
         blender_mocap_fit, blender_live_mix, blender_panel]
# the steps that read the shared data (the finger meshes, the CC0 human)
NEEDS_SHARED_DATA = {cli_encode, cli_interpolate, cli_human_model, cli_human_fit, blender_mocap_fit,
                     blender_live_mix}


def main(argv=None):
    parser = argparse.ArgumentParser(description="Run the Lengths & Angles demo.")
    parser.add_argument("--output", default=os.path.join(REPO, "demo_output"))
    parser.add_argument("--only", action="append", help="run only these steps (by function name)")
    args = parser.parse_args(argv)
    out_dir = os.path.abspath(args.output)
    steps = [step for step in STEPS if not args.only or step.__name__ in args.only]
    missing = missing_shared_data() if any(step in NEEDS_SHARED_DATA for step in steps) else None
    if missing:
        print(f"demo: the shared data is not where the demo looks ({missing} is missing): put the shared data "
              "folder beside the repository (../shared/data) or set LACORE_SHARED_DATA to it", file=sys.stderr)
        return 2
    os.makedirs(out_dir, exist_ok=True)
    summary, lines = {}, ["# Lengths & Angles demo", ""]
    for step in steps:
        t = time.perf_counter()
        info = step(out_dir)
        info["seconds"] = round(time.perf_counter() - t, 3)
        summary[step.__name__] = info
        lines.append(f"- **{step.__name__}** ({info['seconds']} s): {info['text']}  ")
        lines.append(f"  files: {', '.join(info['outputs'])}")
    with open(os.path.join(out_dir, "summary.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    with open(os.path.join(out_dir, "summary.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"\nwrote {out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
