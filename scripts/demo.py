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
3. ``blender_encode``: the add-on's Encode operator on a generated scene (cube, bar,
   grid with shape keys) -> ``demo_scene.blend`` (encodings stored in the meshes),
   ``demo_scene.json``, ``demo_scene.npz`` and a rendered picture of every key
   ``demo_scene_keys.png`` (runs in a subprocess: bpy can be imported once).
4. ``blender_interpolate``: the Interpolate and Bake Keyframes operators on a box bar bent
   180 degrees by Simple Deform -> ``bar_blend_comparison.png`` (linear shape-key blend vs
   lengths-and-angles in-between vs Blender's 90-degree bend), ``bar_blend_comparison.json``
   and ``bar_inbetweens.blend`` (in-between keys + a baked motion), via scripts/render_comparison.py.
"""

import argparse
import json
import os
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


def run(cmd, **kwargs):
    print("+", " ".join(cmd), flush=True)
    return subprocess.run(cmd, check=True, cwd=REPO, **kwargs)


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
                 f"{result['faces']} faces; max integrability violation {result['max_integrability_violation']:.2e}; "
                 f"{result['seconds']:.2f} s"),
        "result": result,
    }


# The Blender steps run in this interpreter (must have bpy; `make demo`: the newest Blender's venv, bpy 5.2)
# with LACORE_DEMO_BLENDER_PYTHONPATH (where that Python finds scipy & co.) as its PYTHONPATH.
BLENDER_PYTHON = os.environ.get("LACORE_DEMO_BLENDER_PYTHON") or sys.executable


def blender_env(user_dir):
    env = dict(os.environ, BLENDER_USER_RESOURCES=user_dir)  # do not touch the user's Blender config
    if os.environ.get("LACORE_DEMO_BLENDER_PYTHONPATH"):
        env["PYTHONPATH"] = os.environ["LACORE_DEMO_BLENDER_PYTHONPATH"]
    return env


def blender_encode(out_dir):
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        run([BLENDER_PYTHON, os.path.join(HERE, "demo_blender.py"), out_dir], env=blender_env(user_dir))
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
        "text": "Blender add-on Encode operator: " + "; ".join(parts),
        "result": result,
    }


def blender_interpolate(out_dir):
    """Lengths-and-angles in-betweens in Blender vs the linear shape-key blend (scripts/render_comparison.py)."""
    picture = os.path.join(out_dir, "bar_blend_comparison.png")
    blend = os.path.join(out_dir, "bar_inbetweens.blend")
    numbers = os.path.join(out_dir, "bar_blend_comparison.json")
    with tempfile.TemporaryDirectory(prefix="lengths_angles_demo_") as user_dir:
        run([BLENDER_PYTHON, os.path.join(HERE, "render_comparison.py"), "--output", picture, "--blend", blend,
             "--json", numbers, "--bake"], env=blender_env(user_dir), stdout=subprocess.DEVNULL)
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
                 "keys, frames 1-48, press Play)"),
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
                 f"extrapolates; Gauss-Newton projection, warm-started): {len(factors)} PLY files; "
                 "open them in any mesh viewer"),
        "result": result,
    }


STEPS = [cli_encode, cli_interpolate, blender_encode, blender_interpolate]


def main(argv=None):
    parser = argparse.ArgumentParser(description="Run the Lengths & Angles demo.")
    parser.add_argument("--output", default=os.path.join(REPO, "demo_output"))
    parser.add_argument("--only", action="append", help="run only these steps (by function name)")
    args = parser.parse_args(argv)
    out_dir = os.path.abspath(args.output)
    os.makedirs(out_dir, exist_ok=True)
    summary, lines = {}, ["# Lengths & Angles demo", ""]
    for step in STEPS:
        if args.only and step.__name__ not in args.only:
            continue
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
