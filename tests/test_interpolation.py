"""Interpolation, extrapolation and keyframe in-betweens in lengths and angles (thesis 4.2, eqs. 4.9, 4.10)."""

import numpy as np
import pytest
from conftest import load_mesh
from scipy.interpolate import CubicSpline

import lacore.shapes.interpolation
import lacore.shapes.projection
import lacore.reconstruction.context as reconstruction_context
from lacore.errors import InputError, LengthsAnglesError, MeshError
from lacore.shapes.interpolation import (check_keyframes, interpolate, keyframe_inbetweens, piecewise_linear_z,
                                         shapes_to_z, spline_z)
from lacore.progress import Cancelled
from lacore.geometry.lengths_angles import edge_lengths, face_areas, face_normals, lengths_and_angles
from lacore.reconstruction import get_context, reconstruct
from lacore.geometry.rigid import rigid_rms
from lacore.samples.simple_deform import box_bar, simple_deform_bend
from lacore.geometry.topology import MeshTopology


FINGER_T = np.array([-0.5, 0.0, 0.25, 0.5, 0.75, 1.0, 1.5])


def _topology(faces, n):
    return MeshTopology.from_faces(faces, n_vertices=n)


@pytest.fixture(scope="module")
def finger():
    X0, F = load_mesh("finger/finger0.ply")
    X1, _ = load_mesh("finger/finger1.ply")
    return _topology(F, len(X0)), X0, X1


@pytest.fixture(scope="module")
def finger_runs(finger):
    topo, X0, X1 = finger
    warm = interpolate([X0, X1], topo, FINGER_T)
    cold = interpolate([X0, X1], topo, FINGER_T, warm_start=False)
    return warm, cold


@pytest.fixture(scope="module")
def plates():
    Xf, F = load_mesh("plate/plate121.ply")
    XA, _ = load_mesh("plate/plate121_rolledA.ply")
    XB, _ = load_mesh("plate/plate121_rolledB.ply")
    return _topology(F, len(Xf)), [Xf, XA, XB]


def signed_volume(X, faces):
    return float(np.einsum("ij,ij->i", X[faces[:, 0]], np.cross(X[faces[:, 1]], X[faces[:, 2]])).sum() / 6.0)


# --------------------------------------------------------------------------- targets
def test_piecewise_linear_z_with_uneven_keyframes_and_extrapolation():
    rng = np.random.default_rng(0)
    Z = rng.standard_normal((3, 6))
    k = np.array([0.0, 3.0, 10.0])
    out = piecewise_linear_z(Z, k, [0.0, 3.0, 10.0, 1.5, 6.5, -3.0, 17.0])
    np.testing.assert_array_equal(out[:3], Z)                                 # exact at the keyframes
    np.testing.assert_allclose(out[3], 0.5 * (Z[0] + Z[1]), rtol=1e-14)
    np.testing.assert_allclose(out[4], 0.5 * (Z[1] + Z[2]), rtol=1e-14)
    np.testing.assert_allclose(out[5], 2 * Z[0] - Z[1], rtol=1e-13)          # end segments extended
    np.testing.assert_allclose(out[6], 2 * Z[2] - Z[1], rtol=1e-13)
    # two shapes at 0 and 1: (1 - t) z0 + t z1 for any t
    t = np.array([-0.5, 0.3, 1.5])
    np.testing.assert_allclose(piecewise_linear_z(Z[:2], [0, 1], t), (1 - t)[:, None] * Z[0] + t[:, None] * Z[1],
                               rtol=1e-13)


