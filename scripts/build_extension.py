#!/usr/bin/env python3
"""Build the Blender extension zip (``make extension``).

1. Download the wheels listed in ``blender_manifest.toml`` into ``./wheels``
   (``pip download --only-binary=:all: --no-deps --python-version 3.11|3.13 --platform ...``);
   wheels already present are not downloaded again.
2. Build with Blender's own ``blender_ext.py build`` (shipped inside the ``bpy``
   wheel: ``<site-packages>/bpy/<ver>/scripts/addons_core/bl_pkg/cli/blender_ext.py``).
3. Check the zip with ``blender_ext.py validate`` and the wheel tags of every bundled
   wheel against the zip manifest's platforms and Pythons 3.11 / 3.13
   (``scripts/check_wheel_tags.py``; ``validate`` ignores Python tags).

Without ``--platform`` one zip for all platforms of the manifest is built from the
repository itself.  With ``--platform linux-x64`` (repeatable, or ``--platform current``)
only those platforms' wheels are downloaded and the zip is built from a staging copy
whose manifest lists just those platforms and wheels (used by the tests).

Prints the path of the zip on the last line of stdout.
"""

import argparse
import glob
import importlib.util
import os
import platform as _platform
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"

# Never copied into a staging tree (the manifest's [build] excludes do the rest).
STAGING_IGNORE = shutil.ignore_patterns(
    ".venv", ".venv-*", ".git", "dist", "wheels", "tests", "benchmarks", "demo_output", "blend_samples",
    "__pycache__", ".pytest_cache", ".ruff_cache", "*.egg-info", "build", "*.zip",
)


