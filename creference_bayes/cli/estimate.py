"""``creference estimate SCENE.json`` and ``creference demo``: one scene's target, a table, a result file."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from ..inference.optimize import PRESETS
from ..pipeline import DEFAULT_MODEL, MODELS
from .main import UsageError, example_scene_path

__all__ = ["register", "format_table"]


def format_table(result, truth=None) -> str:
    """A plain-text table of a :class:`~creference_bayes.result.Result`."""
    from ..models.params import PARAM_NAMES, PARAM_UNITS

    d = result.to_dict()
    post = d.get("posterior")
    cols = ["parameter", "unit", "MAP"]
    if post:
        cols += ["mean", "sd", f"HDI {post['hdi']['prob']:.0%}"]
    if truth is not None:
        cols.append("truth")
    names = list(PARAM_NAMES) + (["distance_m"] if post else [])
    units = list(PARAM_UNITS) + (["m"] if post else [])
    rows = []
    for name, unit in zip(names, units):
        row = [name, unit, _fmt(d["map"].get(name, np.hypot(d["map"]["x"], d["map"]["z"])))]
        if post:
            lo, hi = post["hdi"][name]
            row += [_fmt(post["mean"][name]), _fmt(post["sd"][name]), f"[{_fmt(lo)}, {_fmt(hi)}]"]
        if truth is not None:
            row.append(_fmt(truth.get(name)) if truth.get(name) is not None else "")
        rows.append(row)
    widths = [max(len(str(r[i])) for r in rows + [cols]) for i in range(len(cols))]
    line = "  ".join(c.ljust(w) for c, w in zip(cols, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(out)


def _fmt(x) -> str:
    if x is None:
        return ""
    x = float(x)
    return f"{x:.4g}" if abs(x) < 1e4 else f"{x:.0f}"


def _truth_dict(scene):
    gt = scene.ground_truth
    if gt is None:
        return None
    t = {"x": gt.location_m[0], "y": gt.location_m[1], "z": gt.location_m[2],
         "yaw": gt.yaw_rad, "focal_length_px": gt.focal_length_px,
         "distance_m": float(np.hypot(gt.location_m[0], gt.location_m[2]))}
    return t


def _run_estimate(args) -> int:
    from ..io.scene import load_scene
    from ..pipeline import estimate

    scene = load_scene(args.scene)
    for w in scene.warnings:
        print(f"warning: {w}", file=sys.stderr)
    _check_posterior_options(args)
    result = estimate(scene, preset=args.preset, seed=args.seed, model=args.model,
                      use_references=not args.no_references, posterior=not args.no_posterior,
                      temperature=args.temperature, hdi_prob=args.hdi_prob,
                      sampling=None if args.min_ess is None else {"min_ess": args.min_ess},
                      progress=not args.quiet and sys.stderr.isatty())
    if args.netcdf and result.inference_data is None:
        print(f"warning: no posterior, so {args.netcdf} was not written", file=sys.stderr)
    elif args.netcdf:
        result.inference_data.to_netcdf(args.netcdf)
        result = dataclasses.replace(result, extra={**result.extra, "netcdf": str(args.netcdf)})
    _report(result, scene, args)
    return 0


def _check_posterior_options(args) -> None:
    """The posterior options' values, checked before any work is done."""
    if args.no_posterior and args.netcdf:
        raise UsageError("--netcdf: there is no posterior to write with --no-posterior")
    if not 0.0 < args.hdi_prob < 1.0:
        raise UsageError(f"--hdi-prob: expected a probability in (0, 1), got {args.hdi_prob!r}")
    if args.temperature is not None and not (np.isfinite(args.temperature) and args.temperature > 0):
        raise UsageError(f"--temperature: expected a number > 0, got {args.temperature!r}")
    if args.min_ess is not None and not args.min_ess >= 1:
        raise UsageError(f"--min-ess: expected a number ≥ 1, got {args.min_ess!r}")


