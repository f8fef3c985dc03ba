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
    everywhere but macOS on Python 3.13 (lacore's SciPy backend there)."""
    platforms, wheels = manifest()
    matrix = tags.wheel_matrix(wheels, platforms)
    assert len(matrix) == 8
    for (platform, python), dists in matrix.items():
        assert set(dists) == {"scipy", "trimesh", "cvxopt", "c3d"}
        cp = f"cp{python[0]}{python[1]}"
        assert [w.split("-")[2] for w in dists["scipy"]] == [cp], (platform, python, dists["scipy"])
        assert dists["trimesh"] == ["trimesh-5.2.0-py3-none-any.whl"]
        assert dists["c3d"] == ["c3d-0.6.0-py3-none-any.whl"]
        missing_cvxopt = platform.startswith("macos") and python == (3, 13)
        assert len(dists["cvxopt"]) == (0 if missing_cvxopt else 1), (platform, python, dists["cvxopt"])
    assert {(d, p, py) for (p, py), ds in matrix.items() for d, w in ds.items() if not w} == tags.KNOWN_GAPS


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


def test_zip_check(tmp_path):
    """A zip must hold exactly the wheels its manifest lists."""
    text = MANIFEST.read_text(encoding="utf-8")
    _platforms, wheels = manifest()
    good, bad = tmp_path / "good.zip", tmp_path / "bad.zip"
    for path, held in ((good, wheels), (bad, wheels[1:] + ["./wheels/extra-1.0-py3-none-any.whl"])):
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("blender_manifest.toml", text)
            for w in held:
                zf.writestr(w[2:], b"")
    assert tags.check_zip(str(good)) == []
    problems = tags.check_zip(str(bad))
    assert any("does not hold" in p and wheels[0][2:] in p for p in problems)
    assert any("does not list" in p and "extra-1.0" in p for p in problems)
