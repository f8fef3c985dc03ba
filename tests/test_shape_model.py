"""Shape models in lengths and angles (thesis 4.3, (4.14)-(4.19)): lacore.models.shape_model.ShapeModel."""

from dataclasses import replace
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lacore import MeshTopology, lengths_and_angles
from lacore.errors import InputError, MeshError, ReconstructionWarning
from lacore.integrability.local import euler_integrability_jacobian
from lacore.io.meshes import load_mesh
from lacore.progress import Cancelled
from lacore.geometry.rigid import apply_rigid, rigid_rms
from lacore.samples.bar import articulated_bar_pose, bar_family, bar_mesh, bar_pose
from lacore.models.settings import MODEL_OPTIONS
from lacore.models.shape_model import ShapeModel, ShapeModelError, TangentProjector

# bend x twist grid: one-sided ranges where the bend-twist interaction (the third direction) stays below 0.1 %
BENDS, TWISTS = np.linspace(0.0, 0.3, 4), np.linspace(0.0, 0.1, 4)


@pytest.fixture(scope="module")
def bar():
    poses, faces, params = bar_family(BENDS, TWISTS)
    topo = MeshTopology.from_faces(faces, n_vertices=poses.shape[1])
    return poses, topo, params


@pytest.fixture(scope="module")
def bar_models(bar):
    poses, topo, _ = bar
    return {t: ShapeModel.fit(poses, topo, tangent=t, n_modes=3) for t in ("ambient", "projected")}


def _diag(X):
    return float(np.linalg.norm(X.max(0) - X.min(0)))


@pytest.mark.parametrize("tangent", ["ambient", "projected"])
def test_bar_family_has_two_modes_and_synthesis_reproduces_training_poses(bar, tangent):
    import lacore

    poses, topo, _ = bar
    model = lacore.ShapeModel.fit(poses, topo, tangent=tangent, n_modes=2)
    # measured 0.99956 (ambient) / 0.99957 (projected); the third direction is the bend-twist interaction
    assert model.explained_variance_ratio.sum() > 0.999
    assert model.explained_variance_ratio[0] > 0.9
    X = model.synthesize(model.training_coefficients)
    rms = [rigid_rms(X[i], poses[i]) / _diag(poses[i]) for i in range(len(poses))]
    assert max(rms) < 1e-3  # measured 1.7e-4 (ambient)
    assert X.shape == poses.shape
    assert model.n_modes == 2 and model.n_samples == 16
    assert model.mean_z.shape == (2 * topo.n_edges,) and model.mean_vertices.shape == (topo.n_vertices, 3)
    # the mean is admissible: the lengths and angles of its vertices
    np.testing.assert_allclose(model.mean_z, lengths_and_angles(model.mean_vertices, topo), atol=1e-14)


@pytest.mark.parametrize("tangent", ["ambient", "projected"])
def test_modes_are_g_orthonormal_and_coefficients_are_g_projections(bar_models, bar, tangent):
    model = bar_models[tangent]
    G = model.metric_dot(model.modes[:, None, :], model.modes[None, :, :])
    assert np.abs(G - np.eye(model.n_modes)).max() < 1e-12  # measured 3e-14
    # metric = 1/2 Hessian of W_q (4.5): diagonal 2 w
    H = model.energy.hessian(model.mean_z, model.mean_z).diagonal()
    np.testing.assert_allclose(H, 2 * model.metric_weights)
    poses = bar[0]
    c = model.coefficients(poses)
    assert np.abs(c - model.training_coefficients).max() < 1e-12 * np.abs(c).max()
    np.testing.assert_allclose(model.coefficients(model.z_of(c)), c, atol=1e-12 * np.abs(c).max())
    # variances and ratios from the eigenvalues
    assert np.all(np.diff(model.variances) <= 0)
    np.testing.assert_allclose(model.variances, np.mean(model.training_coefficients**2, axis=0), rtol=1e-12)
    np.testing.assert_allclose(model.variances / model.total_variance, model.explained_variance_ratio, rtol=1e-12)


