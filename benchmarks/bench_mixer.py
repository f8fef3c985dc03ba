"""Benchmark of the shape mixer (:mod:`lacore.shapes.mixing`): build time by stage, time per mix, accuracy.

Meshes (keys: K = 3 at 50k, K = 4 on the CC0 body):

* ``bar5k`` / ``bar50k``: the box bar (:func:`lacore.samples.simple_deform.box_bar`, 64 x 16 resp.
  210 x 52 segments), keys rest, bent by 90 degrees (Simple Deform), twisted by 90 degrees;
* ``body13k`` / ``body50k``: the MakeHuman body (``human/base.obj``, group ``body``; 50k: one midpoint
  subdivision), keys rest, bent by 60 degrees, twisted by 60 degrees;
* ``human13k``: the CC0 rigged body (:func:`lacore.samples.human.load_human`), keys rest, left arm
  raised by 70 degrees, right knee bent by 35 degrees, torso twisted (10/15/10 degrees).

Accuracy is measured against converged full Gauss-Newton projections (``reconstruct(..., method="gn",
max_iterations=300)`` from the basis, by continuation along the straight line in steps of 0.25) at the
weights of :func:`reference_weights`, computed once (hours at 50k vertices) and kept in a cache,
``--reference DIR`` (default :func:`bench_common.cache_dir`), as ``<mesh>.npz`` with ``weights (N, K-1)``,
``n_in`` (the first ``n_in`` weights lie in [0, 1]), ``vertices (N, V, 3)``, ``energy (N,)`` and ``digest``
(of the keys, faces and weights: a file made for other keys or weights is computed again).  RMS vertex
distance after the best rigid motion, in % of the bounding-box diagonal of the basis.

The continuation can stop in a worse local minimum than the projection: where a mix's full energy is below the
reference's or its distance misses the goal, full Gauss-Newton from the mix (a polish) is run, and if it ends at a
lower energy it is the reference there and in the cache (``references_checked``; on the CC0 body at
``w = (1.5, 1.5, 1.5)`` the continuation ends at ``W_q`` = 4.48, the polished mix at 0.150, 1.96 % of the
diagonal away).

Energy: the full ``W_q`` at the mix over that at the converged Gauss-Newton mix (``energy_ratio``),
and the goal as a margin, ``energy_goal`` = ``(E_mix - E_gn) / (0.02 E_gn + floor)`` (at most 1: within
the goal), with ``floor`` = :data:`ENERGY_FLOOR` times ``E_gn`` at the centre of ``[0, 1]^(K-1)``.  Near a
key ``E_gn`` falls to 0 (quadratically in the distance to the key), so a ratio there compares two
numbers next to nothing; the floor measures the excess on the scale of the keys' own mixing energy.

Prints one JSON object.  Times: wall (``perf_counter``) and CPU (``process_time``); run with
``OPENBLAS_NUM_THREADS=1`` for one core.  The build's minor page faults and system seconds
(``build_minor_page_faults``, ``build_system_seconds``: the fresh memory it touches, costly on a virtual machine)
come from ``getrusage``, its peak resident memory growth from :func:`bench_common.peak_rss_growth`; each mesh is
measured in a process of its own.
"""

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

from bench_common import cache_dir, machine_info, peak_rss_growth  # noqa: E402

from lacore.geometry.rigid import rigid_align  # noqa: E402
from lacore.samples.simple_deform import box_bar, simple_deform_bend  # noqa: E402
from lacore.shapes.mixing import ShapeMixer, blend_targets  # noqa: E402

#: A mix whose full energy is below the reference's by more than this fraction, or whose RMS distance to it misses the
#: goal (:data:`GOALS`), is polished (full Gauss-Newton from the mix); a lower energy so found replaces the reference
#: (the continuation's local minimum was not the projection).
LOWER_ENERGY = 1e-3

#: Accuracy goals, RMS % of the diagonal: in [0, 1]^(K-1), outside.
GOALS = (0.3, 1.0)

#: Floor of the energy goal, as a fraction of the converged energy at the centre of [0, 1]^(K-1) (see above).
ENERGY_FLOOR = 1e-3

MESHES = ("bar5k", "human13k", "body13k", "bar50k", "body50k")


