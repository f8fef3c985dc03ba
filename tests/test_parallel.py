"""Worker processes (lacore.parallel): chains of frames, the same results as one process, progress, on_frame,
cancel, errors from a worker, lacore imported under a package prefix (as inside Blender), the CLI's --workers."""

import json
import os
import pickle
import shutil
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from conftest import REPO, load_topology, shared_mesh

from lacore import parallel
from lacore.cache import DerivedCache
from lacore.cli import main
from lacore.errors import InputError, LengthsAnglesError
from lacore.shapes.interpolation import interpolate
from lacore.shapes.projection import ProjectionOptions, ProjectionTargets, project_chain
from lacore.parallel import WorkerError, WorkerProcess, check_workers, close_workers, frame_chains
from lacore.progress import Cancelled


def sleeping_job(seconds, *, send):
    """A worker job for the tests (pickled by reference: the tests directory is on the worker's sys.path)."""
    send(os.getpid())
    time.sleep(seconds)
    return "slept"


def test_frame_chains_start_next_to_a_key():
    t = np.arange(1, 11) / 11.0
    a, b = frame_chains(t, [0.0, 1.0], 2)
    assert a.tolist() == [0, 1, 2, 3, 4] and b.tolist() == [9, 8, 7, 6, 5]
    chains = frame_chains(t[::-1], [0.0, 1.0], 2)           # indices refer to the given order
    assert [t[::-1][c].tolist() for c in chains] == [t[:5].tolist(), t[:4:-1].tolist()]
    three = frame_chains(t, [0.0, 1.0], 3)
    assert sorted(np.concatenate(three).tolist()) == list(range(10))
    assert three[0][0] == 0 and three[2][0] == 9             # outer chains start at the keys
    assert len(frame_chains(t[:2], [0.0], 5)) == 2            # no more chains than frames
    assert frame_chains([0.3, 0.1, 0.2], [], 1)[0].tolist() == [1, 2, 0]
    # extrapolation beyond the last key: the chain runs away from it
    assert frame_chains([1.5, 1.25, 2.0, 1.75], [0.0, 1.0], 2)[0].tolist() == [1, 0]
    assert frame_chains([1.5, 1.25, 2.0, 1.75], [0.0, 1.0], 2)[1].tolist() == [3, 2]


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_check_workers_names_the_value(bad):
    with pytest.raises((InputError, ValueError), match="workers|invalid literal"):
        check_workers(bad)


def test_a_pickled_topology_arrives_without_its_cache():
    X, topo = load_topology("octa/octa_src_small.ply")
    _ = topo.interior_edges
    assert len(topo.cache) > 0
    copy = pickle.loads(pickle.dumps(topo))
    assert len(copy.cache) == 0 and isinstance(copy.cache, DerivedCache)
    assert np.array_equal(copy.edges, topo.edges) and np.array_equal(copy.edge_faces, topo.edge_faces)
    assert np.array_equal(copy.interior_edges, topo.interior_edges)


@pytest.fixture(scope="module")
def finger():
    X0, topo = load_topology("finger/finger0.ply")
    X1, _ = load_topology("finger/finger1.ply")
    return [X0, X1], topo


def test_two_workers_give_the_frames_of_one_process(finger):
    shapes, topo = finger
    t = np.linspace(0.05, 0.95, 8)
    one = interpolate(shapes, topo, t, method="gn")
    seen, progress = [], []
    two = interpolate(shapes, topo, t, method="gn", workers=2, on_frame=lambda i, res: seen.append(i),
                      progress=lambda done, total, message: progress.append((done, total)))
    assert two.workers == 2 and one.workers == 1
    assert two.order.tolist() == [0, 1, 2, 3, 7, 6, 5, 4]
    assert sorted(seen) == list(range(8))
    assert [d for d, _ in progress] == list(range(9)) and {n for _, n in progress} == {8}
    assert two.success and all(r is not None for r in two.reconstructions)
    # converged Gauss-Newton: the same minimizers (measured 7.5e-10 relative energy, 6.2e-7 in vertices)
    assert np.max(np.abs(two.energy / one.energy - 1)) < 1e-8
    assert np.abs(two.vertices - one.vertices).max() < 5e-6
    assert np.all(two.seconds > 0) and np.all(np.isfinite(two.max_length_error))
    # the worker's chain started from the second key (time 1), this process's from the first
    assert two.warm_start_times[7] == 1.0 and two.warm_start_times[0] == 0.0


def test_fast_with_workers_matches_within_its_tolerance(finger):
    shapes, topo = finger
    t = np.arange(1, 7) / 7.0
    ref = interpolate(shapes, topo, t, method="gn")
    two = interpolate(shapes, topo, t, workers=2)  # the default projection, Fast
    assert np.max(two.energy / ref.energy - 1) < 2e-3   # measured 3.5e-4 (the goal: 0.5 %)


def test_cancel_kills_the_workers(finger):
    shapes, topo = finger
    t = np.linspace(0.05, 0.95, 8)
    with pytest.raises(Cancelled):
        interpolate(shapes, topo, t, workers=2, progress=lambda done, total, message: done >= 2)
    assert not parallel._RUNNING