def test_projected_tangent_vectors_satisfy_linearized_integrability(bar_models, bar):
    model = bar_models["projected"]
    Z = np.stack([lengths_and_angles(x, model.topology) for x in bar[0]])
    A = euler_integrability_jacobian(model.mean_z, model.topology)
    raw = np.linalg.norm(A @ (Z - model.mean_z).T, axis=0)
    v = model.tangent_vectors(Z)
    res = np.linalg.norm(A @ v.T, axis=0)
    assert raw.max() > 1e-4  # measured 4.1e-4: the samples are not tangent
    assert res.max() < 1e-11 * raw.max()  # solver precision
    assert np.linalg.norm(A @ model.modes.T, axis=0).max() < 1e-12


@pytest.mark.parametrize("metric", ["euclidean", "g"])
def test_tangent_projection_matches_explicit_kernel_basis(metric):
    """The solve-based projection equals the SVD-basis one (thesis 4.1, small examples) on a closed mesh."""
    X0, faces = bar_mesh(n_along=5, n_side=1)
    topo = MeshTopology.from_faces(faces, n_vertices=len(X0))
    z = lengths_and_angles(bar_pose(X0, 0.4, 0.3), topo)
    w = np.random.default_rng(3).uniform(0.5, 2.0, 2 * topo.n_edges)
    P = TangentProjector(z, topo, metric_weights=w, metric=metric)
    A = euler_integrability_jacobian(z, topo).toarray()
    s = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(s > 1e-10 * s[0]))
    assert rank == topo.n_edges  # dim Z = E (4.3): 3V - 6 independent conditions on a closed mesh
    u = np.random.default_rng(4).normal(size=(3, 2 * topo.n_edges))
    if metric == "euclidean":
        _, _, Vt = np.linalg.svd(A)
        N = Vt[rank:].T
        expected = (N @ (N.T @ u.T)).T
    else:
        C = np.diag(1 / w)
        expected = u - (C @ A.T @ np.linalg.pinv(A @ C @ A.T, rcond=1e-10) @ A @ u.T).T  # cut at the known rank
    got = P(u)
    assert np.abs(got - expected).max() < 1e-10 * np.abs(u).max()
    np.testing.assert_allclose(P(got), got, atol=1e-12)  # idempotent
    if metric == "g":  # the remainder is g-orthogonal to every tangent vector
        t = P(np.random.default_rng(5).normal(size=2 * topo.n_edges))
        assert abs(np.sum(t * w * (u[0] - got[0]))) < 1e-11 * np.linalg.norm(u[0])


@pytest.mark.parametrize("tangent", ["ambient", "projected"])
def test_rigid_motions_of_training_meshes_change_no_mode_or_variance(bar, tangent):
    poses, topo, _ = bar
    rng = np.random.default_rng(7)
    moved = np.stack([apply_rigid(x, Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix(),
                                  rng.normal(size=3) * 10) for x in poses])
    a = ShapeModel.fit(poses, topo, tangent=tangent, n_modes=3)
    b = ShapeModel.fit(moved, topo, tangent=tangent, n_modes=3)
    # modes carrying variance (ratios 0.97, 0.03, 4e-4) agree to < 1e-9 (measured 3e-10); weaker directions
    # are determined only up to the mean's Gauss-Newton tolerance
    assert np.abs(a.modes - b.modes).max() < 1e-9
    assert np.abs(a.variances - b.variances).max() < 1e-9 * a.variances[0]
    assert np.abs(a.training_coefficients - b.training_coefficients).max() < 1e-9
    assert rigid_rms(b.mean_vertices, a.mean_vertices) < 1e-9 * _diag(a.mean_vertices)


def test_ambient_and_projected_pca_agree_to_first_order_near_the_mean():
    """For admissible samples at distance O(eps) from the mean, z - zbar is tangent up to O(eps^2)."""
    X0, faces = bar_mesh()
    topo = MeshTopology.from_faces(faces, n_vertices=len(X0))
    diffs = []
    for eps in (0.2, 0.1, 0.05):
        poses, _, _ = bar_family(np.linspace(0, eps, 3), np.linspace(0, eps / 2, 3))
        ma = ShapeModel.fit(poses, topo, tangent="ambient", n_modes=2)
        mp = ShapeModel.fit(poses, topo, tangent="projected", n_modes=2)
        va, vp = ma.tangent_vectors(poses), mp.tangent_vectors(poses)
        size = np.sqrt(ma.metric_dot(va, va).max())
        gap = np.sqrt(ma.metric_dot(va - vp, va - vp).max())
        dvar = np.abs(ma.variances - mp.variances).max() / ma.variances[0]
        diffs.append((size, gap, dvar))
    for (s0, g0, d0), (s1, g1, d1) in zip(diffs, diffs[1:], strict=False):
        assert 1.8 < s0 / s1 < 2.2  # samples shrink linearly with eps
        assert 3.5 < g0 / g1 < 4.5  # the normal part quadratically (measured 4.0)
        assert 3.5 < d0 / d1 < 4.5  # so do the variance differences (measured 4.1, 4.1)
    assert diffs[-1][2] < 2e-6  # measured 5.6e-7