def test_spline_z_natural_passes_through_keys_and_extends_linearly():
    rng = np.random.default_rng(1)
    Z = rng.standard_normal((4, 5))
    k = np.array([0.0, 3.0, 4.0, 10.0])
    np.testing.assert_array_equal(spline_z(Z, k, k), Z)
    S = CubicSpline(k, Z, axis=0, bc_type="natural")
    np.testing.assert_allclose(S(k[[0, -1]], 2), 0.0, atol=1e-12)            # natural boundary conditions
    t = np.array([1.0, 3.5, 7.0])
    np.testing.assert_allclose(spline_z(Z, k, t), S(t), rtol=1e-13)
    assert np.abs(spline_z(Z, k, t) - piecewise_linear_z(Z, k, t)).max() > 0.1
    # beyond the keyframes: linear with the end slopes (C1)
    for end, outside in ((k[0], -2.0), (k[-1], 13.0)):
        np.testing.assert_allclose(spline_z(Z, k, [outside])[0], S(end) + (outside - end) * S(end, 1), rtol=1e-12)
        h = 1e-5 * np.sign(outside - end)
        slope_out = (spline_z(Z, k, [end + h])[0] - S(end)) / h           # outside
        slope_in = (S(end) - spline_z(Z, k, [end - h])[0]) / h            # inside (the spline)
        np.testing.assert_allclose(slope_out, slope_in, atol=1e-4)
    # two keyframes: the spline is the linear interpolation
    np.testing.assert_allclose(spline_z(Z[:2], [0, 2], [0.5, 3.0]), piecewise_linear_z(Z[:2], [0, 2], [0.5, 3.0]),
                               rtol=1e-14)


def test_input_validation(plates):
    topo, (Xf, XA, _) = plates
    with pytest.raises(ValueError, match="3 keyframes given for 2 shapes"):
        check_keyframes([0, 1, 2], 2)
    with pytest.raises(ValueError, match="strictly increasing: keyframe 2"):
        check_keyframes([0, 3, 3], 3)
    with pytest.raises(ValueError, match="strictly increasing"):
        keyframe_inbetweens([Xf, XA], topo, [5, 1])
    with pytest.raises(ValueError, match="finite"):
        check_keyframes([0, np.nan], 2)
    with pytest.raises(ValueError, match="at least 2 shapes"):
        interpolate([Xf], topo, [0.5])
    with pytest.raises(ValueError, match="factors must be finite"):
        interpolate([Xf, XA], topo, [0.5, np.nan])
    with pytest.raises(ValueError, match="unknown projection method"):
        interpolate([Xf, XA], topo, [0.5], method="magic")
    # a misspelt method is answered with every method these functions take, the preset and path included
    for call in (lambda: interpolate([Xf, XA], topo, [0.5], method="Fast"),
                 lambda: keyframe_inbetweens([Xf, XA], topo, [0, 2], [1], method="pth")):
        with pytest.raises(InputError, match="use one of fast, gn, bfs, mst, spt, lsq, hybrid, path$"):
            call()
    # entries that are no numbers, and workers=None: InputErrors naming the argument
    with pytest.raises(InputError, match="factors must be an array of numbers"):
        interpolate([Xf, XA], topo, ["half"])
    with pytest.raises(InputError, match="keyframes must be an array of numbers"):
        interpolate([Xf, XA], topo, [0.5], keyframes="ab")
    with pytest.raises(InputError, match="keyframes must be an array of numbers"):
        keyframe_inbetweens([Xf, XA], topo, ["a", "b"])
    with pytest.raises(InputError, match="workers must be a positive integer, got None"):
        interpolate([Xf, XA], topo, [0.5], workers=None)
    # a boundary condition the cubic spline does not take, with two keys (linear, no spline) as with three
    for keys, frames in (([Xf, XA], [0, 2]), ([Xf, XA, Xf], [0, 2, 4])):
        with pytest.raises(InputError, match="bc_type='bogus' does not fit the cubic spline"):
            keyframe_inbetweens(keys, topo, frames, [1], smooth=True, bc_type="bogus")
    with pytest.raises(InputError, match="bc_type='periodic' does not fit .*last key repeats the first"):
        keyframe_inbetweens([Xf, XA, Xf * 1.01], topo, [0, 2, 4], [1], smooth=True, bc_type="periodic")
    bad = XA.copy()
    bad[7, 2] = np.nan
    with pytest.raises(MeshError, match="shape 1 has NaN"):
        interpolate([Xf, bad], topo, [0.5])
    with pytest.raises(LengthsAnglesError, match="2E = "):
        shapes_to_z([Xf, np.ones(7)], topo)
    z = lengths_and_angles(XA, topo)
    with pytest.raises(ValueError, match="reference_vertices"):
        interpolate([z, Xf], topo, [0.5])
    # extrapolating too far gives non-positive lengths: the error names the frame before any work is done
    with pytest.raises(LengthsAnglesError, match="t = 3 .*non-positive edge lengths"):
        interpolate([Xf, 0.5 * Xf], topo, [0.5, 3.0])         # lengths (1 - t/2) l