def _posterior_line(result) -> str:
    g = result.diagnostics
    ess = [v for v in g.ess_bulk.values() if v is not None]
    rhat = [v for v in g.r_hat.values() if v is not None]
    state = "converged" if g.converged else "NOT converged"
    return (f"posterior: {g.n_walkers} walkers in {g.n_ensembles} ensembles, {g.n_steps} steps "
            f"(+{g.warmup_steps} warm-up), {state}; R-hat ≤ {max(rhat, default=float('nan')):.3f}, "
            f"bulk ESS ≥ {min(ess, default=float('nan')):.0f}; {g.seconds:.2f} s; "
            f"T = {result.posterior.temperature:g}")


def _report(result, scene, args) -> None:
    if not args.quiet:
        print(f"target {result.target!r}  model {result.model}  preset {result.preset}  "
              f"handedness {result.map.handedness:+d}  MAP in {result.map.seconds:.2f} s")
        print(format_table(result, _truth_dict(scene)))
        if result.diagnostics is not None:
            print(_posterior_line(result))
        refs = result.references
        if refs is not None and hasattr(refs, "pairs_used"):
            if not refs.enabled:
                print(f"references: {refs.n_references} ignored (--no-references)")
            else:
                why = ", ".join(f"{k} {n}" for k, n in refs.skipped_reasons.items())
                pairs = (f"pairs solvable {refs.pairs_used}, skipped {refs.pairs_skipped}"
                         + (f" ({why})" if why else ""))
                if refs.used_as == "likelihood":
                    print(f"references: {refs.n_references}, {refs.in_likelihood} in the likelihood "
                          f"(for comparison, the paper's pairwise aggregation: {pairs})")
                else:
                    print(f"references: {refs.n_references} as pairwise bounds, {pairs.replace('solvable', 'used')}")
        if result.evaluation is not None:
            print(f"location error (Eq. 3): {result.evaluation.location_pct_error:.2f} %")
            ev = result.evaluation
            if ev.posterior_location_pct_error is not None:
                inside = [k for k, v in (ev.in_hdi or {}).items() if v]
                print(f"posterior-mean location error: {ev.posterior_location_pct_error:.2f} %; "
                      f"truth inside the HDI for: {', '.join(inside) or 'none'}")
        for w in result.warnings:
            print(f"note: {w}")
    if args.out:
        result.to_json(args.out)
        if not args.quiet:
            print(f"wrote {args.out}")


def _run_demo(args) -> int:
    args.scene = str(example_scene_path())
    if not args.quiet:
        print(f"example scene: {args.scene}")
    return _run_estimate(args)


def _add_estimate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", metavar="RESULT.json", help="write a creference-result/1 file")
    p.add_argument("--preset", default="default", choices=PRESETS,
                   help="optimiser preset (default: %(default)s)")
    p.add_argument("--model", default=DEFAULT_MODEL, choices=MODELS,
                   help="likelihood model: the measurement-likelihood extension or the paper's "
                        "cost with pairwise soft constraints (default: %(default)s; see "
                        "docs/benchmark_results.md)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--no-references", action="store_true", help="ignore the scene's reference annotations")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    g = p.add_argument_group("posterior")
    g.add_argument("--no-posterior", action="store_true", help="the MAP only: do not sample the posterior")
    g.add_argument("--hdi-prob", type=float, default=0.9, metavar="P",
                   help="probability of the credible intervals (default: %(default)s)")
    g.add_argument("--temperature", type=float, default=None, metavar="T",
                   help="temperature of the posterior, log p = -cost/T + log prior (default: the "
                        "model's: 1 for metrology and for the paper presets, 3 for the paper model "
                        "with the default preset)")
    g.add_argument("--min-ess", type=float, default=None, metavar="N",
                   help="bulk effective sample size to reach (default: 1000)")
    g.add_argument("--netcdf", metavar="PATH", help="write the full posterior (arviz InferenceData) as NetCDF")


def register(subparsers) -> None:
    """Add ``estimate`` and ``demo`` to the ``creference`` command."""
    p = subparsers.add_parser("estimate", help="estimate the target of a scene file")
    p.add_argument("scene", metavar="SCENE.json")
    _add_estimate_options(p)
    p.set_defaults(func=_run_estimate)
    p = subparsers.add_parser("demo", help="estimate the example scene shipped with the package")
    _add_estimate_options(p)
    p.set_defaults(func=_run_demo)
