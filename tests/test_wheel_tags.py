"""The bundled wheels' tags against the manifest's platforms and Pythons (scripts/check_wheel_tags.py).

No network: runs on the manifest text (and on built zips in test_blender_extension.py).
Blender's own ``validate`` accepts a cp311-only zip that Blender 5.1+ (Python 3.13) refuses.
"""

import importlib.util
import zipfile

import pytest
from conftest import REPO

_spec = importlib.util.spec_from_file_location("check_wheel_tags", REPO / "scripts" / "check_wheel_tags.py")
tags = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tags)

MANIFEST = REPO / "blender_manifest.toml"
ALL = ["linux-x64", "windows-x64", "macos-arm64", "macos-x64"]


def manifest():
    return tags.manifest_wheels(MANIFEST.read_text(encoding="utf-8"))


def test_manifest_wheels_cover_every_platform_and_python():
    platforms, wheels = manifest()
    assert platforms == ALL
    assert tags.check_wheels(wheels, platforms) == []
    assert tags.main([str(MANIFEST)]) == 0


def test_manifest_matrix_picks_one_wheel_each():
    """What Blender installs where: one SciPy per pair (cp311 for 4.2-5.0, cp313 for 5.1/5.2), cvxopt
    everywhere but macOS on Python 3.13 (lacore's SciPy backend there), pymetis everywhere but Windows
    (lacore's geometric ordering there)."""
    platforms, wheels = manifest()
    matrix = tags.wheel_matrix(wheels, platforms)
    assert len(matrix) == 8
    for (platform, python), dists in matrix.items():
        assert set(dists) == {"scipy", "trimesh", "cvxopt", "c3d", "pymetis", "typing-extensions"}
        cp = f"cp{python[0]}{python[1]}"
        assert [w.split("-")[2] for w in dists["scipy"]] == [cp], (platform, python, dists["scipy"])
        assert dists["scipy"][0].split("-")[1] == {(3, 11): "1.16.3", (3, 13): "1.16.2"}[python]
        assert dists["trimesh"] == ["trimesh-5.2.0-py3-none-any.whl"]
        assert dists["c3d"] == ["c3d-0.6.0-py3-none-any.whl"]
        missing_cvxopt = platform.startswith("macos") and python == (3, 13)
        assert len(dists["cvxopt"]) == (0 if missing_cvxopt else 1), (platform, python, dists["cvxopt"])
        pymetis = [] if platform.startswith("windows") else [f"pymetis-2025.2.2-{cp}-{cp}-"]
        assert [w[: len("pymetis-2025.2.2-cp3xx-cp3xx-")] for w in dists["pymetis"]] == pymetis, dists["pymetis"]
        assert dists["typing-extensions"] == ["typing_extensions-4.16.0-py3-none-any.whl"]
    assert {(d, p, py) for (p, py), ds in matrix.items() for d, w in ds.items() if not w} == tags.KNOWN_GAPS


def test_early_blender_42_installer_picks_cp311_scipy():
    """Blender 4.2.0 ignores Python tags and keeps the highest version per distribution (ties: the
    greater file name, cp313 > cp311): the cp311 SciPy (1.16.3) outranks the cp313 one (1.16.2);
    cvxopt's cp313 wheel wins on Linux/Windows (lacore falls back to SciPy there), pymetis' everywhere it is
    bundled (lacore falls back to its geometric ordering)."""
    platforms, wheels = manifest()
    for platform in platforms:
        picks = tags.legacy_installer_picks(wheels, platform)
        assert set(picks) == {"scipy", "trimesh", "cvxopt", "c3d", "typing_extensions"} | (  # file-name prefixes
            set() if platform.startswith("windows") else {"pymetis"})
        assert platform.startswith("windows") or picks["pymetis"].startswith("pymetis-2025.2.2-cp313-"), picks
        assert picks["scipy"].startswith("scipy-1.16.3-cp311-"), picks
        cvxopt_tag = "cp311" if platform.startswith("macos") else "cp313"
        assert picks["cvxopt"].startswith(f"cvxopt-1.3.2-{cvxopt_tag}-"), picks
    same_version = [w.replace("scipy-1.16.2-", "scipy-1.16.3-") for w in wheels]
    problems = tags.check_wheels(same_version, platforms)
    assert len(problems) == 4 and all("early Blender 4.2.x" in p and "scipy-1.16.3-cp313" in p for p in problems)
    assert tags._version_key("1.16.10") > tags._version_key("1.16.9") > tags._version_key("1.16")


def test_cp311_only_bundle_is_refused_for_python_313():
    """The issue's bug: every wheel cp311 -> no SciPy for Blender 5.1/5.2 (Python 3.13) on any platform."""
    _platforms, wheels = manifest()
    cp311_only = [w for w in wheels if "-cp313-" not in w]
    problems = tags.check_wheels(cp311_only, ALL)
    scipy_missing = sorted(p.split(":")[0] for p in problems if p.endswith("no usable wheel of scipy"))
    assert scipy_missing == sorted(f"{p} / Python 3.13 (Blender 5.1-5.2)" for p in ALL)
    assert tags.main([str(MANIFEST)]) == 0  # the real manifest is fine