def test_mismatched_vertex_counts_are_rejected():
    Xs, F = load_mesh("octa/octa_src_small.ply")
    Xt, _ = load_mesh("octa/octa_trg_small.ply")
    topo = _topology(F, len(Xs))
    with pytest.raises(MeshError, match="shape 1 has 601 vertices.*dense correspondence"):
        interpolate([Xs, Xt], topo, [0.5])


# --------------------------------------------------------------------------- finger: interpolation, extrapolation
def test_end_points_are_reproduced(finger, finger_runs):
    topo, X0, X1 = finger
    warm, _ = finger_runs
    for t, X_in in ((0.0, X0), (1.0, X1)):
        i = int(np.flatnonzero(warm.times == t)[0])
        z = lengths_and_angles(warm.vertices[i], topo)
        z_in = lengths_and_angles(X_in, topo)
        E = topo.n_edges
        assert np.abs(z[:E] - z_in[:E]).max() < 1e-10
        assert np.abs(z[E:] - z_in[E:]).max() < 1e-8
        assert warm.max_length_error[i] < 1e-10 and warm.max_angle_error[i] < 1e-8
        assert warm.iterations[i] == 0                       # warm-started from the input shape itself
        assert warm.warm_start_times[i] == t
    np.testing.assert_allclose(warm.vertices[1], X0, atol=1e-9)  # t = 0 is the reference itself, in place


def test_average_is_a_valid_mesh_with_the_energy_of_a_direct_reconstruction(finger, finger_runs):
    """t = 0.5 of finger0/finger1: a non-admissible average (thesis 3.4.3) projected as by reconstruct() (the
    default projection, Fast: one Gauss-Newton step from the extrapolation through t = 0 and 0.25)."""
    topo, X0, X1 = finger
    warm, _ = finger_runs
    i = int(np.flatnonzero(warm.times == 0.5)[0])
    z_avg = 0.5 * (lengths_and_angles(X0, topo) + lengths_and_angles(X1, topo))
    np.testing.assert_allclose(warm.z_targets[i], z_avg, rtol=1e-14, atol=1e-15)
    direct = reconstruct(z_avg, topo, X0)
    print(f"\nfinger t=0.5: energy {warm.energy[i]:.10g} ({warm.iterations[i]} it, warm from t="
          f"{warm.warm_start_times[i]}), direct reconstruct {direct.energy:.10g} ({direct.iterations} it)")
    assert warm.energy[i] > 1e-4                               # not admissible
    assert warm.energy[i] == pytest.approx(direct.energy, rel=1e-4)  # measured 3.2e-5 (method "gn": 1e-6)
    assert rigid_rms(warm.vertices[i], direct.vertices) < 1e-4
    X = warm.vertices[i]
    assert np.all(np.isfinite(X))
    assert face_areas(X, topo.faces).min() > 0.5 * face_areas(X0, topo.faces).min()
    assert warm.max_length_error[i] < 1e-3 and warm.max_angle_error[i] < 0.2


