"""Hybrid reconstruction (section 3.4.3): a direct start smoothed by a few Gauss-Newton iterations
reaches the energy of full Gauss-Newton on the non-admissible averages of the thesis' examples."""

import numpy as np
import pytest
from conftest import shared_mesh

from lacore.lengths_angles import lengths_and_angles
from lacore.mesh_io import load_mesh
from lacore.reconstruction import reconstruct
from lacore.topology import MeshTopology


def average_target(a, b):
    A, F = load_mesh(shared_mesh(a))
    B, _ = load_mesh(shared_mesh(b))
    topo = MeshTopology.from_faces(F, n_vertices=len(A))
    return A, topo, 0.5 * (lengths_and_angles(A, topo) + lengths_and_angles(B, topo))


@pytest.mark.parametrize("a, b", [("finger/finger0.ply", "finger/finger1.ply"),
                                  ("plate/plate121_rolledA.ply", "plate/plate121_rolledB.ply"),
                                  ("plate/plate4SD_rolledA.ply", "plate/plate4SD_rolledB.ply")])
def test_hybrid_within_one_percent_of_gauss_newton(a, b):
    A, topo, z = average_target(a, b)
    full = reconstruct(z, topo, A, method="gn", max_iterations=500)
    hybrid = reconstruct(z, topo, A, method="hybrid")
    assert full.success and np.all(np.isfinite(hybrid.vertices))
    assert hybrid.iterations <= 10 < full.iterations or "finger" in a  # plates: far fewer iterations
    assert hybrid.energy <= 1.01 * full.energy
    assert hybrid.method.startswith("hybrid")


def test_tree_start_needs_more_smoothing_on_the_plate():
    A, topo, z = average_target("plate/plate121_rolledA.ply", "plate/plate121_rolledB.ply")
    lsq = reconstruct(z, topo, A, method="hybrid", smoothing_iterations=3)
    tree = reconstruct(z, topo, A, method="hybrid", hybrid_start="tree", smoothing_iterations=3)
    assert lsq.energy < 0.1 * tree.energy  # the tree walk accumulates the integrability error