@pytest.mark.parametrize("wheel, usable", [
    ("scipy-1.16.3-cp313-cp313-manylinux2014_x86_64.manylinux_2_17_x86_64.whl", {("linux-x64", (3, 13))}),
    ("scipy-1.16.3-cp311-cp311-manylinux_2_27_x86_64.whl", {("linux-x64", (3, 11))}),
    ("x-1.0-cp311-cp311-manylinux_2_34_x86_64.whl", set()),  # newer glibc than Blender's 2.28 baseline
    ("x-1.0-cp311-cp311-musllinux_1_2_x86_64.whl", set()),
    ("x-1.0-cp311-cp311-manylinux_2_17_aarch64.whl", set()),  # linux-arm64 is not a manifest platform
    ("x-1.0-cp313-cp313-win_amd64.whl", {("windows-x64", (3, 13))}),
    ("x-1.0-cp313-cp313-win32.whl", set()),
    ("x-1.0-cp311-cp311-macosx_12_0_arm64.whl", {("macos-arm64", (3, 11))}),
    ("x-1.0-cp311-cp311-macosx_14_0_arm64.whl", set()),  # needs a newer macOS than the 12 baseline
    ("x-1.0-cp313-cp313-macosx_10_9_universal2.whl", {("macos-arm64", (3, 13)), ("macos-x64", (3, 13))}),
    ("x-1.0-cp39-abi3-win_amd64.whl", {("windows-x64", (3, 11)), ("windows-x64", (3, 13))}),
    ("x-1.0-cp312-abi3-win_amd64.whl", {("windows-x64", (3, 13))}),
    ("x-1.0-py2.py3-none-any.whl", {(p, py) for p in ALL for py in ((3, 11), (3, 13))}),
    ("x-1.0-py312-none-any.whl", {(p, (3, 13)) for p in ALL}),
    ("x-1.0-cp312-cp312-win_amd64.whl", set()),  # Python 3.12: no supported Blender
    ("x-1.0-pp310-pypy310_pp73-win_amd64.whl", set()),
])
def test_tag_parsing(wheel, usable):
    got = {(p, py) for p in ALL for py in tags.SUPPORTED_PYTHONS if tags.wheel_supports(wheel, p, py)}
    assert got == usable


def test_ambiguous_and_unusable_wheels_are_reported():
    wheels = ["a-1.0-py3-none-any.whl", "a-2.0-py3-none-any.whl",  # two usable everywhere
              "b-1.0-cp311-cp311-musllinux_1_2_x86_64.whl"]  # usable nowhere, b missing everywhere
    problems = tags.check_wheels(wheels, ["linux-x64"])
    assert sum("2 wheels of a are usable" in p for p in problems) == 2
    assert sum(p.endswith("no usable wheel of b") for p in problems) == 2
    assert any(p.startswith("b-1.0-cp311-cp311-musllinux_1_2_x86_64.whl: usable on none") for p in problems)
    assert tags.check_wheels(["a-1.0-py3-none-any.whl"], ["linux-riscv"]) != []
    assert "not a wheel" in tags.check_wheels(["a-1.0.tar.gz"], ["linux-x64"])[0]


def _zip(path, manifest_text, wheels):
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("blender_manifest.toml", manifest_text)
        for w in wheels:
            zf.writestr(w.removeprefix("./"), b"")
    return str(path)


def test_zip_check(tmp_path):
    """A zip must hold exactly the wheels its manifest lists (for the platforms it serves)."""
    text = MANIFEST.read_text(encoding="utf-8")
    _platforms, wheels = manifest()
    assert tags.check_zip(_zip(tmp_path / "good.zip", text, wheels)) == []
    problems = tags.check_zip(_zip(tmp_path / "bad.zip", text, wheels[1:] + ["./wheels/extra-1.0-py3-none-any.whl"]))
    assert any("linux-x64: manifest lists" in p and wheels[0][2:] in p for p in problems), problems
    assert any("does not list" in p and "extra-1.0" in p for p in problems)


def test_split_platform_zip_check(tmp_path):
    """`--split-platforms` zips keep the whole manifest but hold one platform's wheels (what
    `make extension-split` builds): fine if that platform has all of its wheels, for both Pythons."""
    text = MANIFEST.read_text(encoding="utf-8")
    _platforms, wheels = manifest()
    mac = [w for w in wheels if "x86_64.whl" in w and "macosx" in w or w.endswith("-none-any.whl")]
    assert len(mac) == 8  # scipy cp311 + cp313, cvxopt cp311, pymetis cp311 + cp313, trimesh, c3d, typing_extensions
    assert tags.check_zip(_zip(tmp_path / "mac.zip", text, mac)) == []
    no313 = [w for w in mac if "-cp313-" not in w]
    problems = tags.check_zip(_zip(tmp_path / "mac311.zip", text, no313))
    assert problems[:2] == [f"{tmp_path / 'mac311.zip'}: macos-x64: manifest lists wheels/{w} but the zip does not "
                            "hold it" for w in ("pymetis-2025.2.2-cp313-cp313-macosx_10_13_x86_64.whl",
                                                "scipy-1.16.2-cp313-cp313-macosx_10_14_x86_64.whl")]
    assert len(problems) == 3 and "holds the wheels of none" in problems[2]
    pure = [w for w in wheels if w.endswith("-none-any.whl")]
    assert "holds the wheels of none" in tags.check_zip(_zip(tmp_path / "pure.zip", text, pure))[-1]