def test_extrapolation_is_finite_and_sane(finger, finger_runs):
    topo, X0, X1 = finger
    warm, _ = finger_runs
    E = topo.n_edges
    ref_normals = face_normals(X0, topo.faces)
    vol0 = signed_volume(X0, topo.faces)
    for t in (-0.5, 1.5):
        i = int(np.flatnonzero(warm.times == t)[0])
        X = warm.vertices[i]
        assert np.all(np.isfinite(X))
        theta = lengths_and_angles(X, topo)[E:]
        folds = int(np.count_nonzero(np.abs(theta - warm.z_targets[i, E:]) > np.pi / 2))
        area_ratio = face_areas(X, topo.faces).min() / face_areas(X0, topo.faces).min()
        vol_ratio = signed_volume(X, topo.faces) / vol0
        turned = int(np.count_nonzero(np.einsum("ij,ij->i", face_normals(X, topo.faces), ref_normals) < 0))
        print(f"\nfinger t={t}: {folds} folded edges (dihedral off target by > pi/2), min area ratio "
              f"{area_ratio:.3f}, volume ratio {vol_ratio:.4f}, faces turned > 90 deg from the reference's "
              f"normal {turned} (bending), energy {warm.energy[i]:.4g}, max angle error "
              f"{warm.max_angle_error[i]:.3f}")
        assert folds == 0                                      # no flipped (folded-over) faces
        assert area_ratio > 0.1                                # no collapsed faces
        assert 0.9 < vol_ratio < 1.1                           # closed surface keeps its orientation and volume
        assert warm.max_angle_error[i] < 0.5
        assert warm.status[i] > 0


def test_frames_are_placed_in_the_reference_frame(finger, finger_runs):
    topo, X0, _ = finger
    warm, _ = finger_runs
    a, b, c = topo.faces[warm.context.fixed_face]
    e1 = (X0[b] - X0[a]) / np.linalg.norm(X0[b] - X0[a])
    n = np.cross(X0[b] - X0[a], X0[c] - X0[a])
    n /= np.linalg.norm(n)
    for X in warm.vertices:
        np.testing.assert_allclose(X[a], X0[a], atol=1e-12)                     # fixed vertex in place
        d = X[b] - X[a]
        assert np.linalg.norm(d - (d @ e1) * e1) < 1e-12 and d @ e1 > 0         # on the reference ray a -> b
        assert abs((X[c] - X[a]) @ n) < 1e-12                                   # in the reference plane


def test_warm_start_saves_iterations(finger):
    topo, X0, X1 = finger
    warm = interpolate([X0, X1], topo, FINGER_T, method="gn")
    cold = interpolate([X0, X1], topo, FINGER_T, method="gn", warm_start=False)
    print(f"\nfinger {len(FINGER_T)} frames: warm start {warm.total_iterations} Gauss-Newton iterations "
          f"({warm.iterations.tolist()}), cold start {cold.total_iterations} ({cold.iterations.tolist()})")
    assert warm.total_iterations <= cold.total_iterations
    assert np.all(np.isnan(cold.warm_start_times))
    # processed in order of t, each from its nearest known neighbour (input shapes win ties)
    np.testing.assert_array_equal(warm.order, np.argsort(FINGER_T, kind="stable"))
    np.testing.assert_array_equal(warm.warm_start_times, [0.0, 0.0, 0.0, 0.25, 1.0, 1.0, 1.0])
    # both reach the same frames
    np.testing.assert_allclose(warm.energy, cold.energy, rtol=1e-4, atol=1e-20)


def test_all_frames_share_one_symbolic_factorization(plates, monkeypatch):
    """Counts the symbolic analyses (SparseCholesky constructions) on a fresh topology."""
    _, (Xf, XA, XB) = plates
    topo = _topology(load_mesh("plate/plate121.ply")[1], len(Xf))   # fresh per-topology caches
    made = []

    class Counting(reconstruction_context.SparseCholesky):
        def __init__(self, *args, **kwargs):
            made.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(reconstruction_context, "SparseCholesky", Counting)
    res = interpolate([XA, XB], topo, [0.2, 0.4, 0.6, 0.8])
    again = interpolate([XA, XB], topo, [0.5])
    numeric = sum(r.factorizations for r in res.reconstructions) + again.reconstructions[0].factorizations
    print(f"\nplates: {numeric} numeric factorizations, {len(made)} symbolic analysis")
    assert len(made) == 1
    assert numeric >= 5
    assert again.context is res.context is get_context(topo, XA)
    assert res.context.solver is again.context.solver