def test_open_and_closed_real_meshes(meshes_dir):
    """Deformed spheres (closed, 10 samples) and plates (open; boundary vertices carry no conditions)."""
    spheres = [load_mesh(meshes_dir / "sphere" / f"defSphere{i}.ply") for i in range(10)]
    topo = MeshTopology.from_faces(spheres[0][1], n_vertices=len(spheres[0][0]))
    m = ShapeModel.fit([x for x, _ in spheres], topo, tangent="projected", n_modes=4)
    A = euler_integrability_jacobian(m.mean_z, topo)
    assert A.shape[0] == 3 * topo.n_vertices
    assert np.linalg.norm(A @ m.modes.T, axis=0).max() < 1e-10
    assert np.all(m.explained_variance_ratio > 0) and m.explained_variance_ratio.sum() < 1
    plates = [load_mesh(meshes_dir / "plate" / f"plate121{s}.ply") for s in ("", "_rolledA", "_rolledB")]
    topo = MeshTopology.from_faces(plates[0][1], n_vertices=len(plates[0][0]))
    m = ShapeModel.fit([x for x, _ in plates], topo, tangent="projected", n_modes=2)
    A = euler_integrability_jacobian(m.mean_z, topo)
    assert A.shape[0] == 3 * len(topo.interior_vertices) < 3 * topo.n_vertices
    assert np.linalg.norm(A @ m.modes.T, axis=0).max() < 1e-10
    G = m.metric_dot(m.modes[:, None], m.modes[None])
    assert np.abs(G - np.eye(2)).max() < 1e-12
    # boundary angles stay 0 in every mode
    assert np.abs(m.modes[:, topo.n_edges + topo.boundary_edges]).max() == 0


def test_mode_sweep_and_progress(bar_models):
    model = bar_models["ambient"]
    calls = []
    X, t = model.mode_sweep(0, (-1.0, 1.0), 3, progress=lambda d, n, msg: calls.append((d, n)))
    assert X.shape == (3, model.topology.n_vertices, 3)
    np.testing.assert_allclose(t, [-1, 0, 1])
    assert rigid_rms(X[1], model.mean_vertices) < 1e-9 * _diag(model.mean_vertices)
    c = model.coefficients(X, tangent="ambient")
    sd = model.standard_deviations[0]
    # the projection P_Z moves the swept z little along the mode itself (measured 0.3 %)
    np.testing.assert_allclose(c[:, 0], t * sd, atol=0.02 * sd)
    assert calls[0] == (0, 3) and calls[-1] == (3, 3)
    with pytest.raises(Cancelled):
        model.synthesize(np.zeros((2, model.n_modes)), progress=lambda d, n, msg: True)


def test_save_load_round_trip(bar_models, bar, tmp_path):
    model = bar_models["projected"]
    path = tmp_path / "model.npz"
    model.save(path)
    loaded = ShapeModel.load(path, faces=model.faces)
    for name in ("faces", "edges", "reference_vertices", "mean_z", "mean_vertices", "modes", "variances",
                 "explained_variance_ratio", "training_coefficients", "metric_weights"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(model, name), err_msg=name)
    assert (loaded.tangent, loaded.bending_weight, loaded.weights, loaded.method) == \
        (model.tangent, model.bending_weight, model.weights, model.method)
    # the tangent projector is rebuilt from the saved mean
    c = loaded.coefficients(bar[0])
    assert np.abs(c - model.training_coefficients).max() < 1e-12
    a = model.training_coefficients[5]
    assert np.abs(loaded.synthesize(a) - model.synthesize(a)).max() < 1e-12
    assert not [p for p in tmp_path.iterdir() if p.name != "model.npz"]  # no temp files left


