"""Regression test: the core maps reproduce frozen reference outputs.

The ``tests/data/core_regression_*.npz`` files were written by the *reference*
implementation of :mod:`lacore.geometry.lengths_angles`, :mod:`lacore.integrability.local` and
:mod:`lacore.geometry.trigonometry` (commit 344d756, before their performance rewrite),
by running this file as a script::

    PYTHONPATH=. .venv/bin/python tests/test_core_regression.py --regenerate

Do NOT regenerate them to make a failing test pass: they freeze the numbers
the optimized code must keep (to 1e-12 relative to each quantity's scale).

Every file is self-contained (vertices and faces are stored with the outputs),
so the test does not need the shared meshes.  Per mesh it freezes

* from the vertex positions ``X``: ``z``, ``dZ/dX`` (also with ``return_z``),
  edge lengths, dihedral angles, face normals and areas;
* for three lengths-and-angles vectors -- the admissible ``z = Z[X]``
  (``adm``), a randomly perturbed, non-admissible one (``pert``) and one with
  triangles that violate the triangle inequality (``tri``): interior angles,
  their Jacobian, triangle areas and area gradients, the triangle-inequality
  map, transition rotations, the holonomies ``I_v``, the Euler integrability
  map and its Jacobian (also with ``return_value``), and the integrability
  violation.
"""

import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import lacore.integrability as integ
from lacore.geometry import lengths_angles as la
from lacore.geometry import trigonometry as trig
from lacore.geometry.topology import MeshTopology

#: Frozen numbers written on another machine: run again on other kernels (scripts/other_kernels.py).
pytestmark = pytest.mark.numerics

DATA = Path(__file__).resolve().parent / "data"

#: name of the regression file -> (shared mesh it was generated from, z variants frozen)
#: (the larger meshes keep one variant each so that every file stays well below 1 MB)
MESHES = {
    "plate121_rolledA": ("plate/plate121_rolledA.ply", ("adm", "pert", "tri")),
    "unitSphere1": ("sphere/unitSphere1.ply", ("adm", "pert", "tri")),
    "defSphere0": ("sphere/defSphere0.ply", ("pert",)),
    "monkey_saddle_1": ("hyperbolic/monkey_saddle_1.ply", ("tri",)),
}

RTOL = 1e-12


# --------------------------------------------------------------------------- computing the outputs
def _perturbed_z(z, topology, seed):
    """Deterministic non-admissible variants of ``z``: ``{"adm", "pert", "tri"}``."""
    E = topology.n_edges
    rng = np.random.default_rng(seed)
    pert = z.copy()
    pert[:E] *= 1.0 + 0.02 * rng.uniform(-1, 1, E)
    pert[E:] += 0.05 * rng.uniform(-1, 1, E)
    tri = pert.copy()
    # lengthen a few edges beyond the sum of the other two edges of their first face
    for e in rng.choice(E, size=3, replace=False):
        f = topology.edge_faces[e, 0]
        others = [x for x in topology.face_edges[f] if x != e]
        tri[e] = 1.05 * (tri[others[0]] + tri[others[1]])
    return {"adm": z, "pert": pert, "tri": tri}


def _sparse_parts(prefix, J):
    J = sp.csr_matrix(J)
    return {f"{prefix}__data": J.data, f"{prefix}__indices": J.indices, f"{prefix}__indptr": J.indptr,
            f"{prefix}__shape": np.array(J.shape)}