# --------------------------------------------------------------------------- bent bar
def test_bent_bar_inbetween_matches_the_analytic_bend():
    """Straight vs 90-degree bent bar (Blender Simple Deform 'BEND', see benchmarks/bench_interpolation.py):
    the lengths-and-angles in-between at t = 0.5 is the 45-degree bend; linear vertex blending is not."""
    X, F = box_bar(16, 4)                      # 290 vertices, closed box 4 x 1 x 1
    topo = _topology(F, len(X))
    X90 = simple_deform_bend(X, np.pi / 2)
    X45 = simple_deform_bend(X, np.pi / 4)
    res = interpolate([X, X90], topo, [0.5])
    Y = res.vertices[0]
    diag = float(np.linalg.norm(X45.max(0) - X45.min(0)))
    blend = 0.5 * (X + X90)
    rms_la, rms_lin = rigid_rms(Y, X45), rigid_rms(blend, X45)
    l45 = edge_lengths(X45, topo)
    dist_la = float(np.abs(edge_lengths(Y, topo) / l45 - 1).max())
    dist_lin = float(np.abs(edge_lengths(blend, topo) / l45 - 1).max())
    print(f"\nbar t=0.5 vs 45-degree bend: RMS lengths&angles {rms_la / diag:.2e} of the diagonal, linear blend "
          f"{rms_lin / diag:.2e}; max relative edge-length distortion {dist_la:.2e} vs {dist_lin:.2e}")
    assert rms_la < 0.01 * diag
    assert rms_lin > 10 * rms_la
    assert dist_la < 0.01 and dist_lin > 10 * dist_la


# --------------------------------------------------------------------------- keyframes
@pytest.fixture(scope="module")
def plate_keys(plates):
    topo, shapes = plates
    lin = keyframe_inbetweens(shapes, topo, [0, 3, 10])
    smooth = keyframe_inbetweens(shapes, topo, [0, 3, 10], smooth=True)
    return lin, smooth


def test_keyframe_frames_reproduce_the_shapes(plates, plate_keys):
    topo, shapes = plates
    E = topo.n_edges
    for res in plate_keys:
        np.testing.assert_array_equal(res.times, np.arange(11.0))
        for frame, X_in in zip((0, 3, 10), shapes, strict=True):
            z = lengths_and_angles(res.vertices[frame], topo)
            z_in = lengths_and_angles(X_in, topo)
            assert np.abs(z[:E] - z_in[:E]).max() < 1e-10
            assert np.abs(z[E:] - z_in[E:]).max() < 1e-8
            np.testing.assert_array_equal(res.z_targets[frame], z_in)
        assert np.all(np.isfinite(res.vertices))
        # warm starts: every frame starts from a neighbour at most 1.5 frames away
        assert np.nanmax(np.abs(res.warm_start_times - res.times)) <= 1.5


def test_spline_differs_from_linear_between_keys(plates, plate_keys):
    topo, shapes = plates
    lin, smooth = plate_keys
    dz = np.abs(smooth.z_targets - lin.z_targets).max(axis=1)
    print(f"\nplates [0, 3, 10]: max |z_spline - z_linear| per frame {np.array2string(dz, precision=3)}")
    assert np.all(dz[[0, 3, 10]] == 0.0)
    assert np.all(dz[[1, 2, 4, 5, 6, 7, 8, 9]] > 1e-3)
    rms = [rigid_rms(smooth.vertices[f], lin.vertices[f]) for f in (1, 5, 8)]
    assert min(rms) > 1e-3
    # the spline's projected frames are as good projections as the linear ones (same solver)
    assert np.all(smooth.status > 0) and np.all(lin.status > 0)