def test_an_error_in_a_worker_is_raised_here_with_its_message(finger):
    shapes, topo = finger
    # a worker whose targets are bad (non-positive lengths) fails with the input error, raised here as itself
    bad = ProjectionTargets(np.zeros((1, 2 * topo.n_edges)), topo, shapes[0], np.array([0.5]), ())
    worker = WorkerProcess(project_chain, (bad, ProjectionOptions()))
    tag, kind, payload = worker.messages.get(timeout=60)
    worker.close()
    assert kind == "error" and payload[0] == "LengthsAnglesError"
    with pytest.raises(LengthsAnglesError, match="target at t = 0.5"):
        parallel.raise_worker_error(payload)
    with pytest.raises(WorkerError, match="ZeroDivisionError: division by zero\n.*Traceback"):
        parallel.raise_worker_error(("ZeroDivisionError", "division by zero", "Traceback (most recent call last)"))


def test_a_worker_that_cannot_start_names_the_interpreter(monkeypatch, tmp_path):
    missing = str(tmp_path / "no-such-python")
    monkeypatch.setattr(sys, "executable", missing)
    with pytest.raises(WorkerError, match="could not start a worker process .*no-such-python"):
        WorkerProcess(sleeping_job, (1,))
    assert not parallel._RUNNING


def test_close_workers_kills_a_running_job():
    worker = WorkerProcess(sleeping_job, (60,))
    tag, kind, pid = worker.messages.get(timeout=60)
    assert kind == "message" and pid != os.getpid() and worker.running
    close_workers()
    assert not worker.running and not parallel._RUNNING
    tag, kind, payload = worker.messages.get(timeout=10)   # the reader reports the end, naming it
    assert kind == "error" and "ended unexpectedly" in payload[1]


def test_a_worker_imports_lacore_under_a_package_prefix(tmp_path):
    """Inside Blender lacore is bl_ext.<repository>.<extension>.lacore and the add-on's __init__ imports bpy:
    a worker must import lacore under that name without importing the packages above it."""
    ext = tmp_path / "fake_ext" / "user_default" / "lengths_angles"
    shutil.copytree(REPO / "lacore", ext / "lacore", ignore=shutil.ignore_patterns("__pycache__"))
    (ext / "__init__.py").write_text("raise ImportError('the add-on itself must not be imported by a worker')\n")
    script = textwrap.dedent(f"""
        import sys, types
        sys.path.insert(0, {str(tmp_path)!r})
        for name, path in [("fake_ext", {str(tmp_path / "fake_ext")!r}),
                           ("fake_ext.user_default", {str(tmp_path / "fake_ext" / "user_default")!r}),
                           ("fake_ext.user_default.lengths_angles", {str(ext)!r})]:
            module = types.ModuleType(name)
            module.__path__ = [path]
            sys.modules[name] = module
        import numpy as np
        from fake_ext.user_default.lengths_angles.lacore.shapes.interpolation import interpolate
        from fake_ext.user_default.lengths_angles.lacore.io.meshes import load_mesh
        from fake_ext.user_default.lengths_angles.lacore.geometry.topology import MeshTopology
        X0, F = load_mesh({str(shared_mesh("plate/plate121_rolledA.ply"))!r})
        X1, _ = load_mesh({str(shared_mesh("plate/plate121_rolledB.ply"))!r})
        topo = MeshTopology.from_faces(F, n_vertices=len(X0))
        r = interpolate([X0, X1], topo, [0.25, 0.5, 0.75, 0.9], workers=2)
        print(r.workers, type(r.reconstructions[3]).__module__, r.success)
    """)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=env,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["2", "fake_ext.user_default.lengths_angles.lacore.reconstruction.result", "True"]


def test_cli_workers(tmp_path, capsys):
    plates = [shared_mesh(f"plate/{n}.ply") for n in ("plate121_rolledA", "plate121_rolledB")]
    prefix = tmp_path / "inb"
    code = main(["interpolate", *map(str, plates), "--t", "0.2", "0.4", "0.6", "0.8", "--workers", "2",
                 "-o", str(prefix), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    summary = json.loads(out)
    assert summary["workers"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"inb_{i:03d}.ply" for i in range(4)]
    with pytest.raises(SystemExit) as exc:
        main(["interpolate", *map(str, plates), "--t", "0.5", "--workers", "0", "-o", str(tmp_path / "bad")])
    assert exc.value.code == 2
    assert "--workers" in capsys.readouterr().err


def test_call_in_process_builds_a_mixer_relays_progress_and_cancels_at_once():
    """A mixer built in a worker process (what Blender's modal Enable Live Mixing does) is the one built here;
    its stage reports arrive; a cancel kills the worker; a lacore input error comes back as its one line."""
    import io

    from lacore.samples.bar import bar_mesh, bar_pose
    from lacore.shapes.mixing import ShapeMixer
    from lacore.shapes.mixing.mixer import build_mixer_bytes
    X, F = bar_mesh(n_along=12, n_side=2)
    keys = np.stack([X, bar_pose(X, 1.2, 0.0), bar_pose(X, 0.0, 1.0)])
    seen = []
    data = parallel.call_in_process(build_mixer_bytes, (keys, F), progress=lambda *r: seen.append(r))
    mixer = ShapeMixer.load(io.BytesIO(data))
    here = ShapeMixer.build(keys, F)
    w = [0.4, 0.7]
    assert np.abs(mixer.mix(w).vertices - here.mix(w).vertices).max() < 1e-9 * np.ptp(X)
    assert seen[-1][0] == seen[-1][1] and len({m for _, _, m in seen}) >= 3
    with pytest.raises(Cancelled):
        parallel.call_in_process(build_mixer_bytes, (keys, F), progress=lambda done, total, message: done >= 1)
    assert not parallel._RUNNING
    with pytest.raises(InputError, match="keys"):
        parallel.call_in_process(build_mixer_bytes, (keys[:1], F))
