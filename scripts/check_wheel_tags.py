#!/usr/bin/env python3
"""Check the bundled wheels' tags against the manifest's platforms and the supported Pythons.

Blender's ``blender_ext.py validate`` does not look at Python tags: a zip with only
``cp311`` wheels validates, then fails to install on Blender 5.1+ (Python 3.13).
This check parses every wheel file name (PEP 425 / 427 tags: python, abi, platform,
including compressed tag sets such as ``manylinux_2_17_x86_64.manylinux2014_x86_64``,
manylinux glibc versions, macOS deployment targets and ``universal2``) and asserts,
for every manifest platform x supported Python:

* every bundled distribution has EXACTLY ONE wheel usable there (Blender's installer
  keeps the wheels of its platform and Python, then one per distribution), except the
  known gaps of optional accelerators (:data:`KNOWN_GAPS`: lacore falls back);
* no wheel is unusable everywhere (wrong Python, wrong platform, too new a glibc / macOS);
* early Blender 4.2.x (4.2.0; 4.2.13 matches Python tags) ignore Python tags: per distribution
  they keep the highest version among the platform's wheels, ties broken by the greater file
  name.  What they keep must be a
  wheel Python 3.11 can use, except for the optional distributions (:data:`LEGACY_OPTIONAL`).

usage: check_wheel_tags.py [blender_manifest.toml | extension.zip ...]   (default: the repository's manifest)
Exit code 0 when every check passes, 1 otherwise (one line per problem on stderr).
"""

import os
import re
import sys
import tomllib
import zipfile
from typing import NamedTuple

# Blender 4.2 LTS .. 5.0 embed Python 3.11, Blender 5.1 and 5.2 embed Python 3.13.
SUPPORTED_PYTHONS = ((3, 11), (3, 13))
BLENDER_PYTHONS = {(3, 11): "Blender 4.2-5.0", (3, 13): "Blender 5.1-5.2"}

# Per Blender platform: the wheel platform family, the architectures accepted and the newest
# OS baseline a wheel may need (Blender 4.2+ needs glibc 2.28 on Linux, the VFX platform 2024;
# SciPy >= 1.15 needs macOS 12 on arm64, so the extension needs macOS 12 there).
PLATFORMS = {
    "linux-x64": ("linux", {"x86_64"}, (2, 28)),
    "linux-arm64": ("linux", {"aarch64"}, (2, 28)),
    "windows-x64": ("windows", {"amd64"}, None),
    "windows-arm64": ("windows", {"arm64"}, None),
    "macos-x64": ("macos", {"x86_64", "universal2", "intel", "universal"}, (12, 0)),
    "macos-arm64": ("macos", {"arm64", "universal2"}, (12, 0)),
}

# (distribution, Blender platform, Python) pairs allowed to have no wheel: optional accelerators
# that lacore replaces (lacore.linalg.sparse_cholesky: cvxopt/CHOLMOD -> SciPy's sparse factorization;
# pymetis/METIS -> lacore's geometric nested dissection).
KNOWN_GAPS = frozenset({
    ("cvxopt", "macos-arm64", (3, 13)),
    ("cvxopt", "macos-x64", (3, 13)),
    ("pymetis", "windows-x64", (3, 11)),
    ("pymetis", "windows-x64", (3, 13)),
})

# Distributions lacore can do without: on early Blender 4.2.x (4.2.0; fixed by 4.2.13) their cp313 wheel may win
# (it cannot be imported by Python 3.11, so lacore uses SciPy's factorization instead of CHOLMOD, and its own
# ordering instead of METIS).
LEGACY_OPTIONAL = frozenset({"cvxopt", "pymetis"})

_LEGACY_MANYLINUX = {"manylinux1": (2, 5), "manylinux2010": (2, 12), "manylinux2014": (2, 17)}


class Wheel(NamedTuple):
    """The parts of a wheel file name (PEP 427), tag sets expanded (PEP 425)."""

    filename: str
    distribution: str  # normalized (PEP 503): lower case, runs of -_. as "-"
    version: str
    python_tags: frozenset
    abi_tags: frozenset
    platform_tags: frozenset


def parse_wheel_filename(path):
    """:class:`Wheel` of a wheel path or file name; ValueError naming the file if it is not one."""
    filename = os.path.basename(path)
    if not filename.endswith(".whl"):
        raise ValueError(f"{filename}: not a wheel (no .whl suffix)")
    parts = filename[:-4].split("-")
    if len(parts) not in (5, 6):
        raise ValueError(f"{filename}: a wheel name has 5 or 6 '-'-separated parts, not {len(parts)}")
    py, abi, plat = parts[-3:]
    return Wheel(filename, re.sub(r"[-_.]+", "-", parts[0]).lower(), parts[1],
                 frozenset(py.split(".")), frozenset(abi.split(".")), frozenset(plat.split(".")))


