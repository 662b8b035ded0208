"""``creference estimate SCENE.json`` and ``creference demo``: one scene's target, a table, a result file."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from ..camera_setup import FOCAL_PRIORS, ORIENTATIONS
from ..inference.optimize import PRESETS
from ..pipeline import DEFAULT_MODEL, MODELS
from .main import UsageError, check_output_file, example_scene_path, seed_value

__all__ = ["register", "format_table", "truth_of", "confidence_map_option", "add_confidence_map_option"]


#: Units of the quantities a result may hold; a quantity not listed is shown without a unit.
UNITS = {"x": "m", "y": "m", "z": "m", "yaw": "rad", "pitch": "rad", "roll": "rad",
         "focal_length_px": "px", "distance_m": "m"}
#: Decimals shown per unit (millimetres, milliradians, whole pixels); every number of a row
#: (MAP, mean, sd, HDI, truth) has its row's decimals. Other units: 4 significant digits of the MAP.
DECIMALS = {"m": 3, "rad": 3, "px": 0}


def format_table(result, truth=None) -> str:
    """A plain-text table of a result: one row per quantity, in the order of the result's ``map``
    (then the posterior's extra quantities, such as ``distance_m``), whatever parameters it has.

    Parameters
    ----------
    result : a :class:`~creference_bayes.io.result.Result` or its ``creference-result/1`` dict
    truth : optional: a :class:`~creference_bayes.io.scene.Scene` (its ground truth, if any) or
        a dict name → true value (missing names are left blank)
    """
    d = result if isinstance(result, dict) else result.to_dict()
    if truth is not None and not isinstance(truth, dict):
        truth = truth_of(truth)
    post = d.get("posterior")
    point = dict(d["map"])
    names = list(point)
    if post:
        names += [k for k in post["mean"] if k not in point]
    if "distance_m" not in names and {"x", "z"} <= set(point):
        names.append("distance_m")
    if "distance_m" not in point and {"x", "z"} <= set(point):
        point["distance_m"] = float(np.hypot(point["x"], point["z"]))
    cols = ["quantity", "unit", "MAP"]
    if post:
        cols += ["mean", "sd", f"{post['hdi']['prob']:.0%} HDI"]
    if truth is not None:
        cols.append("truth")
    rows = []
    for name in names:
        unit = UNITS.get(name, "")
        dec = _decimals(unit, point.get(name))
        row = [name, unit, _fmt(point.get(name), dec)]
        if post:
            lo, hi = post["hdi"].get(name) or (None, None)
            row += [_fmt(post["mean"].get(name), dec), _fmt(post["sd"].get(name), dec), (_fmt(lo, dec), _fmt(hi, dec))]
        if truth is not None:
            row.append(_fmt(truth.get(name), dec))
        rows.append(row)
    if post:  # the HDI as "[low, high]" with the lows and the highs aligned
        i = cols.index(f"{post['hdi']['prob']:.0%} HDI")
        wl = max(len(r[i][0]) for r in rows)
        wh = max(len(r[i][1]) for r in rows)
        for r in rows:
            lo, hi = r[i]
            r[i] = f"[{lo.rjust(wl)}, {hi.rjust(wh)}]" if lo or hi else ""
    widths = [max(len(str(r[i])) for r in rows + [cols]) for i in range(len(cols))]
    left = {0, 1}  # names and units to the left, numbers to the right

    def line(cells):
        return "  ".join(c.ljust(w) if i in left else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return "\n".join([line(cols), "  ".join("-" * w for w in widths)] + [line(r) for r in rows])


def _decimals(unit: str, value) -> int:
    if unit in DECIMALS:
        return DECIMALS[unit]
    if value is None or not np.isfinite(value) or value == 0:
        return 3
    return int(max(0, 3 - np.floor(np.log10(abs(float(value))))))


def _fmt(x, decimals: int = 3) -> str:
    if x is None:
        return ""
    x = float(x)
    if not np.isfinite(x):
        return str(x)
    text = f"{x:.{decimals}f}"
    return text.lstrip("-") if float(text) == 0 else text


def truth_of(scene) -> dict | None:
    """The scene's ground truth by quantity name (pitch and roll from its extras when given), or
    None when it has none."""
    gt = scene.ground_truth
    if gt is None:
        return None
    x, y, z = (float(v) for v in gt.location_m)
    t = {"x": x, "y": y, "z": z, "yaw": gt.yaw_rad, "focal_length_px": gt.focal_length_px,
         "distance_m": float(np.hypot(x, z))}
    for name in ("pitch", "roll"):
        if gt.extra.get(f"{name}_rad") is not None:
            t[name] = float(gt.extra[f"{name}_rad"])
    return t


def confidence_map_option(value: str | None, model: str):
    """The map named by ``--confidence-map`` (None: the default), read and checked before any work:
    ``"default"``, ``"none"``, ``"identity"`` or a :class:`ConfidenceMap` read from the file."""
    from ..models.confidence_map import MAP_NAMES, ConfidenceMap, ConfidenceMapError

    if value is None:
        return "default"
    if model == "paper" and value != "none":
        raise UsageError(f"--confidence-map: the paper model turns ranges into bounds and does not read "
                         f"stated confidences, got {value!r} (use --model metrology, or none)")
    if value in MAP_NAMES:
        return value
    try:
        return ConfidenceMap.load(value)
    except ConfidenceMapError as exc:
        raise UsageError(f"--confidence-map: {exc}") from None


def add_confidence_map_option(p: argparse.ArgumentParser) -> None:
    """``--confidence-map`` (estimate, demo, batch)."""
    from ..models.confidence_map import DEFAULT_CONFIDENCE_MAP

    p.add_argument("--confidence-map", default=None, metavar="none|identity|MAP.json",
                   help="how the metrology model reads a range stated with a confidence: none "
                        "(confidence ignored), identity (the worker's c %% range read as their central "
                        "c %% interval) or a map fitted by `creference confidence fit` (default: "
                        f"{DEFAULT_CONFIDENCE_MAP}; docs/confidence.md)")


def _run_estimate(args) -> int:
    from ..io.scene import load_scene
    from ..pipeline import estimate
    from .frame import is_frame_file, run_frame_estimate

    if is_frame_file(args.scene):
        return run_frame_estimate(args)
    scene = load_scene(args.scene)
    for w in scene.warnings:
        print(f"warning: {w}", file=sys.stderr)
    _check_posterior_options(args)
    cmap = confidence_map_option(args.confidence_map, args.model)
    result = estimate(scene, preset=args.preset, seed=args.seed, model=args.model, confidence_map=cmap,
                      use_references=not args.no_references, posterior=not args.no_posterior,
                      focal_prior=args.focal_prior, orientation=args.orientation,
                      location_prior=args.location_prior,
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
    check_output_file("--out", args.out)
    check_output_file("--netcdf", args.netcdf)
    check_posterior_values(args)


def check_posterior_values(args) -> None:
    """``--hdi-prob``, ``--temperature`` and ``--min-ess`` (shared with ``batch``)."""
    if not 0.0 < args.hdi_prob < 1.0:
        raise UsageError(f"--hdi-prob: expected a probability in (0, 1), got {args.hdi_prob!r}")
    if args.temperature is not None and not (np.isfinite(args.temperature) and args.temperature > 0):
        raise UsageError(f"--temperature: expected a number > 0, got {args.temperature!r}")
    if args.min_ess is not None and not args.min_ess >= 1:
        raise UsageError(f"--min-ess: expected a number ≥ 1, got {args.min_ess!r}")


#: Handedness of the dimension lines, in a word (core/geometry.py: dimension_corners).
HANDEDNESS_WORDS = {1: "width line counter-clockwise from the length line, seen from above",
                    -1: "width line clockwise from the length line, seen from above"}


def _posterior_line(result) -> str:
    g = result.diagnostics
    ess = [v for v in g.ess_bulk.values() if v is not None]
    rhat = [v for v in g.r_hat.values() if v is not None]
    state = "converged" if g.converged else "NOT converged (see the notes below)"
    return (f"posterior: {state}; R-hat ≤ {max(rhat, default=float('nan')):.3f}, bulk ESS ≥ "
            f"{min(ess, default=float('nan')):.0f}; {g.n_walkers} walkers in {g.n_ensembles} "
            f"ensembles, {g.n_steps} steps (+{g.warmup_steps} warm-up), {g.seconds:.2f} s, "
            f"temperature {result.posterior.temperature:g}")


def _references_line(refs) -> str | None:
    if refs is None or not hasattr(refs, "pairs_used"):
        return None
    if not refs.enabled:
        return f"references: {refs.n_references} ignored (--no-references)"
    if refs.n_references == 0:
        return "references: none"
    n_pairs = refs.pairs_used + refs.pairs_skipped
    why = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in refs.skipped_reasons.items())
    skipped = f" (skipped: {why})" if why else ""
    if refs.used_as == "likelihood":
        return (f"references: {refs.in_likelihood} of {refs.n_references} used as measurements; "
                f"the paper's pairwise method could use {refs.pairs_used} of {n_pairs} pairs{skipped}")
    return f"references: {refs.n_references}, as bounds from {refs.pairs_used} of {n_pairs} pairs{skipped}"


def _report(result, scene, args) -> None:
    if not args.quiet:
        h = result.map.handedness
        print(f"target {result.target!r}  model {result.model}  preset {result.preset}  "
              f"MAP in {result.map.seconds:.2f} s")
        print(f"handedness {h:+d} ({HANDEDNESS_WORDS.get(h, 'unknown')})")
        print(format_table(result, truth_of(scene)))
        if result.diagnostics is not None:
            print(_posterior_line(result))
        refs = _references_line(result.references)
        if refs:
            print(refs)
        ev = result.evaluation
        if ev is not None:
            text = f"location error against the ground truth: MAP {ev.location_pct_error:.2f} %"
            if ev.posterior_location_pct_error is not None:
                text += f", posterior mean {ev.posterior_location_pct_error:.2f} %"
            print(text + " (distance to the true location, as a share of its distance from the camera)")
            if ev.in_hdi is not None:
                inside = [k for k, v in ev.in_hdi.items() if v]
                outside = [k for k, v in ev.in_hdi.items() if not v]
                truth = truth_of(scene) or {}
                fixed = [k for k in result.posterior.mean if k in truth and k not in ev.in_hdi]
                print(f"truth inside the {result.posterior.hdi_prob:.0%} HDI: {', '.join(inside) or 'none'}"
                      + (f"; outside: {', '.join(outside)}" if outside else "")
                      + (f"; not checked: {', '.join(fixed)} (no spread in the posterior: fixed by "
                         "the exact horizon or the camera set-up)" if fixed else ""))
        printed = set(scene.warnings)  # already printed as "warning:" when the scene was read
        for w in result.warnings:
            if w not in printed:
                print(f"note: {w}")
    if args.out:
        result.to_json(args.out)
        if not args.quiet:
            print(f"wrote {args.out}")


def _run_demo(args) -> int:
    args.scene = str(example_scene_path())
    if not args.quiet:
        print(f"example scene (synthetic, with ground truth): {args.scene}")
    return _run_estimate(args)


def add_camera_options(p: argparse.ArgumentParser) -> None:
    """``--focal-prior`` and ``--orientation`` (shared by ``estimate``, ``demo`` and ``batch``)."""
    g = p.add_argument_group("camera")
    g.add_argument("--focal-prior", default="auto", choices=FOCAL_PRIORS,
                   help="prior on the focal length when the scene does not give it: auto (the "
                        "scene's camera.focal_length_prior, else the photo's EXIF, else a weak "
                        "default around a 30 mm-equivalent lens), default (the weak default), "
                        "none (flat within the bounds) (default: %(default)s)")
    g.add_argument("--orientation", default="auto", choices=ORIENTATIONS,
                   help="camera pitch and roll: auto (from an exact horizon; otherwise estimated, "
                        "with the horizon from the photo as a measurement when there is one), free "
                        "(estimated even with a horizon), level (assume a level camera when there "
                        "is no horizon, the old behaviour) (default: %(default)s)")
    g.add_argument("--location-prior", default="auto", choices=("auto", "log-depth", "flat", "inverse-square"),
                   help="one target: prior on its ground position: uniform in log depth with the MAP in log "
                        "coordinates, or flat in (x, z) (auto: log-depth with the default preset, flat with "
                        "the paper presets; inverse-square, 1/d², for comparison; docs/method.md, Priors); "
                        "frames: log-depth (auto) or flat")


def _add_estimate_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", metavar="RESULT.json", help="write a creference-result/1 file")
    p.add_argument("--preset", default="default", choices=PRESETS,
                   help="optimiser preset (default: %(default)s)")
    p.add_argument("--model", default=DEFAULT_MODEL, choices=MODELS,
                   help="likelihood model: the measurement-likelihood extension or the paper's "
                        "cost with pairwise soft constraints (default: %(default)s; see "
                        "docs/benchmark_results.md)")
    p.add_argument("--seed", type=seed_value, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--no-references", action="store_true", help="ignore the scene's reference annotations")
    add_confidence_map_option(p)
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    add_camera_options(p)
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
    p = subparsers.add_parser(
        "estimate", help="estimate the target of a scene file",
        description="Estimate the 3D location of a scene's target: the MAP, then (unless "
                    "--no-posterior) the posterior with credible intervals and diagnostics. "
                    "Prints a table; --out writes a creference-result/1 file (docs/result_format.md).")
    p.add_argument("scene", metavar="SCENE.json",
                   help="a creference-scene/1 file, or a creference-scene/2 frame of several targets "
                        "(docs/scene_format.md, docs/frames.md)")
    _add_estimate_options(p)
    p.add_argument("--classes", metavar="CLASSES.json", default=None,
                   help="frames: size priors of your own classes (docs/frames.md); the scene's own win")
    p.set_defaults(func=_run_estimate)
    p = subparsers.add_parser(
        "demo", help="estimate the synthetic example scene shipped with the package",
        description="Run `creference estimate` on the example scene shipped with the package: a "
                    "synthetic scene (simulated annotations of a TV stand in a room, no photo) "
                    "with five references and its ground truth, so the output also shows the "
                    "error of the estimate.")
    _add_estimate_options(p)
    p.set_defaults(func=_run_demo)