def compute_outputs(X, faces, z_variants):
    """All frozen quantities for one mesh, as a flat ``{name: array}`` dict.

    Sparse matrices are stored as ``name__data``, ``name__indices``,
    ``name__indptr``, ``name__shape``.  ``z_variants`` is a tuple of keys of
    :func:`_perturbed_z` (variants of ``Z[X]``) or a ``{key: z}`` dict.
    """
    topo = MeshTopology.from_faces(faces, n_vertices=len(X))
    out = {}
    z = la.lengths_and_angles(X, topo)
    out["z"] = z
    out.update(_sparse_parts("dZdX", la.lengths_and_angles_jacobian(X, topo)))
    out["edge_lengths"] = la.edge_lengths(X, topo)
    out["dihedral_angles"] = la.dihedral_angles(X, topo)
    out["face_normals"] = la.face_normals(X, topo.faces)
    out["face_normals_raw"] = la.face_normals(X, topo.faces, unit=False)
    out["face_areas"] = la.face_areas(X, topo.faces)
    if not isinstance(z_variants, dict):
        all_variants = _perturbed_z(z, topo, seed=len(X))
        z_variants = {key: all_variants[key] for key in z_variants}
    for key, zz in z_variants.items():
        p = f"{key}_"
        out[p + "zin"] = zz
        L = trig.face_edge_lengths(zz[:topo.n_edges], topo)
        out[p + "face_lengths"] = L
        out[p + "margin"] = trig.triangle_inequality_margin(L)
        out[p + "areas"] = trig.triangle_areas(L)
        out[p + "area_grad"] = trig.triangle_area_gradient(L)
        out[p + "gamma"] = trig.interior_angles(L)
        out[p + "dgamma"] = trig.interior_angle_jacobian(L)
        out[p + "tri_map"] = integ.triangle_inequality_map(zz, topo)
        out[p + "transitions"] = integ.transition_rotations(zz, topo)
        out[p + "holonomy"] = integ.integrability_map(zz, topo)
        out[p + "euler"] = integ.euler_integrability_map(zz, topo)
        out.update(_sparse_parts(p + "dEuler", integ.euler_integrability_jacobian(zz, topo)))
        out[p + "violation"] = integ.integrability_violation(zz, topo)
        out[p + "violation_nan"] = integ.integrability_violation(zz, topo, invalid=np.nan)
    return out


def _load_sparse(store, prefix):
    return sp.csr_matrix((store[prefix + "__data"], store[prefix + "__indices"], store[prefix + "__indptr"]),
                         shape=tuple(store[prefix + "__shape"]))


def _regenerate():  # pragma: no cover - run by hand with the reference implementation only
    import trimesh

    from conftest import shared_mesh

    DATA.mkdir(exist_ok=True)
    for name, (rel, variants) in MESHES.items():
        m = trimesh.load(shared_mesh(rel), process=False)
        X = np.asarray(m.vertices, np.float64)
        faces = np.asarray(m.faces, np.int64)
        out = compute_outputs(X, faces, variants)
        path = DATA / f"core_regression_{name}.npz"
        np.savez_compressed(path, vertices=X, faces=faces, **out)
        print(f"{path}: {path.stat().st_size / 1e6:.2f} MB, {len(out)} arrays")


# --------------------------------------------------------------------------- the test
def _scale(name, ref):
    """Magnitude that the 1e-12 tolerance is relative to.

    The array's largest entry, at least 1 for dimensionless quantities (angles,
    rotation entries, the Euler map, violations), whose reference values can be
    pure round-off (``~1e-15`` for admissible ``z``).
    """
    m = float(np.max(np.abs(ref[np.isfinite(ref)]))) if ref.size and np.isfinite(ref).any() else 0.0
    dimensionless = any(k in name for k in ("gamma", "transitions", "holonomy", "euler", "violation",
                                            "dihedral", "normals"))
    return max(m, 1.0) if dimensionless or m == 0.0 else m


def _assert_close(name, actual, ref):
    actual = np.asarray(actual)
    assert actual.shape == ref.shape, f"{name}: shape {actual.shape} != {ref.shape}"
    # non-finite entries (the `invalid` marker of integrability_violation) must match exactly
    fin = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(actual), fin, err_msg=f"{name}: non-finite pattern")
    np.testing.assert_array_equal(np.isnan(actual), np.isnan(ref), err_msg=f"{name}: NaN pattern")
    np.testing.assert_array_equal(actual[~fin & ~np.isnan(ref)], ref[~fin & ~np.isnan(ref)],
                                  err_msg=f"{name}: infinities")
    tol = RTOL * _scale(name, ref)
    err = float(np.max(np.abs(actual[fin] - ref[fin]), initial=0.0))
    assert err <= tol, f"{name}: max abs error {err:.3e} > {tol:.3e}"


