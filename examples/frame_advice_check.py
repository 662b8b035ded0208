"""Check the frame advice's predictions against re-estimates (docs/advice.md#frames).

For simulated street frames, `creference advise`'s best set of dimension lines is predicted from the
Laplace approximation at the MAP; here the set is simulated (around the MAP, with the object's σ:
the model's own noise), added to the frame, and the frame re-estimated (MAP + Laplace), in
antithetic pairs (MAP ± the same noise). Printed per frame: the predicted and the realised ratio
of each distance's sd (after / before), for the object annotated and averaged over the frame's
objects, with the realised ratio's standard error over the pairs.

    python examples/frame_advice_check.py --seeds 1 2 3 --annotations 1 2 5 --pairs 4
    python examples/frame_advice_check.py --sigma reestimated     # σ re-estimated with the new set
"""

from __future__ import annotations

import argparse
import copy

import numpy as np

from creference_bayes.bench.frame_simulate import simulate_frame
from creference_bayes.frame_pipeline import build_frame_model
from creference_bayes.inference.frame_laplace import block_variances, frame_laplace, work_gradients
from creference_bayes.inference.frame_map import optimize_frame
from creference_bayes.io.frame_scene import parse_frame
from creference_bayes.workflows.advice.frame import advise_frame


def distance_sd(model, camera, objects) -> np.ndarray:
    """(m,) the Laplace approximation's sd of every object's distance, metres."""
    lap = frame_laplace(model, camera, objects)
    g_c, g_o = (g[:, 0] for g in work_gradients(model, lap.wc, lap.wo,
                                                lambda c, o: np.hypot(o[..., 0], o[..., 1])[..., None]))
    return np.sqrt(block_variances(lap.Sc, lap.Ao, lap.B, g_c, g_o))


def check(seed: int, n_objects: int, n_annotations: int, pairs: int, reestimate_sigma: bool) -> dict:
    scene = simulate_frame(seed, n_objects=n_objects, n_annotations=n_annotations)
    frame = parse_frame(scene)
    model, _ = build_frame_model(frame)
    est = optimize_frame(model)
    advice = advise_frame(model, frame, est.camera, est.objects)
    pred = next(p for p in advice.predictions if p.candidate.kind == "dims")
    i = pred.candidate.index
    sd_now = distance_sd(model, est.camera, est.objects)
    centre = model.simulate_annotations(est.camera, est.objects, 1, 0.0)[i, 0]
    ratios = []
    for rep in range(pairs):
        noise = np.random.default_rng(rep).normal(0.0, model.sigma[i], (4, 2))
        pair = []
        for new in (centre + noise, centre - noise):
            more = copy.deepcopy(scene)
            more["targets"][i]["dimension_lines"].append({"corners": new.tolist()})
            m2, _ = build_frame_model(parse_frame(more))
            if not reestimate_sigma:
                m2.sigma = model.sigma.copy()
            e2 = optimize_frame(m2)
            pair.append(distance_sd(m2, e2.camera, e2.objects) / sd_now)
        ratios.append(np.mean(pair, axis=0))
    r = np.array(ratios)
    se = r.std(axis=0, ddof=1) / np.sqrt(len(r)) if len(r) > 1 else np.full(r.shape[1], np.nan)
    predicted = pred.distance_sd_m / sd_now
    return {"seed": seed, "K": n_annotations, "key": pred.candidate.key, "best": advice.best.candidate.key,
            "pred_i": predicted[i], "real_i": r.mean(axis=0)[i], "se_i": se[i],
            "pred_mean": predicted.mean(), "real_mean": r.mean(axis=0).mean(), "se_mean": r.mean(axis=1).std(ddof=1) / np.sqrt(len(r)) if len(r) > 1 else np.nan}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="frames (simulator seeds)")
    p.add_argument("--objects", type=int, default=4, help="objects per frame (default: %(default)s)")
    p.add_argument("--annotations", type=int, nargs="+", default=[1, 2, 5],
                   help="sets of dimension lines per object before the new one (default: %(default)s)")
    p.add_argument("--pairs", type=int, default=4, help="antithetic pairs of new sets (default: %(default)s)")
    p.add_argument("--sigma", choices=("fixed", "reestimated"), default="fixed",
                   help="hold each object's σ at its value (what the advice predicts) or re-estimate it")
    args = p.parse_args(argv)
    print(f"{'seed':>4} {'K':>2}  {'set on':<8}{'advised':<13}{'object: predicted':>18}{'realised':>16}"
          f"{'frame mean: predicted':>23}{'realised':>16}")
    for k in args.annotations:
        for seed in args.seeds:
            c = check(seed, args.objects, k, args.pairs, args.sigma == "reestimated")
            print(f"{c['seed']:>4} {c['K']:>2}  {c['key']:<8}{c['best']:<13}{c['pred_i']:>18.3f}"
                  f"{c['real_i']:>9.3f} ±{c['se_i']:.3f}{c['pred_mean']:>23.3f}{c['real_mean']:>9.3f} ±{c['se_mean']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