def mesh_keys(name):
    """``(keys (K, V, 3), faces)`` of a benchmark mesh."""
    from bench_multires import beam_bend, load_body, midpoint_subdivide, twist

    if name.startswith("bar"):
        nl, nw = {"bar50k": (210, 52), "bar5k": (64, 16), "bar2k": (40, 10)}[name]
        B, F = box_bar(nl, nw)
        return np.stack([B, simple_deform_bend(B, np.pi / 2), twist(B, np.pi / 2, axis=0)]), F
    if name.startswith("body"):
        X, F = load_body()
        if name == "body50k":
            X, F = midpoint_subdivide(X, F)
        return np.stack([X, beam_bend(X, np.pi / 3), twist(X, np.pi / 3, axis=1)]), F
    if name == "human13k":
        from lacore.samples.human import load_human, pose_keys

        body = load_human()
        return pose_keys(body)[1], body.faces
    raise KeyError(name)


def reference_weights(m, seed=0):
    """10 weights in [0, 1]^m (the centre, all ones, random) and 10 in [-0.5, 1.5]^m (4 corners first, random)."""
    rng = np.random.default_rng(seed)
    inside = [np.full(m, 0.5), np.ones(m)] + list(rng.uniform(0, 1, (8, m)))
    lo, hi = np.full(m, -0.5), np.full(m, 1.5)
    corners = [lo, hi, np.r_[1.5, lo[1:]], np.r_[-0.5, hi[1:]]]             # all low, all high, first alone
    outside = corners + list(rng.uniform(-0.5, 1.5, (10 - len(corners), m)))
    return np.array(inside + outside), len(inside)


def compute_references(keys, faces, W, masks=None, relative_to=None):
    """Converged full Gauss-Newton projections ``(X (N, V, 3), E (N,))`` of the blends at the weights ``W``, each by
    continuation from the basis in steps of 0.25 (``masks``, ``relative_to``: as for :meth:`ShapeMixer.build`)."""
    from lacore import MeshTopology, lengths_and_angles, reconstruct
    from lacore.shapes.mixing import edge_masks

    topo = MeshTopology.from_faces(faces, n_vertices=keys.shape[1])
    zk = np.stack([lengths_and_angles(k, topo) for k in keys])
    em = None if masks is None else edge_masks(masks, topo.edges)
    X, E = [], []
    for w in W:
        start = None
        for t in np.append(np.arange(0.25, 1.0, 0.25), 1.0):
            res = reconstruct(blend_targets(zk, t * w, topo.n_edges, relative_to=relative_to, edge_masks=em), topo,
                              keys[0], method="gn", initial_vertices=start, max_iterations=300)
            start = res.vertices
        X.append(res.vertices)
        E.append(res.energy)
    return np.array(X), np.array(E)


def reference_digest(keys, faces, W, masks=None, relative_to=None):
    """What a stored reference was computed for: SHA-256 of the keys (to 1e-9), the faces, the weights and the masks
    and relative keys when given."""
    h = hashlib.sha256()
    arrays = [np.round(np.asarray(keys, float), 9), np.asarray(faces, np.int64), np.asarray(W, float)]
    arrays += [np.asarray(a, float) for a in (masks, relative_to) if a is not None]
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def load_references(path, digest):
    """``(vertices, energy)`` stored at ``path`` for ``digest``, else None."""
    if not os.path.exists(path):
        return None
    with np.load(path) as ref:
        if "digest" not in ref or str(ref["digest"]) != digest:
            return None
        return ref["vertices"], ref["energy"]


def save_references(path, digest, W, n_in, X, E):
    """Store references at ``path`` (written whole, then renamed)."""
    tmp = path + ".tmp.npz"
    np.savez(tmp, weights=W, n_in=n_in, vertices=X, energy=E, digest=digest)
    os.replace(tmp, path)


def rms_percent(A, B, diag):
    Y = rigid_align(A, B)
    return 100.0 * float(np.sqrt(np.mean(np.sum((Y - B) ** 2, axis=1)))) / diag