def test_model_file_entries_are_the_field_table_and_files_of_version_1_load(bar_models, tmp_path):
    import io

    from lacore.models.model_io import FIELDS, FORMAT, FORMAT_ALIASES, FORMAT_VERSION

    model = bar_models["ambient"]
    buffer = io.BytesIO()
    model.save(buffer)
    d = dict(np.load(io.BytesIO(buffer.getvalue())))
    assert set(d) == {"format", "format_version"} | {f.name for f in FIELDS if getattr(model, f.name) is not None}
    assert str(d["format"]) == FORMAT == "lacore.shape_model" and int(d["format_version"]) == FORMAT_VERSION
    a = model.training_coefficients[3]
    # a version-1 file of an earlier writer: format named after the module path, no all_eigenvalues entry
    for fmt in FORMAT_ALIASES:
        older = dict(d, format=np.array(fmt))
        del older["all_eigenvalues"]
        np.savez(tmp_path / "older.npz", **older)
        loaded = ShapeModel.load(tmp_path / "older.npz", faces=model.faces)
        assert loaded.all_eigenvalues is None and loaded.n_modes == model.n_modes
        assert np.abs(loaded.synthesize(a) - model.synthesize(a)).max() < 1e-12
    np.savez(tmp_path / "nan.npz", **dict(d, variances=np.full_like(d["variances"], np.nan)))
    with pytest.raises(ShapeModelError, match=r"nan.npz is a corrupt shape model: variances has NaN or infinite "
                                              "entries"):
        ShapeModel.load(tmp_path / "nan.npz")
    np.savez(tmp_path / "tangent.npz", **dict(d, tangent=np.array("log")))
    with pytest.raises(ShapeModelError, match="tangent must be one of ambient, projected, got 'log'"):
        ShapeModel.load(tmp_path / "tangent.npz")
    np.savez(tmp_path / "missing.npz", **{k: v for k, v in d.items() if k != "mean_z"})
    with pytest.raises(ShapeModelError, match="corrupt shape model: missing mean_z"):
        ShapeModel.load(tmp_path / "missing.npz")


def test_bad_input_messages(bar, bar_models, tmp_path):
    poses, topo, _ = bar
    with pytest.raises(ShapeModelError, match="at least 2 training meshes, got 1"):
        ShapeModel.fit(poses[:1], topo)
    with pytest.raises(ShapeModelError, match=r"training mesh 2 has vertices of shape \(201, 3\).*correspondence"):
        ShapeModel.fit([poses[0], poses[1], poses[2][:-1]], topo)
    with pytest.raises(ShapeModelError, match=r"n_modes must be an integer from 1 to N - 1 = 15 \(16 samples\)"):
        ShapeModel.fit(poses, topo, n_modes=16)
    with pytest.raises(ShapeModelError, match="only 0 directions of the 2 training samples have non-zero variance"):
        ShapeModel.fit([poses[4], poses[4]], topo)
    assert ShapeModel.fit([poses[0], poses[1], poses[1]], topo, n_modes=2).n_modes == 2  # not centred: rank 2
    with pytest.raises(ShapeModelError, match="unknown tangent 'log'"):
        ShapeModel.fit(poses, topo, tangent="log")
    flat = poses[3].copy()
    flat[topo.faces[7]] = flat[topo.faces[7][0]]
    with pytest.raises(MeshError, match=r"training mesh 2: degenerate triangles \(zero area.*\): faces 7, "):
        ShapeModel.fit([poses[0], poses[1], flat], topo)
    model = bar_models["ambient"]
    with pytest.raises(ShapeModelError, match=r"coefficients must have shape \(3,\)"):
        model.synthesize(np.zeros(4))
    with pytest.raises(ShapeModelError, match=r"vertices of shape \(202, 3\)"):
        model.coefficients(np.zeros((5, 3)))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file at all")
    with pytest.raises(ShapeModelError, match="not a readable .npz shape model"):
        ShapeModel.load(bad)
    np.savez(tmp_path / "other.npz", faces=topo.faces)
    with pytest.raises(ShapeModelError, match="not a lacore shape model"):
        ShapeModel.load(tmp_path / "other.npz")
    model.save(tmp_path / "m.npz")
    d = dict(np.load(tmp_path / "m.npz"))
    np.savez(tmp_path / "v2.npz", **dict(d, format_version=np.array(3)))
    with pytest.raises(ShapeModelError, match="format version 3; this lacore reads versions 1 to 2"):
        ShapeModel.load(tmp_path / "v2.npz")
    np.savez(tmp_path / "cut.npz", **dict(d, modes=d["modes"][:, :-3]))
    with pytest.raises(ShapeModelError, match="corrupt shape model: modes has shape"):
        ShapeModel.load(tmp_path / "cut.npz")
    other = bar_mesh(n_along=10)[1]
    with pytest.raises(ShapeModelError, match="not this model's connectivity"):
        ShapeModel.load(tmp_path / "m.npz", faces=other)
    with pytest.raises(FileNotFoundError):
        ShapeModel.load(tmp_path / "missing.npz")
    assert issubclass(ShapeModelError, InputError)


