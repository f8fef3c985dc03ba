"""Marker fitting on the sample human: quality against the vertex-PCA and mean-only baselines, and speed.

Prints ONE JSON object.  Set-up (issue 8): the coarse body
(:func:`lacore.samples.human.load_human` ``coarse=True``), a model trained on
``--train`` random poses (seed 0), the 41-marker set of
:mod:`lacore.samples.markers` (8 mm normal offset, 0.5 mm noise, ~10 % of the
samples occluded in runs of 2-8 frames), held-out takes
(:meth:`HumanBody.take`: joint curves reaching 1.1 x the training range, a
2 m walk turning by 90 degrees).  The prior weight ``gamma`` of the
lengths-and-angles fit and the Tikhonov weight of the vertex-PCA baseline are
chosen on a separate validation take (seed 99) from small grids; the test
takes use seeds 1, 2, ...  Errors: mean per-vertex distance to the true pose in
millimetres (the body is in decimetres).

Usage::

    python benchmarks/bench_marker_fitting.py [--frames 200] [--takes 2] [--train 30] [--prolong]

``--prolong`` (thesis 2.3: fit coarse, prolong): the lengths-and-angles fit is
prolonged to the full 13,380-vertex body
(:func:`lacore.samples.human.coarse_human_coarsening`) with the 3 nearest
training poses as key shapes (:class:`lacore.markers.prolongation.NearestKeysProlongation`),
and, for comparison, with the rest pose as the only key; reported: the
full-body mean per-vertex error against the true fine poses, the error at the
kept (coarse) and the re-inserted vertices, the coarse error counted per fine
vertex (at the coarse vertex that absorbed it: the full body's vertex
density), the error of prolonging the *true*
coarse poses (the prolongation's own share) and the seconds per frame.
"""

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from bench_common import machine_info

from lacore.markers.baselines import VertexPCA, fit_markers_vertex_pca
from lacore.markers.fitting import fit_markers
from lacore.markers.prolongation import NearestKeysProlongation
from lacore.multiresolution import Coarsening, Prolongation
from lacore.samples.human import HumanBody, coarse_human_coarsening, load_human
from lacore.samples.markers import observe_markers, place_markers
from lacore.models.shape_model import ShapeModel

MM = 100.0  # decimetres -> millimetres


def coarse_body(coarse_file=None):
    """The coarse body, or (development) the body restricted to another stored coarsening record."""
    if coarse_file is None:
        return load_human(coarse=True)
    c = Coarsening.load(coarse_file)
    return HumanBody.restrict(load_human(), c.vertex_indices, c.faces)


def setup(body, n_train=30, n_modes=None, seed=0):
    train, _ = body.random_poses(n_train, seed=seed)
    t = time.perf_counter()
    model = ShapeModel.fit(train, body.faces, reference_vertices=body.vertices, n_modes=n_modes)
    t_model = time.perf_counter() - t
    pca = VertexPCA.fit(train, n_modes=model.n_modes)
    names, binding = place_markers(body)
    return model, pca, binding, names, t_model


def take(body, binding, n_frames, seed, return_root=False):
    X, _, root_R, _ = body.take(n_frames, seed=seed)
    x = observe_markers(X, body.faces, binding, seed=seed)
    return (X, x, root_R) if return_root else (X, x)


def errors(V, X):
    """Mean per-vertex error per frame, mm."""
    return np.linalg.norm(V - X, axis=2).mean(1) * MM


def run_la(model, x, binding, gamma, tau=0.0, n_modes=None, prolongation=None):
    return fit_markers(model, x, binding, prior_weight=gamma, temporal_weight=tau, n_modes=n_modes,
                       prolongation=prolongation)


