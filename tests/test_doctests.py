"""The Examples sections of lacore's docstrings run as doctests, and every public entry point has one.

Examples use tiny meshes (:func:`lacore.samples.bar.bar_mesh`) and print rounded values, so they run in
seconds and give the same output under NumPy 1.26 and 2.x.
"""

import doctest
import importlib
import pkgutil
import io
import tempfile

import pytest

import lacore

#: Modules not imported here: running ``python -m lacore.cli`` is what ``__main__`` does on import.
SKIP = {"lacore.cli.__main__"}
MODULES = sorted(m.name for m in pkgutil.walk_packages(lacore.__path__, "lacore.") if m.name not in SKIP)

#: The main public functions and classes of the sub-packages, besides ``lacore.__all__``.
MAIN_ENTRY_POINTS = [
    "lacore.io.meshes.load_mesh", "lacore.io.meshes.save_mesh", "lacore.io.point_cache.write_pc2",
    "lacore.io.point_cache.read_pc2", "lacore.io.atomic.atomic_write",
    "lacore.linalg.sparse_cholesky.SparseCholesky", "lacore.linalg.heap.retained_heap",
    "lacore.reconstruction.context.get_context", "lacore.reconstruction.settings.split_options",
    "lacore.shapes.interpolation.project_targets", "lacore.shapes.geodesics.projected_linear_path",
    "lacore.multiresolution.coarsening.coarsen", "lacore.multiresolution.reconstruction.MultiresolutionReconstruction",
    "lacore.models.shape_model.ShapeModel.fit", "lacore.models.shape_model.ShapeModel.synthesize",
    "lacore.models.shape_model.ShapeModel.coefficients", "lacore.models.shape_model.ShapeModel.save",
    "lacore.samples.bar.bar_mesh", "lacore.samples.bar.bar_pose", "lacore.cli.main",
    "lacore.markers.calibration.calibrate", "lacore.markers.take_fit.fit_take",
    "lacore.geometry.self_intersection.self_intersections", "lacore.markers.interpenetration.new_self_intersections",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the examples' temporary folders go there
    module = importlib.import_module(name)
    out = io.StringIO()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in doctest.DocTestFinder().find(module, name):
        runner.run(test, out=out.write)
    assert runner.failures == 0, out.getvalue()


@pytest.mark.parametrize("name", [f"lacore.{n}" for n in lacore.__all__] + MAIN_ENTRY_POINTS)
def test_public_entry_point_has_an_example(name):
    obj = getattr(lacore, name[len("lacore."):]) if name.count(".") == 1 else pkgutil.resolve_name(name)
    doc = obj.__doc__ or ""
    assert "Examples\n" in doc and ">>> " in doc, f"{name} has no Examples section with a doctest"