def test_angles_straddling_the_branch_cut_are_averaged_on_the_circle():
    from lacore.models.shape_model import wrap_angles

    X0, faces = bar_mesh(n_along=6, n_side=1)
    topo = MeshTopology.from_faces(faces, n_vertices=len(X0))
    E = topo.n_edges
    z = lengths_and_angles(X0, topo)
    np.testing.assert_array_equal(wrap_angles(z, topo), z)
    d = np.zeros(2 * E)
    d[E:] = [np.pi + 0.1, -np.pi - 0.1, 2 * np.pi] + [0.0] * (E - 3)
    np.testing.assert_allclose(wrap_angles(d, topo)[E:E + 3], [-np.pi + 0.1, np.pi - 0.1, 0.0], atol=1e-15)
    # samples whose angle at one edge is +(pi - 0.05) and -(pi - 0.05): the mean sits at pi, not at 0
    Z = np.stack([z, z, z])
    Z[:, E] = [np.pi - 0.05, -(np.pi - 0.05), np.pi - 0.05]
    m = ShapeModel.fit_z(Z, topo, X0, n_modes=1, options=replace(MODEL_OPTIONS, max_iterations=0))
    assert abs(abs(m.linear_mean_z[E]) - (np.pi - 0.05 / 3)) < 1e-12
    v = m.tangent_vectors(Z)
    assert np.abs(v[:, E]).max() < 0.2 + np.pi - abs(m.mean_z[E])


def test_localized_modes_separate_the_joints_of_an_articulated_bar():
    """Two independent joints with equal ranges: PCA mixes them, the g-varimax rotation separates them."""
    X0, faces = bar_mesh()
    topo = MeshTopology.from_faces(faces, n_vertices=len(X0))
    g = np.linspace(-0.5, 0.5, 5)
    poses = np.stack([articulated_bar_pose(X0, (a, b)) for a in g for b in g])
    model = ShapeModel.fit(poses, topo, tangent="projected", n_modes=2, reference_vertices=X0)
    halves = (X0[:, 0] > 3.0).astype(int)  # the joints sit at x = 2 and x = 4
    assert model.region_energy(halves).max(axis=1).max() < 0.6  # measured 0.50: both modes move both joints
    local = model.localized()  # default regions: single vertices
    share = local.region_energy(halves)
    assert np.all(share.max(axis=1) > 0.999)  # measured 1 - 2e-7
    assert sorted(share.argmax(axis=1)) == [0, 1]  # one mode per joint
    assert local.localization["objective_after"] > 1.9 * local.localization["objective_before"]
    # the same subspace: z_of and the fit of any pose are unchanged up to the rotation
    R = local.rotation
    np.testing.assert_allclose(R @ R.T, np.eye(2), atol=1e-12)
    c = model.training_coefficients
    np.testing.assert_allclose(local.z_of(c @ R.T), model.z_of(c), atol=1e-12)
    np.testing.assert_allclose(local.coefficients(poses), c @ R.T, atol=1e-10)
    G = local.metric_dot(local.modes[:, None], local.modes[None])
    assert np.abs(G - np.eye(2)).max() < 1e-12
    np.testing.assert_allclose(local.variances.sum(), model.variances.sum(), rtol=1e-12)
    with pytest.raises(ShapeModelError, match="one label per vertex"):
        model.localized(regions=np.zeros(7, int))