def test_frame_based_methods_share_one_preassembled_tree(plates, monkeypatch):
    topo, (Xf, XA, _) = plates
    calls = []
    original = lacore.shapes.projection.preassembled_tree

    def counting(*args, **kwargs):
        calls.append(kwargs.get("kind"))
        return original(*args, **kwargs)

    monkeypatch.setattr(lacore.shapes.projection, "preassembled_tree", counting)
    res = interpolate([Xf, XA], topo, [0.0, 0.3, 0.7, 1.0], method="mst")
    assert calls == ["mst"]
    assert res.tree is not None and res.tree.kind == "mst"
    assert res.max_length_error[0] < 1e-9 and res.max_length_error[-1] < 1e-9   # admissible ends: exact
    # the default hybrid starts from the least-squares relaxation: no tree is built (nor used)
    hybrid = interpolate([Xf, XA], topo, [0.3, 0.7], method="hybrid")
    assert calls == ["mst"] and hybrid.tree is None
    assert np.all(np.isfinite(hybrid.vertices))
    assert np.all(hybrid.energy <= res.energy[1:3] * (1 + 1e-9))     # smoothing lowers the frame-based energy
    # the tree start builds one tree for all frames
    walk = interpolate([Xf, XA], topo, [0.3, 0.7], method="hybrid", hybrid_start="tree", hybrid_kind="spt")
    assert calls == ["mst", "spt"] and walk.tree.kind == "spt"
    assert all(r.method == "hybrid-spt" for r in walk.reconstructions)


# --------------------------------------------------------------------------- progress and cancellation
def test_progress_reports_every_frame_and_cancels(plates):
    topo, (Xf, XA, XB) = plates
    calls = []
    res = keyframe_inbetweens([XA, XB], topo, [0, 4], progress=lambda *a: calls.append(a))
    assert [c[:2] for c in calls] == [(k, 5) for k in range(6)]          # 0 (start) .. 5 frames, in time order
    assert calls[3][2] == "frame 3 of 5 (t = 2)"
    assert res.keyframes.tolist() == [0.0, 4.0] and not res.smooth and res.timings["total"] == res.total_seconds
    seen = []

    def stop_after_two(done, total, message):
        seen.append(done)
        return done >= 2

    with pytest.raises(Cancelled, match="cancelled after 2 of 3"):
        interpolate([XA, XB], topo, [0.25, 0.5, 0.75], progress=stop_after_two)
    assert seen == [0, 1, 2]


# --------------------------------------------------------------------------- continuation (warm starts)
def test_predicted_start_extrapolates_a_linear_path_exactly():
    """The secant through the nearest known shape and the next one beyond it; nearest alone otherwise."""
    from lacore.shapes.projection import MAX_EXTRAPOLATION, predicted_start

    rng = np.random.default_rng(5)
    A, D = rng.standard_normal((2, 7, 3))
    kt = [0.0, 0.2, 1.0]
    known = [A + t * D for t in kt]
    X, tj = predicted_start(0.4, kt, known)          # through 0.2 and 0.0, r = 1
    assert tj == 0.2 and np.abs(X - (A + 0.4 * D)).max() < 1e-14
    X, tj = predicted_start(-0.1, kt, known)         # through 0.0 and 0.2, r = 0.5
    assert tj == 0.0 and np.abs(X - (A - 0.1 * D)).max() < 1e-14
    assert MAX_EXTRAPOLATION == 1.0
    X, tj = predicted_start(-0.3, kt, known)         # r = 1.5: too far, the nearest shape
    assert tj == 0.0 and X is known[0]
    X, tj = predicted_start(0.7, kt, known)          # nearest 1.0, nothing beyond it
    assert tj == 1.0 and X is known[2]
    third = [0.0, 1 / 11, 2 / 11]                   # equal spacings: r = 1 up to round-off, still a secant
    X, tj = predicted_start(3 / 11, third, [A + t * D for t in third])
    assert tj == 2 / 11 and np.abs(X - (A + 3 / 11 * D)).max() < 1e-14
    X, tj = predicted_start(0.4, kt, known, "nearest")
    assert tj == 0.2 and X is known[1]
    X, _ = predicted_start(0.2, kt, known)           # a known time: that shape itself
    assert X is known[1]
    # the two combined shapes go through `place` (e.g. into one rigid placement)
    X, _ = predicted_start(0.4, kt, [k + 1.0 for k in known], place=lambda Y: Y - 1.0)
    assert np.abs(X - (A + 0.4 * D)).max() < 1e-14
    tri = _topology(np.array([[0, 1, 2]]), 3)
    with pytest.raises(lacore.errors.InputError, match="warm_start must be True, False or one of secant, nearest"):
        interpolate([A[:3], A[:3] + D[:3]], tri, [0.5], warm_start="cubic")