def find_blender_ext():
    """Path of blender_ext.py from the installed bpy module (or $BLENDER_EXT)."""
    if os.environ.get("BLENDER_EXT"):
        return os.environ["BLENDER_EXT"]
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        sys.exit("build_extension: the bpy module is not installed (run `make venv`) and $BLENDER_EXT is not set")
    bpy_dir = os.path.dirname(spec.origin)
    hits = sorted(glob.glob(os.path.join(bpy_dir, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")))
    if not hits:
        sys.exit(f"build_extension: blender_ext.py not found under {bpy_dir}")
    return hits[-1]


def current_platform():
    """Blender's name of this machine's platform, e.g. ``linux-x64``."""
    system = {"Linux": "linux", "Windows": "windows", "Darwin": "macos"}[_platform.system()]
    machine = _platform.machine().lower()
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}.get(machine, machine)
    return f"{system}-{machine}"


def parse_wheel_name(path):
    """``(name, version, python_tag, abi_tag, [platform tags])`` of a wheel file name."""
    stem = os.path.basename(path)[: -len(".whl")]
    parts = stem.split("-")
    if len(parts) not in (5, 6):
        raise ValueError(f"not a wheel file name: {path}")
    name, version = parts[0], parts[1]
    py_tag, abi_tag, plat_tag = parts[-3], parts[-2], parts[-1]
    return name, version, py_tag, abi_tag, plat_tag.split(".")


def wheel_platforms(path):
    """Blender platforms a wheel is for (``None`` = all, pure Python)."""
    *_, plat_tags = parse_wheel_name(path)
    result = set()
    for tag in plat_tags:
        if tag == "any":
            return None
        if tag.startswith(("manylinux", "musllinux", "linux")):
            system = "linux"
        elif tag.startswith("win"):
            system = "windows"
        elif tag.startswith("macosx"):
            system = "macos"
        else:
            continue
        if tag.endswith("universal2"):
            result.update({"macos-x64", "macos-arm64"})
        elif tag.endswith(("x86_64", "amd64")):
            result.add(f"{system}-x64")
        elif tag.endswith(("arm64", "aarch64")):
            result.add(f"{system}-arm64")
    return result


def download_wheel(rel_path, python):
    """Download one manifest wheel into the repository's wheels/ folder if missing."""
    dest = os.path.join(REPO, rel_path)
    if os.path.isfile(dest):
        return dest
    name, version, py_tag, abi_tag, plat_tags = parse_wheel_name(dest)
    os.makedirs(os.path.dirname(dest), exist_ok=True)
    # cp311 -> 3.11, cp313 -> 3.13; pure-Python py3 wheels: any supported Python
    py_version = f"3.{py_tag.split('.')[0][3:]}" if py_tag.startswith("cp3") else "3.11"
    cmd = [python, "-m", "pip", "download", "--disable-pip-version-check", "--only-binary=:all:", "--no-deps",
           "--python-version", py_version, "-d", os.path.dirname(dest), f"{name}=={version}"]
    if plat_tags != ["any"]:
        cmd += ["--implementation", "cp", "--abi", abi_tag]
        for tag in plat_tags:
            cmd += ["--platform", tag]
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)
    if not os.path.isfile(dest):
        got = sorted(os.listdir(os.path.dirname(dest)))
        sys.exit(f"build_extension: pip did not produce {os.path.basename(dest)} (wheels/ holds {got})")
    return dest


def check_zip_tags(zip_path):
    """Exit with the problems if the zip's wheels do not fit its platforms and Pythons 3.11/3.13."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from check_wheel_tags import check_zip

    problems = check_zip(zip_path)
    if problems:
        sys.exit("build_extension: wheel tag check failed:\n" + "\n".join(problems))


def _replace_list(text, key, items):
    new = f"{key} = [\n" + "".join(f'  "{item}",\n' for item in items) + "]"
    out, n = re.subn(rf"^{key}\s*=\s*\[.*?\]", lambda _m: new, text, count=1, flags=re.S | re.M)
    if n != 1:
        raise ValueError(f"cannot find `{key} = [...]` in {MANIFEST}")
    return out


def stage_subset(staging, platforms, wheels):
    """Copy the extension sources to ``staging`` with a manifest for ``platforms``/``wheels`` only."""
    shutil.copytree(REPO, staging, ignore=STAGING_IGNORE)
    for rel in wheels:
        dst = os.path.join(staging, rel)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        shutil.copy2(os.path.join(REPO, rel), dst)
    path = os.path.join(staging, MANIFEST)
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    text = _replace_list(text, "platforms", platforms)
    text = _replace_list(text, "wheels", wheels)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    with open(path, "rb") as fh:  # still valid TOML with the expected lists
        check = tomllib.load(fh)
    assert check["platforms"] == list(platforms) and check["wheels"] == list(wheels), check


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", default=[],
                        help="Blender platform to build for (repeatable; 'current' = this machine); default: all")
    parser.add_argument("--output-dir", default=os.path.join(REPO, "dist"))
    parser.add_argument("--download-only", action="store_true", help="only download the wheels")
    parser.add_argument("--split-platforms", action="store_true",
                        help="one zip per platform, each with only its own wheels (Blender's --split-platforms)")
    parser.add_argument("--python", default=sys.executable, help="Python whose pip downloads the wheels")
    args = parser.parse_args(argv)

    with open(os.path.join(REPO, MANIFEST), "rb") as fh:
        manifest = tomllib.load(fh)
    all_platforms = list(manifest.get("platforms", []))
    platforms = [current_platform() if p == "current" else p for p in args.platform] or all_platforms
    unknown = [p for p in platforms if p not in all_platforms]
    if unknown:
        sys.exit(f"build_extension: platform(s) {unknown} not in the manifest's platforms {all_platforms}")
    subset = sorted(set(platforms)) != sorted(all_platforms)
    wheels = [w for w in manifest.get("wheels", [])
              if (wp := wheel_platforms(w)) is None or wp & set(platforms)]
    for rel in wheels:
        download_wheel(rel, args.python)
    if args.download_only:
        return 0

    blender_ext = find_blender_ext()
    os.makedirs(args.output_dir, exist_ok=True)
    if args.split_platforms:
        if subset:
            sys.exit("build_extension: --split-platforms builds every platform of the manifest; drop --platform")
        before = set(glob.glob(os.path.join(args.output_dir, "*.zip")))
        subprocess.run([sys.executable, blender_ext, "build", "--source-dir", REPO, "--output-dir",
                        os.path.abspath(args.output_dir), "--split-platforms"], check=True)
        zips = sorted(set(glob.glob(os.path.join(args.output_dir, "*.zip"))) - before) or sorted(before)
        for z in zips:
            subprocess.run([sys.executable, blender_ext, "validate", z], check=True)
            check_zip_tags(z)
        print("\n".join(os.path.abspath(z) for z in zips))
        return 0
    name = f"{manifest['id']}-{manifest['version']}"
    if subset:
        name += "-" + "-".join(p.replace("-", "_") for p in platforms)
    out = os.path.abspath(os.path.join(args.output_dir, name + ".zip"))
    with tempfile.TemporaryDirectory(prefix="lengths_angles_build_") as tmp:
        source = REPO
        if subset:
            source = os.path.join(tmp, manifest["id"])
            stage_subset(source, platforms, wheels)
        subprocess.run([sys.executable, blender_ext, "build", "--source-dir", source, "--output-filepath", out],
                       check=True)
    subprocess.run([sys.executable, blender_ext, "validate", out], check=True)
    check_zip_tags(out)
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