@pytest.fixture(scope="module", params=sorted(MESHES))
def frozen(request):
    path = DATA / f"core_regression_{request.param}.npz"
    if not path.is_file():
        pytest.fail(f"missing regression data {path}", pytrace=False)
    with np.load(path) as store:
        ref = {k: store[k] for k in store.files}
    variants = MESHES[request.param][1]
    actual = compute_outputs(ref["vertices"], ref["faces"], {key: ref[f"{key}_zin"] for key in variants})
    return ref, actual, variants


def test_all_quantities_present(frozen):
    ref, actual, _ = frozen
    assert set(actual) == set(ref) - {"vertices", "faces"}


def test_dense_outputs_match(frozen):
    ref, actual, variants = frozen
    names = [k for k in actual if "__" not in k]
    assert len(names) == 6 + 13 * len(variants)
    for name in names:
        _assert_close(name, actual[name], ref[name])


def _assert_sparse_close(prefix, A, B):
    assert A.shape == B.shape, prefix
    # compare as matrices: explicit zeros and the storage order may differ
    D = (A - B).tocoo()
    err = float(np.max(np.abs(D.data), initial=0.0))
    tol = RTOL * max(float(np.max(np.abs(B.data), initial=0.0)), 1.0 if "Euler" in prefix else 0.0)
    assert err <= tol, f"{prefix}: max abs error {err:.3e} > {tol:.3e}"
    # structural nonzeros: every entry of the reference that is clearly nonzero is stored
    Bc = B.tocoo()
    big = np.abs(Bc.data) > 1e-8 * np.max(np.abs(Bc.data))
    vals = np.asarray(A.tocsr()[Bc.row[big], Bc.col[big]]).ravel()
    assert np.all(vals != 0.0), f"{prefix}: missing structural nonzeros"


def test_sparse_jacobians_match(frozen):
    ref, actual, variants = frozen
    prefixes = sorted({k.split("__")[0] for k in actual if "__" in k})
    assert len(prefixes) == 1 + len(variants)
    for prefix in prefixes:
        _assert_sparse_close(prefix, _load_sparse(actual, prefix), _load_sparse(ref, prefix))


def test_combined_evaluations_match(frozen):
    """``return_z`` / ``return_value`` give the same Jacobians and values as the separate calls."""
    ref, _, variants = frozen
    X = ref["vertices"]
    topo = MeshTopology.from_faces(ref["faces"], n_vertices=len(X))
    J, z = la.lengths_and_angles_jacobian(X, topo, return_z=True)
    _assert_sparse_close("dZdX", J, _load_sparse(ref, "dZdX"))
    _assert_close("z", z, ref["z"])
    for key in variants:
        J, e = integ.euler_integrability_jacobian(ref[f"{key}_zin"], topo, return_value=True)
        _assert_sparse_close(f"{key}_dEuler", J, _load_sparse(ref, f"{key}_dEuler"))
        _assert_close(f"{key}_euler", e, ref[f"{key}_euler"])


def test_frozen_data_is_meaningful(frozen):
    """Sanity of the frozen data itself: admissible, non-admissible and invalid cases are what they claim."""
    ref, _, variants = frozen
    if "adm" in variants:
        assert np.max(np.abs(ref["adm_euler"])) < 1e-12
    if "pert" in variants:
        assert np.max(np.abs(ref["pert_euler"])) > 1e-3
    if "tri" in variants:
        assert np.isinf(ref["tri_violation"]).sum() > 0
        assert np.isnan(ref["tri_violation_nan"]).sum() > 0
        assert np.any(ref["tri_margin"] < 0)




# --------------------------------------------------------------------------- properties of the optimized code
def _frozen_case(name="defSphere0"):
    with np.load(DATA / f"core_regression_{name}.npz") as store:
        ref = {k: store[k] for k in store.files}
    X = ref["vertices"]
    return ref, X, MeshTopology.from_faces(ref["faces"], n_vertices=len(X))


