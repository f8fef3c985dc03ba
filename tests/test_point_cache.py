"""PC2 point caches (lacore.io.point_cache): header per the format, 12 bytes per vertex per frame, round trip."""

import os
import stat

import numpy as np
import pytest

from lacore.io.point_cache import HEADER_BYTES, PointCacheError, read_pc2, write_pc2


def test_round_trip_layout_and_header(tmp_path):
    X = np.random.default_rng(0).standard_normal((7, 5, 3))
    path = tmp_path / "take.pc2"
    write_pc2(path, X, start=1.0, sampling=1.0)
    raw = path.read_bytes()
    assert HEADER_BYTES == 32 and len(raw) == 32 + 12 * 5 * 7
    assert raw[:12] == b"POINTCACHE2\0"
    assert np.frombuffer(raw[12:20], "<i4").tolist() == [1, 5]
    assert np.frombuffer(raw[20:28], "<f4").tolist() == [1.0, 1.0]
    assert np.frombuffer(raw[28:32], "<i4").tolist() == [7]
    Y, start, sampling = read_pc2(path)
    assert (start, sampling) == (1.0, 1.0)
    assert np.abs(Y - X).max() < 5e-7  # float32 round-off of values ~1 (measured 1.2e-7)
    # sample t, vertex v at byte 32 + 12 (t V + v)
    assert np.frombuffer(raw[32 + 12 * (3 * 5 + 2):32 + 12 * (3 * 5 + 3)], "<f4").tolist() == \
        X[3, 2].astype(np.float32).tolist()
    # written by the one atomic writer: the permissions of any new file (the umask), no temporary file left
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o666 & ~umask
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take.pc2"]


def test_bad_input(tmp_path):
    with pytest.raises(PointCacheError, match="shape"):
        write_pc2(tmp_path / "a.pc2", np.zeros((4, 3)))
    X = np.zeros((3, 2, 3))
    X[1, 0, 0] = np.nan
    with pytest.raises(PointCacheError, match="frame 1"):
        write_pc2(tmp_path / "a.pc2", X)
    assert list(tmp_path.iterdir()) == []  # nothing left behind
    (tmp_path / "b.pc2").write_bytes(b"not a cache")
    with pytest.raises(PointCacheError, match="POINTCACHE2"):
        read_pc2(tmp_path / "b.pc2")
    write_pc2(tmp_path / "c.pc2", np.ones((2, 2, 3)))
    (tmp_path / "c.pc2").write_bytes((tmp_path / "c.pc2").read_bytes()[:-4])
    with pytest.raises(PointCacheError, match="needs"):
        read_pc2(tmp_path / "c.pc2")
