"""Which Blenders the add-on checks run in (tests/conftest.py): a missing bpy venv is skipped with its
reason when pytest runs by hand, and FAILS under `make test` (LACORE_REQUIRE_BLENDERS=1)."""

import pytest
from conftest import BLENDERS, REPO, ExtensionZip, blender_python, blender_python_version, blender_pythons


def test_configured_from_environment(monkeypatch, tmp_path):
    python = tmp_path / "python"
    python.write_text("")
    monkeypatch.setenv("LACORE_BLENDER_PYTHONS", f"4.2={python}:5.2={tmp_path / 'missing'}")
    monkeypatch.delenv("LACORE_REQUIRE_BLENDERS", raising=False)
    assert blender_pythons() == {"4.2": str(python), "5.2": str(tmp_path / "missing")}
    assert blender_python("4.2") == str(python)
    with pytest.raises(pytest.skip.Exception, match="no bpy venv for Blender 5.2"):
        blender_python("5.2")
    monkeypatch.setenv("LACORE_REQUIRE_BLENDERS", "1")
    with pytest.raises(pytest.fail.Exception, match="no bpy venv for Blender 5.2"):
        blender_python("5.2")
    with pytest.raises(pytest.fail.Exception, match="Blender 9.9 is not configured"):
        blender_python("9.9")


def test_defaults_and_zip_path(monkeypatch):
    monkeypatch.delenv("LACORE_BLENDER_PYTHONS", raising=False)
    assert "4.2" in BLENDERS and "5.2" in BLENDERS  # `make test` configures both
    assert [blender_python_version(v) for v in ("4.2", "4.5", "5.0", "5.1", "5.2")] == [(3, 11)] * 3 + [(3, 13)] * 2
    assert blender_pythons() == {"4.2": str(REPO / ".venv-blender42" / "bin" / "python"),
                                 "5.2": str(REPO / ".venv-blender52" / "bin" / "python")}
    z = ExtensionZip("/x/ext.zip", "4.2", "/py")
    assert z == "/x/ext.zip" and (z.label, z.python) == ("4.2", "/py") and z.endswith(".zip")