def _python_ok(wheel, python):
    """Whether CPython ``python`` (major, minor) can import ``wheel`` (python and abi tags, as pip decides)."""
    major, minor = python
    cp = f"cp{major}{minor}"
    for py in wheel.python_tags:
        m = re.fullmatch(r"(py|cp)(\d)(\d*)", py)
        if m is None or int(m.group(2)) != major:
            continue  # pp3, graalpy, py2...: other implementations or Pythons
        impl, tag_minor = m.group(1), int(m.group(3)) if m.group(3) else None
        for abi in wheel.abi_tags:
            if abi == "none" and impl == "py" and (tag_minor is None or tag_minor <= minor):
                return True  # pure Python: py3, py3X for X <= minor
            if abi == "none" and impl == "cp" and tag_minor == minor:
                return True
            if abi == "abi3" and impl == "cp" and tag_minor is not None and tag_minor <= minor:
                return True  # stable ABI: built for 3.X, usable by every later 3.Y
            if abi == cp and py == cp:
                return True
    return False


def _platform_ok(wheel, platform, check_baseline=True):
    """Whether the platform tags of ``wheel`` run on Blender platform ``platform`` (any OS version if not
    ``check_baseline``)."""
    family, arches, baseline = PLATFORMS[platform]
    if not check_baseline and baseline is not None:
        baseline = (999, 999)
    for tag in wheel.platform_tags:
        if tag == "any":
            return True
        if family == "linux":
            m = re.fullmatch(r"manylinux_(\d+)_(\d+)_(\w+)", tag)
            if m:
                glibc, arch = (int(m.group(1)), int(m.group(2))), m.group(3)
            else:
                m = re.fullmatch(r"(manylinux1|manylinux2010|manylinux2014)_(\w+)", tag)
                if m is None:
                    continue  # musllinux_*, linux_*: not portable to Blender's glibc Linux builds
                glibc, arch = _LEGACY_MANYLINUX[m.group(1)], m.group(2)
            if arch in arches and glibc <= baseline:
                return True
        elif family == "windows":
            m = re.fullmatch(r"win_(\w+)", tag)
            if m and m.group(1) in arches:
                return True
        else:
            m = re.fullmatch(r"macosx_(\d+)_(\d+)_(\w+)", tag)
            if m and m.group(3) in arches and (int(m.group(1)), int(m.group(2))) <= baseline:
                return True
    return False


def wheel_supports(wheel, platform, python):
    """Whether ``wheel`` (a :class:`Wheel` or file name) installs and imports on ``platform`` with ``python``."""
    if isinstance(wheel, str):
        wheel = parse_wheel_filename(wheel)
    return _python_ok(wheel, python) and _platform_ok(wheel, platform)


def _version_key(version):
    """Blender's wheel version comparison: the first three numbers, then the rest as text."""
    m = re.match(r"(\d+)?(?:\.(\d+))?(?:\.(\d+))", version)
    if m is None:
        return (0, 0, 0, "")
    return (*(int(g) if g is not None else 0 for g in m.groups()), version[m.end():])


def legacy_installer_picks(wheel_names, platform):
    """``{distribution: wheel file name}`` that early Blender 4.2.x (4.2.0; not 4.2.13) install on ``platform``.

    Those installers match only the platform tag (any glibc / macOS version), not the Python or
    ABI tag, then keep per distribution the highest version, ties broken by the greater file name
    (``bl_pkg``: ``_extensions_wheel_filter_for_platform``, ``wheel_list_deduplicate_as_skip_set``).
    """
    picks = {}
    for name in wheel_names:
        wheel = parse_wheel_filename(name)
        if not _platform_ok(wheel, platform, check_baseline=False):
            continue
        base = wheel.filename.partition("-")[0]
        best = picks.get(base)
        key = (_version_key(wheel.version), wheel.filename)
        if best is None or (_version_key(parse_wheel_filename(best).version), best) < key:
            picks[base] = wheel.filename
    return picks


def wheel_matrix(wheel_names, platforms, pythons=SUPPORTED_PYTHONS):
    """``{(platform, python): {distribution: [usable wheel file names]}}`` over every bundled distribution."""
    wheels = [parse_wheel_filename(w) for w in wheel_names]
    distributions = sorted({w.distribution for w in wheels})
    return {(p, py): {d: [w.filename for w in wheels if w.distribution == d and wheel_supports(w, p, py)]
                      for d in distributions}
            for p in platforms for py in pythons}


