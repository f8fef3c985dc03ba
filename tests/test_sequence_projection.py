"""lacore.shapes.projection.SequenceProjection: the one projection loop, step by step (thesis 4.10).

The entry points (interpolate, project_targets, keyframe_inbetweens), the worker processes and the
Blender add-on all run it; stepping it gives the frames of interpolate, one per step; worker chains,
take-over of a failed worker and close() as in lacore.parallel; the add-on imports public names only.
"""

import ast
import importlib
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, load_topology

from lacore import parallel
from lacore.errors import InputError, LengthsAnglesError
from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.geometry.rigid import rigid_rms
from lacore.progress import Cancelled
from lacore.reconstruction import GaussNewtonOptions, HybridOptions
from lacore.shapes.interpolation import interpolate, keyframe_targets, project_targets
from lacore.shapes.projection import ProjectionOptions, ProjectedFrame, SequenceProjection

T = np.linspace(0.1, 0.9, 6)
FAST = ProjectionOptions(method="hybrid", options=GaussNewtonOptions(ftol=1e-4),
                         hybrid=HybridOptions(start="given", smoothing_iterations=1, nearest_start_iterations=3))


@pytest.fixture(scope="module")
def finger():
    X0, topo = load_topology("finger/finger0.ply")
    X1, _ = load_topology("finger/finger1.ply")
    z = np.stack([lengths_and_angles(X, topo) for X in (X0, X1)])
    return topo, X0, X1, keyframe_targets(z, [0.0, 1.0], T)


def sequence(finger, **kwargs):
    """The finger's frames, by converged Gauss-Newton unless other options are given."""
    topo, X0, X1, targets = finger
    kwargs.setdefault("options", ProjectionOptions("gn"))
    return SequenceProjection(targets, topo, X0, T, [(0.0, X0), (1.0, X1)], **kwargs)


def test_steps_give_the_frames_of_interpolate_one_per_step(finger):
    topo, X0, X1, _ = finger
    reference = interpolate([X0, X1], topo, T, method="gn")
    run = sequence(finger)
    assert (run.done, run.total, run.finished, run.chains) == (0, 6, False, None)  # nothing computed yet
    steps = []
    while not run.finished:
        steps.append(run.step())
    assert steps == [[i] for i in range(6)] and run.done == 6 and run.step() == []
    assert run.processes == 1 and run.local_frames == 6 and run.order.tolist() == list(range(6))
    assert all(isinstance(f, ProjectedFrame) and f.index == i and f.time == T[i] for i, f in enumerate(run.frames))
    X = np.array([f.result.vertices for f in run.frames])
    # the same loop in the same process: the same numbers
    assert np.array_equal(X, reference.vertices)
    assert [f.warm_start_time for f in run.frames] == reference.warm_start_times.tolist()
    assert np.array_equal([f.max_length_error for f in run.frames], reference.max_length_error)


def test_run_reports_progress_streams_frames_and_cancels(finger):
    seen, progress = [], []
    run = sequence(finger).run(lambda done, total, message: progress.append((done, total, message)),
                               on_frame=lambda i, result: seen.append((i, result.success)))
    assert [p[0] for p in progress] == list(range(7)) and {p[1] for p in progress} == {6}
    assert progress[0][2] == "projecting frames" and progress[3][2] == f"frame 3 of 6 (t = {T[2]:g})"
    assert seen == [(i, True) for i in range(6)]
    run = sequence(finger)
    with pytest.raises(Cancelled):
        run.run(lambda done, total, message: done >= 2)
    assert run.done == 2
    with pytest.raises(Cancelled, match="closed"):  # a cancelled run stays closed
        run.step()


def test_anchors_in_any_placement_give_the_same_frames(finger):
    """Known shapes may come rigidly moved (the add-on passes frames placed on the keys' blend)."""
    topo, X0, X1, targets = finger
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = SequenceProjection(targets, topo, X0, T, [(0.0, X0 @ R.T + 3.0), (1.0, X1 @ R.T - 1.0)],
                               options=ProjectionOptions("gn")).run()
    plain = sequence(finger).run()
    diag = np.linalg.norm(np.ptp(X0, axis=0))
    diff = max(np.abs(a.result.vertices - b.result.vertices).max() for a, b in zip(moved.frames, plain.frames,
                                                                                  strict=True))
    assert diff < 1e-10 * diag, diff  # measured 1.0e-14 of the diagonal (round-off of the rigid motion)