def prolongations(model, n_train, seed=0):
    """(coarsening, nearest-keys prolongation, rest-key prolongation, full body, seconds to build)."""
    t = time.perf_counter()
    c = coarse_human_coarsening()
    t_coarsen = time.perf_counter() - t
    full = load_human()
    train, _ = full.random_poses(n_train, seed=seed)
    t = time.perf_counter()
    keys = NearestKeysProlongation(Prolongation(c, np.concatenate([full.vertices[None], train])),
                                   model.training_coefficients, n_nearest=3, offset=1)
    rest = Prolongation(c, full.vertices)
    return c, keys, rest, full, t_coarsen, time.perf_counter() - t


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--takes", type=int, default=2)
    p.add_argument("--train", type=int, default=30)
    p.add_argument("--validation-frames", type=int, default=60)
    p.add_argument("--gammas", type=float, nargs="+", default=[0.3, 1.0, 3.0])
    p.add_argument("--lambdas", type=float, nargs="+", default=[1e-3, 1e-2, 1e-1, 1.0])
    p.add_argument("--temporal-weight", type=float, default=0.0)
    p.add_argument("--coarse-file", default=None)
    p.add_argument("--prolong", action="store_true", help="prolong the fits to the full body (see module doc)")
    p.add_argument("--save", default=None, help="write the fitted first test take to this .npz (for pictures)")
    args = p.parse_args(argv)

    t0 = time.perf_counter()
    body = coarse_body(args.coarse_file)
    model, pca, binding, names, t_model = setup(body, args.train)
    out = {"benchmark": "marker_fitting", "machine": machine_info(), "vertices": int(body.n_vertices),
           "faces": int(len(body.faces)), "markers": int(binding.n_markers), "train_poses": args.train,
           "modes": int(model.n_modes), "model_seconds": t_model}

    # ---------------------------------------------------------------- validation: choose the weights
    Xv, xv = take(body, binding, args.validation_frames, seed=99)
    val_la = {}
    for g in args.gammas:
        val_la[g] = float(errors(run_la(model, xv, binding, g, args.temporal_weight).vertices, Xv).mean())
    gamma = min(val_la, key=val_la.get)
    val_pca = {}
    for lam in args.lambdas:
        val_pca[lam] = float(errors(fit_markers_vertex_pca(pca, xv, body.faces, binding, tikhonov=lam)["vertices"],
                                    Xv).mean())
    lam = min(val_pca, key=val_pca.get)
    val_mean = {}
    for g in args.gammas:
        val_mean[g] = float(errors(run_la(model, xv, binding, g, 0.0, n_modes=0).vertices, Xv).mean())
    gamma_mean = min(val_mean, key=val_mean.get)
    out["validation"] = {"frames": args.validation_frames,
                         "la_mm_by_gamma": {str(k): v for k, v in val_la.items()},
                         "pca_mm_by_lambda": {str(k): v for k, v in val_pca.items()},
                         "mean_only_mm_by_gamma": {str(k): v for k, v in val_mean.items()},
                         "gamma": gamma, "lambda": lam, "gamma_mean_only": gamma_mean}

    if args.prolong:
        if args.coarse_file is not None:
            raise SystemExit("--prolong needs the committed coarse body (no --coarse-file)")
        coarsening, keys, rest, full, t_coarsen, t_build = prolongations(model, args.train)
        out["prolongation_setup"] = {"fine_vertices": int(coarsening.n_fine_vertices),
                                     "coarsening_seconds": t_coarsen, "build_seconds": t_build,
                                     "levels": len(keys.prolongation.levels)}
        pro = {"keys_mm": [], "rest_mm": [], "keys_kept_mm": [], "keys_inserted_mm": [], "oracle_keys_mm": [],
               "oracle_rest_mm": [], "coarse_mm": [], "coarse_at_parent_mm": [],
               "rest_seconds": 0.0, "keys_seconds": 0.0}
        inserted = np.setdiff1d(np.arange(coarsening.n_fine_vertices), coarsening.vertex_indices)

    # ---------------------------------------------------------------- test takes
    e_la, e_pca, e_mean, stages, per_frame, iters = [], [], [], [], [], []
    t_pca = t_mean = cpu = 0.0
    occluded = visible_min = None
    for k in range(args.takes):
        X, x, root_R = take(body, binding, args.frames, seed=1 + k, return_root=True)
        hidden = np.isnan(x[:, :, 0])
        occluded = float(hidden.mean()) if occluded is None else occluded
        visible_min = int((~hidden).sum(1).min()) if visible_min is None else min(visible_min,
                                                                                  int((~hidden).sum(1).min()))
        c = time.process_time()
        r = run_la(model, x, binding, gamma, args.temporal_weight, prolongation=keys if args.prolong else None)
        cpu += time.process_time() - c
        if args.prolong:
            Xf = full.take(args.frames, seed=1 + k)[0]
            assert np.allclose(Xf[:, coarsening.vertex_indices], X)
            pro["keys_seconds"] += r.timings["prolongation"]
            pro["keys_mm"].append(errors(r.fine_vertices, Xf))
            pro["coarse_mm"].append(errors(r.vertices, X))
            # the coarse error counted once per fine vertex (at the coarse vertex that absorbed it): the full
            # body's vertex density, not the prolongation
            ec = np.linalg.norm(r.vertices - X, axis=2) * MM
            pro["coarse_at_parent_mm"].append(ec[:, coarsening.parent].mean(1))
            kept = coarsening.vertex_indices
            pro["keys_kept_mm"].append(errors(r.fine_vertices[:, kept], Xf[:, kept]))
            pro["keys_inserted_mm"].append(errors(r.fine_vertices[:, inserted], Xf[:, inserted]))
            tp = time.perf_counter()
            Y = np.array([rest(v) for v in r.vertices])
            pro["rest_seconds"] += time.perf_counter() - tp
            pro["rest_mm"].append(errors(Y, Xf))
            a_true = model.coefficients(X)
            pro["oracle_keys_mm"].append(errors(np.array([keys(v, a) for v, a in zip(X, a_true, strict=True)]), Xf))
            pro["oracle_rest_mm"].append(errors(np.array([rest(v) for v in X]), Xf))
        e_la.append(errors(r.vertices, X))
        stages.append(r.timings)
        per_frame.append(r.frame_seconds)
        iters.append(r.frame_iterations)
        o = fit_markers_vertex_pca(pca, x, body.faces, binding, tikhonov=lam)
        t_pca += o["seconds"]
        e_pca.append(errors(o["vertices"], X))
        t = time.perf_counter()
        m0 = run_la(model, x, binding, gamma_mean, 0.0, n_modes=0)
        t_mean += time.perf_counter() - t
        e_mean.append(errors(m0.vertices, X))
        if k == 0 and args.save:
            np.savez(args.save, true=X, markers=x, root_rotation=root_R, la=r.vertices, pca=o["vertices"],
                     mean_only=m0.vertices, faces=body.faces, err_la=e_la[-1], err_pca=e_pca[-1], err_mean=e_mean[-1])
    e_la, e_pca, e_mean = map(np.concatenate, (e_la, e_pca, e_mean))
    T = len(e_la)
    ratio = e_la / e_pca
    sec = np.concatenate(per_frame)
    it = np.concatenate(iters)
    out["test"] = {
        "takes": args.takes, "frames": T, "occluded_fraction": occluded, "min_visible_markers": visible_min,
        "la_mean_mm": float(e_la.mean()), "pca_mean_mm": float(e_pca.mean()), "mean_only_mean_mm": float(e_mean.mean()),
        "la_max_mm": float(e_la.max()), "pca_max_mm": float(e_pca.max()), "mean_only_max_mm": float(e_mean.max()),
        "ratio_la_to_pca": float(e_la.mean() / e_pca.mean()),
        "frames_la_worse_than_pca": int(np.sum(ratio > 1)), "max_frame_ratio": float(ratio.max()),
    }
    tot = {k: float(sum(s[k] for s in stages)) for k in stages[0]}
    out["speed"] = {
        "seconds_per_frame": tot["total"] / T, "cpu_seconds_per_frame": cpu / T,
        "median_frame_seconds": float(np.median(sec)),
        "max_frame_seconds": float(sec.max()),
        "stage_seconds_per_frame": {k: v / T for k, v in tot.items() if k != "total"},
        "mean_iterations": float(np.mean(it)),
        "pca_seconds_per_frame": t_pca / T, "mean_only_seconds_per_frame": t_mean / T,
    }
    if args.prolong:
        e = {k: np.concatenate(v) for k, v in pro.items() if k.endswith("_mm")}
        out["prolongation"] = {
            "key_shapes": "3 nearest training poses by coefficients (NearestKeysProlongation)",
            "full_body_mean_mm": float(e["keys_mm"].mean()), "full_body_max_frame_mm": float(e["keys_mm"].max()),
            "coarse_mean_mm": float(e["coarse_mm"].mean()),
            "coarse_error_per_fine_vertex_mm": float(e["coarse_at_parent_mm"].mean()),
            "kept_vertices_mean_mm": float(e["keys_kept_mm"].mean()),
            "inserted_vertices_mean_mm": float(e["keys_inserted_mm"].mean()),
            "rest_key_full_body_mean_mm": float(e["rest_mm"].mean()),
            "rest_key_full_body_max_frame_mm": float(e["rest_mm"].max()),
            "true_coarse_prolonged_keys_mm": float(e["oracle_keys_mm"].mean()),
            "true_coarse_prolonged_rest_mm": float(e["oracle_rest_mm"].mean()),
            "seconds_per_frame": pro["keys_seconds"] / T, "rest_key_seconds_per_frame": pro["rest_seconds"] / T,
        }
    else:
        out["speed"]["prolongation"] = "none (fitted on the coarse body; --prolong to prolong to the full body)"
    out["seconds"] = time.perf_counter() - t0
    out["load_average_end"] = list(os.getloadavg())
    json.dump(out, sys.stdout)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