def check_wheels(wheel_names, platforms, pythons=SUPPORTED_PYTHONS, known_gaps=KNOWN_GAPS):
    """Problems (list of one-line strings; empty when all is well) of the bundled ``wheel_names``.

    ``platforms`` are Blender platform names (``linux-x64``...); unknown ones are a problem.
    """
    problems = [f"platform '{p}' is not one this check knows ({sorted(PLATFORMS)})"
                for p in platforms if p not in PLATFORMS]
    platforms = [p for p in platforms if p in PLATFORMS]
    try:
        matrix = wheel_matrix(wheel_names, platforms, pythons)
    except ValueError as exc:
        return problems + [str(exc)]
    used = set()
    for (platform, python), dists in matrix.items():
        where = f"{platform} / Python {python[0]}.{python[1]} ({BLENDER_PYTHONS.get(python, '?')})"
        for dist, usable in dists.items():
            used.update(usable)
            if len(usable) > 1:
                problems.append(f"{where}: {len(usable)} wheels of {dist} are usable, Blender would pick one "
                                f"arbitrarily: {usable}")
            elif not usable and (dist, platform, python) not in known_gaps:
                problems.append(f"{where}: no usable wheel of {dist}")
            elif usable and (dist, platform, python) in known_gaps:
                problems.append(f"{where}: {dist} now has a wheel ({usable[0]}): drop it from KNOWN_GAPS")
    if (3, 11) in pythons:
        for platform in platforms:
            for base, pick in sorted(legacy_installer_picks(wheel_names, platform).items()):
                dist = parse_wheel_filename(pick).distribution
                if not wheel_supports(pick, platform, (3, 11)) and dist not in LEGACY_OPTIONAL:
                    problems.append(f"{platform} / early Blender 4.2.x (no Python tag matching): the installer "
                                    f"keeps {pick}, which Python 3.11 cannot use (give the cp311 wheel of {base} "
                                    "the higher version)")
    for name in wheel_names:
        base = os.path.basename(name)
        if base not in used:
            problems.append(f"{base}: usable on none of the platforms {platforms} with Python "
                            f"{', '.join(f'{a}.{b}' for a, b in pythons)}")
    return problems


def manifest_wheels(manifest_text):
    """``(platforms, wheels)`` of a blender_manifest.toml text."""
    data = tomllib.loads(manifest_text)
    return list(data.get("platforms", [])), list(data.get("wheels", []))


def check_manifest(path):
    """Problems of a blender_manifest.toml file."""
    with open(path, encoding="utf-8") as fh:
        platforms, wheels = manifest_wheels(fh.read())
    return check_wheels(wheels, platforms)


def check_zip(path):
    """Problems of a built extension zip.

    A zip built with ``--split-platforms`` keeps the full manifest but holds only its platform's
    wheels (Blender's installer skips listed wheels that are absent).  So the platforms the zip
    serves are those whose listed wheels it holds ALL of; a platform with only some of its own
    (not pure-Python) wheels, a
    zip serving no platform, or a held wheel its manifest does not list is a problem.  The held
    wheels are then checked (:func:`check_wheels`) for the platforms served.
    """
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
        manifest = next((n for n in names if n.rsplit("/", 1)[-1] == "blender_manifest.toml"), None)
        if manifest is None:
            return [f"{path}: no blender_manifest.toml inside"]
        platforms, wheels = manifest_wheels(zf.read(manifest).decode("utf-8"))
    prefix = manifest[: -len("blender_manifest.toml")]
    held = {n[len(prefix):] for n in names if n.endswith(".whl")}
    listed = {os.path.normpath(w) for w in wheels}
    problems = [f"{path}: the zip holds {w} which its manifest does not list" for w in sorted(held - listed)]
    served = []
    for platform in platforms:
        if platform not in PLATFORMS:
            problems.append(f"{path}: platform '{platform}' is not one this check knows ({sorted(PLATFORMS)})")
            continue
        usable = {w for w in listed if any(wheel_supports(os.path.basename(w), platform, py)
                                           for py in SUPPORTED_PYTHONS)}
        missing = sorted(usable - held)
        specific = {w for w in usable if "any" not in parse_wheel_filename(w).platform_tags}
        if not missing:
            served.append(platform)
        elif specific & held:  # some but not all of this platform's own wheels
            problems += [f"{path}: {platform}: manifest lists {w} but the zip does not hold it" for w in missing]
    if not served:
        return problems + [f"{path}: holds the wheels of none of its platforms {platforms}"]
    return problems + [f"{path}: {p}" for p in check_wheels(sorted(held & listed), served)]


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    paths = argv or [os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                  "blender_manifest.toml")]
    problems = []
    for path in paths:
        problems += check_zip(path) if path.endswith(".zip") else check_manifest(path)
    for p in problems:
        print(p, file=sys.stderr)
    if not problems:
        print(f"wheel tags OK: {', '.join(paths)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
