"""Fill-reducing orderings of the Gauss-Newton systems: METIS (pymetis), else the geometric nested dissection.

The 50k-vertex figures are in ``benchmarks/bench_ordering.py`` (README "In-betweens of large meshes"); here a
1.8k-vertex bent box bar, small enough for a test, where the orderings already differ.
"""

import subprocess
import sys

import numpy as np
import pymetis  # noqa: F401  (lacore[test] installs it: these tests check the METIS path, not a skip)
import pytest
from conftest import REPO

from lacore.linalg import sparse_cholesky
from lacore.errors import InputError
from lacore.geometry.lengths_angles import lengths_and_angles
from lacore.reconstruction import get_context, reconstruct
from lacore.reconstruction.assembly import coupled_vertex_graph, dof_ordering
from lacore.samples.simple_deform import box_bar, simple_deform_bend
from lacore.linalg.sparse_cholesky import SparseCholesky, metis_nested_dissection, nested_dissection, vertex_ordering
from lacore.geometry.topology import MeshTopology


@pytest.fixture(scope="module")
def bar():
    """The bent 40 x 10 box bar (1,802 vertices), its context, coupled-vertex graph and Gauss-Newton matrix."""
    B, F = box_bar(40, 10)
    topo = MeshTopology.from_faces(F, n_vertices=len(B))
    ctx = get_context(topo, B)
    pat = ctx.pattern
    G = coupled_vertex_graph(pat, topo.n_vertices)
    _, _, matrix = ctx.objective(lengths_and_angles(simple_deform_bend(B, np.pi / 2), topo)).linearize(
        ctx.to_canonical(B))
    values = matrix()
    ctx.eliminate_fixed(values)
    return topo, B, pat, G, values


def factor_counts(pat, values, vertex_order):
    chol = SparseCholesky(pat["matrix"], ordering=(3 * vertex_order[:, None] + np.arange(3)).ravel())
    chol.factorize(values)
    return chol.factor_column_counts().astype(float)


def test_metis_is_the_default_ordering_and_deterministic(bar, tmp_path):
    topo, B, pat, G, _ = bar
    order, method = vertex_ordering(G, B)
    assert method == "metis" and sparse_cholesky.ORDERINGS[0] == "metis"
    assert np.array_equal(np.sort(order), np.arange(topo.n_vertices))
    assert np.array_equal(order, metis_nested_dissection(G))
    dofs, used = dof_ordering(topo, pat, B)
    np.testing.assert_array_equal(dofs, (3 * order[:, None] + np.arange(3)).ravel())
    assert used == "metis" and get_context(topo, B).ordering in (None, "metis")
    # a fresh process (a worker of lacore.parallel) orders the same graph the same way
    np.save(tmp_path / "graph.npy", np.stack(G.nonzero()))
    code = ("import numpy as np, scipy.sparse as sp\n"
            "from lacore.linalg.sparse_cholesky import metis_nested_dissection\n"
            f"r, c = np.load({str(tmp_path / 'graph.npy')!r})\n"
            f"G = sp.csr_matrix((np.ones(len(r)), (r, c)), shape=({topo.n_vertices}, {topo.n_vertices}))\n"
            "print(','.join(map(str, metis_nested_dissection(G))))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert np.array_equal(np.array(proc.stdout.strip().split(","), int), order)


def test_metis_fills_less_than_the_geometric_ordering(bar):
    """On the bent bar CHOLMOD's factor has 17 % fewer nonzeros and 32 % fewer flops with METIS (measured; the
    50k bar: 21 % / 38 %) than with the geometric nested dissection, each against AMD as CHOLMOD compares."""
    _, B, pat, G, values = bar
    metis = factor_counts(pat, values, vertex_ordering(G, B)[0])
    geometric = factor_counts(pat, values, nested_dissection(G, B))
    assert metis.sum() < 0.9 * geometric.sum(), (metis.sum(), geometric.sum())
    assert (metis ** 2).sum() < 0.8 * (geometric ** 2).sum()


def test_without_pymetis_the_geometric_ordering(bar, monkeypatch):
    _, B, _, G, _ = bar
    monkeypatch.setattr(sparse_cholesky, "_pymetis", lambda: None)
    assert metis_nested_dissection(G) is None
    order, method = vertex_ordering(G, B)
    assert method == "geometric" and np.array_equal(order, nested_dissection(G, B))
    with pytest.raises(InputError, match="ordering 'metis' needs pymetis"):
        vertex_ordering(G, B, method="metis")
    with pytest.raises(InputError, match="unknown ordering 'amd'; use one of metis, geometric"):
        vertex_ordering(G, B, method="amd")


def test_factor_column_counts_of_both_backends(bar):
    _, _, pat, _, values = bar
    n = pat["n"]
    for backend in sparse_cholesky.available_backends():
        chol = SparseCholesky(pat["matrix"], backend=backend)
        with pytest.raises(RuntimeError, match="factorize"):
            chol.factor_column_counts()
        counts = chol.factorize(values).factor_column_counts()
        assert counts.shape == (n,) and counts.min() >= 1 and counts.sum() > pat["nnz"]  # the diagonal, plus fill


@pytest.mark.numerics
def test_ordering_setting_changes_round_off_only(bar):
    topo, B, _, _, _ = bar
    z = lengths_and_angles(simple_deform_bend(B, np.pi / 3), topo)
    results = {}
    for ordering in ("metis", "geometric"):
        ctx = get_context(topo, B, ordering=ordering)
        results[ordering] = reconstruct(z, topo, B, context=ctx)
        assert ctx.ordering == ordering
    a, b = results["metis"], results["geometric"]
    # another elimination order rounds differently: the same minimum (an extra step at most)
    assert a.success and b.success and abs(a.iterations - b.iterations) <= 1
    assert np.abs(a.vertices - b.vertices).max() < 1e-10  # measured 6e-16 (the bar is 4 long)
    assert get_context(topo, B).solver is not None and get_context(topo, B).ordering == "metis"  # the default
    with pytest.raises(InputError, match="unknown ordering 'amd'"):
        get_context(topo, B, ordering="amd")


def test_a_given_ordering_alone_without_amd(bar):
    """``try_amd=False`` analyses the given ordering alone: an identity ordering keeps its (large) fill where CHOLMOD
    would pick AMD, the solve is the same, and CHOLMOD's options are as before the analysis."""
    import cvxopt.cholmod

    _, _, pat, _, values = bar
    n = pat["n"]
    before = dict(cvxopt.cholmod.options)
    fills = {}
    x = {}
    b = np.random.default_rng(0).standard_normal(n)
    for try_amd in (True, False):
        chol = SparseCholesky(pat["matrix"], backend="cholmod", ordering=np.arange(n), try_amd=try_amd)
        chol.factorize(values)
        x[try_amd] = chol.solve(b)
        fills[try_amd] = chol.factor_column_counts().sum()
    assert dict(cvxopt.cholmod.options) == before
    assert fills[False] > 1.1 * fills[True], fills         # identity vs AMD on the bar: 1.23 times (measured)
    # the Gauss-Newton matrix with its fixed face eliminated is ill-conditioned: measured 2.4e-10 of max |x|
    np.testing.assert_allclose(x[False], x[True], rtol=1e-8, atol=1e-9 * np.abs(x[True]).max())