@pytest.mark.numerics
def test_secant_starts_save_iterations_on_the_finger(finger):
    """Ten in-betweens: the extrapolated starts need fewer Gauss-Newton iterations and factorizations than
    starts from the nearest frame, for the same minima."""
    topo, X0, X1 = finger
    ts = np.arange(1, 11) / 11
    secant = interpolate([X0, X1], topo, ts, method="gn")
    nearest = interpolate([X0, X1], topo, ts, method="gn", warm_start="nearest")
    assert secant.success and nearest.success
    np.testing.assert_allclose(secant.energy, nearest.energy, rtol=1e-6)   # measured 3.5e-8
    assert secant.total_iterations <= 0.85 * nearest.total_iterations     # measured 32 vs 46
    assert (sum(r.factorizations for r in secant.reconstructions)
            < sum(r.factorizations for r in nearest.reconstructions))         # measured 15 vs 20


@pytest.mark.numerics
def test_fast_continuation_stays_near_gauss_newton(finger):
    """The default projection, the preset Fast (the extrapolated start and one Gauss-Newton step; up to three,
    ftol 1e-4, for the first frame, which starts from the key itself; more only where a step did not agree with
    its model), on ten finger in-betweens: near converged Gauss-Newton's energies with one factorization per
    frame after the first."""
    topo, X0, X1 = finger
    ts = np.arange(1, 11) / 11
    gn = interpolate([X0, X1], topo, ts, method="gn")
    fast = interpolate([X0, X1], topo, ts)
    assert fast.method == "hybrid" and interpolate([X0, X1], topo, ts[:1], method="fast").energy[0] == fast.energy[0]
    assert fast.success and all(r.method == "hybrid-given" for r in fast.reconstructions)
    excess = fast.energy / gn.energy - 1.0
    assert np.all(excess > -1e-9) and excess.max() < 5e-3                  # measured 1.6e-3 (last frame)
    assert excess[:6].max() < 1e-4                                          # measured 2.9e-5
    # one smoothing step per frame, one factorization each; the first (from the key) up to 3 (measured 2)
    assert 1 <= fast.iterations[0] <= 3 and fast.iterations[1:].tolist() == [1] * 9
    factorizations = [r.factorizations for r in fast.reconstructions]
    assert factorizations[0] <= fast.iterations[0] and factorizations[1:] == [1] * 9
    # without a start to smooth, "given" is the least-squares start
    z = 0.5 * (lengths_and_angles(X0, topo) + lengths_and_angles(X1, topo))
    assert reconstruct(z, topo, X0, method="hybrid", hybrid_start="given").method == "hybrid-lsq"


def test_align_keeps_a_start_whose_fixed_face_is_degenerate(finger):
    """``align(X, keep_degenerate=True)`` (used to combine starts) returns X unmoved when its fixed face has
    zero area; without the flag the MeshError names the face."""
    topo, X0, _ = finger
    ctx = get_context(topo, X0)
    X = X0.copy()
    a, b, c = topo.faces[ctx.fixed_face]
    X[c] = X[a]                                            # the fixed face collapses
    with pytest.raises(MeshError, match=r"the fixed face \(.*\) is degenerate \(zero area\)"):
        ctx.align(X)
    assert np.array_equal(ctx.align(X, keep_degenerate=True), X)
    assert rigid_rms(ctx.align(X0 + 1.0, keep_degenerate=True), X0) < 1e-12