def test_two_chains_step_by_step_and_all_in_workers(finger):
    one = sequence(finger, options=FAST).run()
    run = sequence(finger, options=FAST, workers=2)
    first = run.step()  # this process's first frame; the worker process runs the other chain
    assert first == [0] and len(parallel._RUNNING) == 1 and run.processes == 2
    run.run()
    assert run.local_frames == 3 and sorted(run.order.tolist()) == list(range(6))
    assert run.order.tolist() == [0, 1, 2, 5, 4, 3]  # the second chain starts next to the key at t = 1
    energy = np.array([f.result.energy for f in run.frames]) / np.array([f.result.energy for f in one.frames])
    assert np.max(energy - 1) < 5e-4  # Fast: other warm starts in the second chain (measured 5.3e-5)
    assert not parallel._RUNNING
    every = sequence(finger, workers=2, all_in_workers=True).run()
    gn = sequence(finger).run()
    assert every.local_frames == 0 and every.processes == 2
    diag = np.linalg.norm(np.ptp(finger[1], axis=0))
    # converged Gauss-Newton from other warm starts: the same minimizers (measured 4.2e-8 of the diagonal)
    assert max(rigid_rms(a.result.vertices, b.result.vertices) for a, b in zip(every.frames, gn.frames,
                                                                              strict=True)) < 1e-6 * diag


def test_a_worker_that_cannot_start_raises_or_is_taken_over(finger, monkeypatch, tmp_path):
    gn = sequence(finger).run()
    monkeypatch.setattr(sys, "executable", str(tmp_path / "no-such-python"))
    with pytest.raises(parallel.WorkerError, match="could not start"):
        sequence(finger, workers=2).run()
    run = sequence(finger, workers=2, take_over=True).run()
    assert run.processes == 1 and run.local_frames == 6 and len(run.notes) == 1
    assert "its 3 frame(s) were computed in this process instead" in run.notes[0]
    # converged Gauss-Newton: the same minimizers (the taken-over chain starts from other known shapes)
    diag = np.linalg.norm(np.ptp(finger[1], axis=0))
    assert max(rigid_rms(a.result.vertices, b.result.vertices) for a, b in zip(run.frames, gn.frames,
                                                                              strict=True)) < 1e-6 * diag


def test_close_kills_the_workers_and_a_dead_worker_is_taken_over(finger):
    run = sequence(finger, workers=2)
    run.step()
    assert len(parallel._RUNNING) == 1
    run.close()
    assert not parallel._RUNNING
    run = sequence(finger, workers=2, take_over=True)
    run.step()
    for worker in list(parallel._RUNNING):
        worker._process.kill()
    run.run()
    assert run.finished and run.processes == 1 and len(run.notes) == 1 and "ended unexpectedly" in run.notes[0]


def test_options_and_targets_are_checked_before_any_work(finger):
    topo, X0, X1, targets = finger
    with pytest.raises(InputError, match="unknown projection method 'bogus'"):
        ProjectionOptions(method="bogus")
    with pytest.raises(InputError, match="warm_start must be True, False or one of secant, nearest"):
        ProjectionOptions(warm_start="cubic")
    assert ProjectionOptions(warm_start=False).warm_start is None and not ProjectionOptions("lsq").takes_start
    bad = targets.copy()
    bad[3, : topo.n_edges] *= -1.0
    with pytest.raises(LengthsAnglesError, match=f"target at t = {T[3]:g} \\(extrapolated too far"):
        SequenceProjection(bad, topo, X0, T)
    with pytest.raises(InputError, match="5 times for 6 targets"):
        SequenceProjection(targets, topo, X0, T[:5])
    with pytest.raises(TypeError, match="options must be a ProjectionOptions"):
        SequenceProjection(targets, topo, X0, T, options={"method": "gn"})


def test_project_targets_is_the_same_loop(finger):
    topo, X0, X1, targets = finger
    res = project_targets(targets, topo, X0, times=T, anchors=[(0.0, X0), (1.0, X1)], method="gn")
    run = sequence(finger).run()
    assert np.array_equal(res.vertices, [f.result.vertices for f in run.frames])
    assert res.workers == 1 and res.order.tolist() == list(range(6)) and res.success


def test_the_addon_imports_public_lacore_names_only():
    """addon/ reads Blender data and calls lacore's public API: every name it imports from lacore is in its
    module's __all__, and none of the loop's internals (the add-on steps SequenceProjection)."""
    internals = {"split_options", "ChainWorkers", "frame_chains", "project_chain", "WorkerProcess"}
    found = []
    for path in sorted(Path(REPO, "addon").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 2 and (node.module or "").startswith("lacore"):
                module = importlib.import_module(node.module)
                for alias in node.names:
                    found.append(alias.name)
                    assert not alias.name.startswith("_") and alias.name in getattr(module, "__all__", ()), \
                        (path.name, node.module, alias.name)
                    assert alias.name not in internals, (path.name, alias.name)
    assert "SequenceProjection" in found and "ProjectionOptions" in found


def test_a_given_context_is_the_runs_and_works_in_this_process_only(finger):
    from lacore.reconstruction.context import ReconstructionContext

    topo, X0, X1, _ = finger
    ctx = ReconstructionContext(topo, X0, ProjectionOptions("gn").settings)     # not the cached one
    run = sequence(finger, context=ctx)
    run.step()
    assert run.context is ctx and run.frames[0].result.success
    with pytest.raises(InputError, match=r"^a given context works in this process only: use workers=1 with it$"):
        sequence(finger, context=ctx, workers=2)