def bench_mesh(name, reference_dir=None, repeats=3, options=None, references=None, case=None):
    """The figures of one mesh: ``case`` ``(keys, faces, blend, weights)`` (default :func:`mesh_keys`' keys, no
    masks, :func:`reference_weights`), ``blend`` the ``masks`` and ``relative_to`` of :meth:`ShapeMixer.build`,
    ``weights`` a function of the weights of :func:`reference_weights` giving the ones measured."""
    if case is None:
        keys, faces = mesh_keys(name)
        blend, weights = {}, None
    else:
        keys, faces, blend, weights = case
    diag = float(np.linalg.norm(np.ptp(keys[0], axis=0)))
    out = {"mesh": name, "vertices": int(keys.shape[1]), "keys": int(len(keys))}
    W, n_in = reference_weights(len(keys) - 1)
    if weights is not None:
        W = weights(W, n_in)
    if references:
        W = np.concatenate([W[:references], W[n_in:n_in + references]])
        n_in = references
    path = os.path.join(reference_dir or cache_dir("bench_mixer_references"),
                        f"{name}{f'_{references}' if references else ''}.npz")
    digest = reference_digest(keys, faces, W, **blend)
    stored = load_references(path, digest)   # the digest covers W, so the stored weights are these
    if stored is None:
        stored = compute_references(keys, faces, W, **blend)
        save_references(path, digest, W, n_in, *stored)
    Xref, Eref = stored
    usage0 = resource.getrusage(resource.RUSAGE_SELF)
    peak_growth = peak_rss_growth()
    c0, t0 = time.process_time(), time.perf_counter()
    mixer = ShapeMixer.build(keys, faces, options, **blend)
    out["build_seconds"] = {k: round(v, 3) for k, v in mixer.build_seconds.items()}
    out["build_cpu_seconds_by_stage"] = {k: round(v, 3) for k, v in mixer.build_cpu_seconds.items()}
    out["build_cpu_seconds"] = round(time.process_time() - c0, 3)
    out["build_wall_seconds"] = round(time.perf_counter() - t0, 3)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    # fresh memory the build touched (page faults) and the kernel's time for it: costly on virtual machines
    out["build_minor_page_faults"] = int(usage.ru_minflt - usage0.ru_minflt)
    out["build_system_seconds"] = round(usage.ru_stime - usage0.ru_stime, 3)
    out["reduced_size"] = mixer.reduced_size
    out["cubature_edges"] = mixer.cubature_size
    out["local_vertices"] = len(mixer.local_vertices)
    out["edges"] = int(mixer.n_edges)
    out["cubature_fit_residual"] = round(float(getattr(mixer, "cubature_residual", 0.0)), 5)
    out["mixer_megabytes"] = round(mixer.nbytes / 2 ** 20, 1)
    out["peak_rss_growth_megabytes"] = round(peak_growth() / 1024, 1)
    errs, ratios, exacts, inds, flags, its, wall, cpu, checked = [], [], [], [], [], [], [], [], []
    Xref, Eref = np.array(Xref, float), np.array(Eref, float)
    for i, w in enumerate(W):
        mixer.mix(np.zeros(len(w)), warm_start=False)
        ws, cs = [], []
        for _ in range(repeats):  # cold mixes (no warm start): the worst case of a slider jump
            c1, t1 = time.process_time(), time.perf_counter()
            r = mixer.mix(w, warm_start=False)
            cs.append(time.process_time() - c1)
            ws.append(time.perf_counter() - t1)
        wall.append(min(ws))
        cpu.append(min(cs))
        exact = mixer.full_energy(w, r.vertices)
        err = rms_percent(r.vertices, Xref[i], diag)
        if exact < (1.0 - LOWER_ENERGY) * Eref[i] or err > GOALS[i >= n_in]:
            # a lower energy than the reference or a missed goal: full Gauss-Newton from the mix (a polish); if it
            # ends lower than the reference, the continuation stopped in a worse local minimum and it is the reference
            p = mixer.mix(w, warm_start=False, polish=True)
            e_p = mixer.full_energy(w, p.vertices)
            checked.append({"w": [round(float(a), 3) for a in w], "energy_reference": round(float(Eref[i]), 6),
                            "energy_polished": round(float(e_p), 6), "replaced": bool(e_p < Eref[i]),
                            "rms_percent_polished_to_reference": round(rms_percent(p.vertices, Xref[i], diag), 4)})
            if e_p < Eref[i]:
                Xref[i], Eref[i] = p.vertices, e_p
                err = rms_percent(r.vertices, Xref[i], diag)
                save_references(path, digest, W, n_in, Xref, Eref)
        errs.append(err)
        exacts.append(exact)
        ratios.append(exact / Eref[i] if Eref[i] > 0 else float("nan"))
        inds.append(r.indicator)
        flags.append(bool(r.in_range))
        its.append(r.iterations)
    # slider drags: 20 small steps from 0 to the centre, warm-started
    m = len(keys) - 1
    mixer.mix(np.zeros(m))
    drag = []
    for t in np.linspace(0.05, 1.0, 20):
        c1 = time.process_time()
        mixer.mix(np.full(m, 0.5) * t)
        drag.append(time.process_time() - c1)
    errs, ratios = np.array(errs), np.array(ratios)
    centre = np.flatnonzero(np.all(np.abs(W - 0.5) < 1e-12, axis=1))
    e_centre = float(Eref[centre[0]]) if centre.size else float(np.median(Eref[:n_in]))
    excess = (np.array(exacts) - Eref) / (0.02 * Eref + ENERGY_FLOOR * e_centre)
    out["mix"] = {
        "ms_median_cold_wall": round(1e3 * float(np.median(wall)), 2),
        "ms_median_cold_cpu": round(1e3 * float(np.median(cpu)), 2),
        "ms_median_drag_cpu": round(1e3 * float(np.median(drag)), 2),
        "iterations_max": int(max(its)),
        "rms_percent_diag_in_01": {"mean": round(float(errs[:n_in].mean()), 4),
                                   "max": round(float(errs[:n_in].max()), 4)},
        "rms_percent_diag_extrapolated": {"mean": round(float(errs[n_in:].mean()), 4),
                                          "max": round(float(errs[n_in:].max()), 4)},
        "energy_ratio_in_01": {"median": round(float(np.nanmedian(ratios[:n_in])), 4),
                               "max": round(float(np.nanmax(ratios[:n_in])), 4)},
        "energy_ratio_extrapolated": {"median": round(float(np.nanmedian(ratios[n_in:])), 4),
                                      "max": round(float(np.nanmax(ratios[n_in:])), 4)},
        "energy_goal_in_01": {"median": round(float(np.median(excess[:n_in])), 3),
                              "max": round(float(excess[:n_in].max()), 3),
                              "within": int(np.sum(excess[:n_in] <= 1.0)), "of": int(n_in)},
        "energy_goal_extrapolated": {"median": round(float(np.median(excess[n_in:])), 3),
                                     "max": round(float(excess[n_in:].max()), 3),
                                     "within": int(np.sum(excess[n_in:] <= 1.0)), "of": int(len(W) - n_in)},
        "references_checked": checked,
        "per_weight": [{"w": [round(float(a), 3) for a in w], "rms_percent": round(float(e), 4),
                        "energy_ratio": round(float(q), 4), "energy_goal": round(float(g), 3),
                        "indicator": round(float(d), 5), "in_range": f}
                       for w, e, q, g, d, f in zip(W, errs, ratios, excess, inds, flags, strict=True)],
    }
    return out


