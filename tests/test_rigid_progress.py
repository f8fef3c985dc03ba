"""lacore.geometry.rigid (Kabsch) and lacore.progress (callbacks, cancellation)."""

import numpy as np
import pytest

from lacore.errors import InputError, LengthsAnglesError, MeshError
from lacore.progress import Cancelled, report
from lacore.geometry.rigid import apply_rigid, rigid_align, rigid_fit, rigid_rms


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_rigid_fit_recovers_motion_and_ignores_nan_rows():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(40, 3))
    R, t = random_rotation(rng), rng.normal(size=3)
    Q = apply_rigid(P, R, t)
    R2, t2 = rigid_fit(P, Q)
    assert np.abs(R2 - R).max() < 1e-12 and np.abs(t2 - t).max() < 1e-12
    assert abs(np.linalg.det(R2) - 1) < 1e-12
    Qn = Q.copy()
    Qn[[3, 7]] = np.nan          # occluded markers drop out
    Qn[5] += 100.0
    R3, _ = rigid_fit(P, Qn, weights=np.where(np.arange(40) == 5, 0.0, 1.0))
    assert np.abs(R3 - R).max() < 1e-12
    assert rigid_rms(P, Q) < 1e-12


def test_rigid_fit_never_reflects():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(20, 3))
    Q = P * np.array([-1.0, 1.0, 1.0])   # a mirror image: best proper rotation is not exact
    R, _ = rigid_fit(P, Q)
    assert abs(np.linalg.det(R) - 1) < 1e-12
    assert rigid_rms(P, Q) > 0.1


def test_rigid_fit_errors():
    with pytest.raises(ValueError, match="equal shape"):
        rigid_fit(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="no point"):
        rigid_fit(np.full((3, 3), np.nan), np.zeros((3, 3)))
    Y = rigid_align(np.eye(3), np.eye(3) + 1.0)
    assert np.abs(Y - (np.eye(3) + 1.0)).max() < 1e-12


def test_progress_report_and_cancel():
    seen = []
    report(lambda d, n, m: seen.append((d, n, m)), 1, 4, "frame 1")
    report(None, 1, 4)
    assert seen == [(1, 4, "frame 1")]
    with pytest.raises(Cancelled, match="after 2 of 4") as info:
        report(lambda d, n, m: d >= 2, 2, 4, "frame 2", partial=[1, 2])
    assert info.value.partial == [1, 2]


def test_input_error_hierarchy():
    assert issubclass(MeshError, InputError) and issubclass(LengthsAnglesError, InputError)
    assert issubclass(InputError, ValueError)