def test_synthesis_far_out_clamps_lengths(bar_models):
    model = bar_models["ambient"]
    E = model.topology.n_edges
    u, lbar = model.modes[0, :E], model.mean_z[:E]
    a = np.zeros((2, model.n_modes))
    a[1, 0] = 1.2 * np.min(lbar[u < 0] / -u[u < 0])  # far enough out that one length turns negative
    z = model.z_of(a)
    assert np.count_nonzero(z[1, :E] <= 0) > 0  # the linear combination has non-positive lengths
    state = dict(vars(model))
    X, results = model.synthesize(a, options=replace(MODEL_OPTIONS, max_iterations=5), return_results=True)
    assert np.all(np.isfinite(X))
    # side-effect free: the model is unchanged; what was clamped comes from synthesis_targets and the notes
    assert vars(model).keys() == state.keys() and all(vars(model)[k] is v for k, v in state.items())
    targets, clamped = model.synthesis_targets(a)
    n = np.count_nonzero(z[1, :E] < 0.01 * model.mean_z[:E])
    assert clamped.shape == (2, E) and clamped[0].sum() == 0 and clamped[1].sum() == n > 0
    np.testing.assert_array_equal(targets[1, :E][clamped[1]], 0.01 * model.mean_z[:E][clamped[1]])
    assert not any("floor" in note for note in results[0].notes)
    assert f"{n} target lengths below 0.01 of the mean's were raised to that floor" in results[1].notes


def test_fit_progress_and_selectable_synthesis_method(bar):
    poses, topo, _ = bar
    calls = []
    model = ShapeModel.fit(poses, topo, n_modes=2, progress=lambda d, n, m: calls.append((d, n, m)))
    assert [c[0] for c in calls] == [0, 1, 2, 3, 4] and calls[-1][1] == 4
    with pytest.raises(Cancelled):
        ShapeModel.fit(poses, topo, n_modes=2, progress=lambda d, n, m: d == 2)
    a = model.training_coefficients[9]
    gn = model.synthesize(a)
    hybrid = model.synthesize(a, method="hybrid")
    lsq = model.synthesize(a, method="lsq")
    d = _diag(gn)
    assert rigid_rms(hybrid, gn) < 1e-11 * d  # measured 4e-13: least-squares start + GN smoothing converges
    assert rigid_rms(lsq, gn) < 1e-5 * d  # measured 1.7e-6: the linear relaxation alone


def test_synthesis_warns_about_failed_poses_unless_their_results_are_returned(bar_models):
    model = bar_models["ambient"]
    E = model.topology.n_edges
    u, lbar = model.modes[0, :E], model.mean_z[:E]
    a = np.zeros((2, model.n_modes))
    a[1, 0] = 1.2 * np.min(lbar[u < 0] / -u[u < 0])  # folds: pose 2 fails its checks, pose 1 (the mean) passes
    options = replace(MODEL_OPTIONS, max_iterations=5)
    X, results = model.synthesize(a, options=options, return_results=True)
    assert [r.success for r in results] == [True, False]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the caller holds the results: no warning
        model.synthesize(a, options=options, return_results=True)
        model.synthesize(a[0], options=options)  # every pose passed
    failed = r"^1 of 2 poses failed their checks \(coefficient rows 1\): "
    with pytest.warns(ReconstructionWarning, match=failed) as caught:
        X2 = model.synthesize(a, options=options)
    assert results[1].message in str(caught[0].message) and caught[0].filename == __file__
    np.testing.assert_array_equal(X2, X)  # returned all the same


def test_fit_names_a_misspelt_option(bar):
    """``ShapeModel.fit`` declares the options of ``fit_z``: a misspelt one is named against ``fit`` itself."""
    poses, faces = bar[0], bar[1]
    with pytest.raises(TypeError, match=r"fit\(\) got an unexpected keyword argument 'n_mode'"):
        ShapeModel.fit(poses, faces, n_mode=2)
    assert ShapeModel.fit(poses, faces, n_modes=1, tangent="ambient").n_modes == 1