def run(argv, meshes, description, benchmark, case=None, script=None):
    """Parse ``argv`` (mesh names of ``meshes``, ``--reference``, ``--repeats``, ``--references``), measure each
    mesh (:func:`bench_mesh`, ``case(name)`` its case when given) and print the JSON object titled ``benchmark``.

    With ``script`` (the calling benchmark's file) and more than one mesh, each mesh is measured by ``script`` in a
    process of its own: the build's time, page faults and peak memory are then those of a fresh process, as in
    ``lacore mixer`` or Blender's Enable, whatever ran before it.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("meshes", nargs="*", default=list(meshes), help=f"of {', '.join(meshes)}")
    ap.add_argument("--reference", help="folder of the converged full Gauss-Newton mixes <mesh>.npz, computed "
                                        "there when missing (default: a folder under ~/.cache)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--references", type=int, default=None, metavar="N",
                    help="only N weights in [0, 1] and N outside (default 10 + 10)")
    args = ap.parse_args(argv)
    if script is not None and len(args.meshes) > 1:
        rest = [a for a in argv if a not in args.meshes]
        records = [json.loads(subprocess.run([sys.executable, os.path.abspath(script), name, *rest], check=True,
                                             stdout=subprocess.PIPE, text=True).stdout) for name in args.meshes]
        print(json.dumps(dict(records[0], meshes=[m for r in records for m in r["meshes"]]), indent=1))
        return
    results = {"benchmark": benchmark, "machine": machine_info(),
               "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"), "meshes": []}
    for name in args.meshes:
        results["meshes"].append(bench_mesh(name, args.reference, args.repeats, references=args.references,
                                            case=None if case is None else case(name)))
        print(json.dumps(results["meshes"][-1]), file=sys.stderr, flush=True)
    print(json.dumps(results, indent=1))


def main(argv=None):
    run(argv, MESHES, __doc__.split("\n")[0],
        "shape mixer (build by stage, ms per mix, RMS % of the diagonal against converged full Gauss-Newton, energy "
        "ratio and goal margin, memory)")


if __name__ == "__main__":
    main()