def test_gamma_argument_matches_frozen_holonomy():
    """``integrability_map`` and ``transition_rotations`` with given interior angles (the quaternion path
    then takes half angles of ``gamma`` instead of Kahan's factors)."""
    ref, _, topo = _frozen_case()
    _assert_close("pert_holonomy", integ.integrability_map(ref["pert_zin"], topo, gamma=ref["pert_gamma"]),
                  ref["pert_holonomy"])
    _assert_close("pert_transitions", integ.transition_rotations(ref["pert_zin"], topo, gamma=ref["pert_gamma"]),
                  ref["pert_transitions"])


def test_angles_are_periodic():
    """Dihedral angles shifted by multiples of 2 pi give the same Euler map and Jacobian (range reduction)."""
    ref, _, topo = _frozen_case()
    z = ref["pert_zin"]
    E = topo.n_edges
    shifted = z.copy()
    shifted[E:] += 2 * np.pi * np.random.default_rng(5).integers(-3, 4, E)
    _assert_close("euler", integ.euler_integrability_map(shifted, topo), ref["pert_euler"])
    _assert_close("violation", integ.integrability_violation(shifted, topo), ref["pert_violation"])
    J = integ.euler_integrability_jacobian(shifted, topo)
    B = _load_sparse(ref, "pert_dEuler")
    assert abs(J - B).max() <= 1e-11 * abs(B).max()


def test_mesh_without_interior_vertices():
    topo = MeshTopology.from_faces([[0, 1, 2]])
    X = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 4.0, 0.0]])
    z = la.lengths_and_angles(X, topo)
    np.testing.assert_allclose(np.sort(z[:3]), [3.0, 4.0, 5.0], rtol=1e-15)
    assert np.all(z[3:] == 0.0)
    assert integ.euler_integrability_map(z, topo).shape == (0,)
    J, value = integ.euler_integrability_jacobian(z, topo, return_value=True)
    assert J.shape == (0, 6) and J.nnz == 0 and value.shape == (0,)
    np.testing.assert_array_equal(integ.integrability_violation(z, topo), np.zeros(3))
    assert integ.integrability_map(z, topo).shape == (0, 3, 3)
    Jz = la.lengths_and_angles_jacobian(X, topo)
    assert Jz.shape == (6, 9) and Jz.nnz == 18


def test_concurrent_calls_on_one_topology():
    """Per-thread scratch buffers: threads sharing a topology get the single-threaded results."""
    import threading

    ref, X, topo = _frozen_case()
    zs = [ref["pert_zin"] * (1.0 + 1e-3 * i) for i in range(4)]
    expected = [(integ.euler_integrability_map(z, topo), la.lengths_and_angles_jacobian(X * (1.0 + i), topo).data)
                for i, z in enumerate(zs)]
    failures = []

    def work(i):
        for _ in range(10):
            _, value = integ.euler_integrability_jacobian(zs[i], topo, return_value=True)
            data = la.lengths_and_angles_jacobian(X * (1.0 + i), topo).data
            if not (np.array_equal(value, expected[i][0]) and np.array_equal(data, expected[i][1])):
                failures.append(i)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert failures == []


def test_returned_matrices_share_read_only_patterns():
    """The CSR index arrays are shared with the cached pattern and protected against in-place changes."""
    ref, X, topo = _frozen_case()
    for J in (la.lengths_and_angles_jacobian(X, topo), integ.euler_integrability_jacobian(ref["pert_zin"], topo)):
        assert not J.indices.flags.writeable and not J.indptr.flags.writeable
        assert J.has_canonical_format
        rows = np.repeat(np.arange(J.shape[0]), np.diff(J.indptr))
        assert np.all((np.diff(J.indices) > 0) | (np.diff(rows) > 0))     # sorted, unique columns per row
        with pytest.raises(ValueError):
            J.indices[0] = 0


if __name__ == "__main__":  # pragma: no cover
    if "--regenerate" in sys.argv:
        _regenerate()
    else:
        print(__doc__)
