"""``creference estimate SCENE.json`` and ``creference demo``: any scene (one target or many), a
table for the camera and one for the objects, a ``creference-result/2`` file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..camera_setup import FOCAL_PRIORS, ORIENTATIONS
from ..inference.map import PRESETS
from ..models.location_prior import LOCATION_PRIORS
from ..pipeline import DEFAULT_MODEL, MODEL_OPTIONS, MODELS
from .main import (UsageError, advanced_group, check_output_file, example_scene_path, require, seed_value,
                   usage_errors)

__all__ = ["register", "format_tables", "load_classes", "confidence_map_option", "add_confidence_map_option",
           "add_camera_options", "add_distance_range_option", "add_model_option", "model_options", "check_posterior_values"]


def _num(v, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def load_classes(path):
    """The size priors of ``--classes FILE`` (None without it), read and checked before any work."""
    if path is None:
        return None
    from ..io.validation import read_json
    from ..models.size_priors import size_priors_from_dict

    data = read_json(path)  # a SceneError naming the file: exit status 2
    with usage_errors():
        return size_priors_from_dict(data, f"{path}", "file")


def _f(v, nd=2):
    return "-" if v is None else f"{v:.{nd}f}"


#: The camera's rows: label, decimals, factor from the result's units.
_CAMERA_ROWS = {"focal_length_px": ("focal length px", 1, 1.0), "pitch": ("pitch deg", 2, 180 / np.pi),
                "roll": ("roll deg", 2, 180 / np.pi), "height_m": ("height m", 3, 1.0),
                "ref_scale": ("crowd scale", 3, 1.0)}


def format_tables(d: dict) -> str:
    """The camera's table, the objects' table (a row each) and, when the scene has ground truth,
    the errors and which true values lie in their HDI, of a ``creference-result/2`` dict."""
    cam = d["camera"]
    post = cam.get("posterior")
    prob = post["hdi"]["prob"] if post else None
    truth = (cam.get("evaluation") or {}).get("truth") or {}
    lines = ["camera", f"  {'':<16}{'MAP':>10}" + (f"{'mean':>10}  {f'{prob:.0%} HDI':<22}" if post else "")
             + (f"{'' if post else ' ' * 20}{'truth':>10}" if truth else "")]
    mid = 32 if post else 20  # the width of the mean and HDI columns, or of the notes
    for key, (label, nd, k) in _CAMERA_ROWS.items():
        if key == "ref_scale" and key not in cam["free"]:
            continue  # no references read with a crowd scale: the model has none
        row = f"  {label:<16}{_f(cam['map'][key] * k, nd):>10}"
        if post and key in post["mean"]:
            lo, hi = post["hdi"][key]
            row += f"{_f(post['mean'][key] * k, nd):>10}  {'[' + _f(lo * k, nd) + ', ' + _f(hi * k, nd) + ']':<22}"
        elif key not in cam["free"]:
            row += f"  {'(' + _why_fixed(key, cam) + ')':<{mid - 2}}"
        else:
            row += " " * mid
        if truth.get(key) is not None:
            row += f"{_f(truth[key] * k, nd):>10}"
        lines.append(row.rstrip())
    lines.append("")
    evaluated = any("evaluation" in o for o in d["objects"])
    head = f"  {'target':<10}{'class':<11}{'dist m':>8}{'x':>8}{'z':>8}{'yaw°':>7}{'l×w×h m':>16}"
    head += f"{'dist HDI':>18}" if post else ""
    head += f"{'err %':>7}" if evaluated else ""
    given = (d.get("provenance") or {}).get("distance_range_m")
    lines.append("objects (MAP" + (f"; distance {prob:.0%} HDI" if post else "")
                 + ("; location error against the truth" if evaluated else "")
                 + (f"; distance range given: {given[0]:g}–{given[1]:g} m" if given else "") + ")")
    lines.append(head)
    for o in d["objects"]:
        m = o["map"]
        size = f"{m['length_m']:.2f}×{m['width_m']:.2f}×{m['height_m']:.2f}"
        row = (f"  {o['id'][:9]:<10}{str(o['class'] or '-')[:10]:<11}{_f(m['distance_m']):>8}{_f(m['x']):>8}"
               f"{_f(m['z']):>8}{_f(np.degrees(m['yaw']), 0):>7}{size:>16}")
        if post:
            lo, hi = o["posterior"]["hdi"]["distance_m"]
            row += f"{'[' + _f(lo) + ', ' + _f(hi) + ']':>18}"
        if evaluated:
            row += f"{_f(o.get('evaluation', {}).get('location_pct_error'), 1):>7}"
        lines.append(row)
    lines += _truth_lines(d)
    diag = d.get("diagnostics")
    if diag:
        lines.append("")
        lines.append(f"posterior: {'converged' if diag['converged'] else 'NOT converged (see the notes below)'} after "
                     f"{diag['iterations']} iterations × {diag['n_chains']} chains ("
                     + (f"{diag['n_chains']} × {diag['draws_per_chain']} draws; " if diag.get("draws_per_chain") else "")
                     + "min bulk ESS "
                     f"{_num(diag['min_ess_bulk'], '.0f')}, max R-hat {_num(diag['max_r_hat'], '.3f')}), {d['seconds']:.1f} s")
    refs = _references_line(d.get("references") or {})
    if refs:
        lines.append(refs)
    return "\n".join(lines)


def _why_fixed(key: str, cam: dict) -> str:
    """What fixed a camera quantity (not a parameter of the model), as the scene has it."""
    orientation = (cam.get("setup") or {}).get("orientation")
    if key in ("pitch", "roll") and orientation == "horizon":
        return "from the exact horizon"
    if key in ("pitch", "roll") and orientation == "level":
        return "a level camera, as asked"
    if key == "focal_length_px":
        return "given in the scene"
    return "fixed"


def _truth_lines(d: dict) -> list[str]:
    """The location error and which true values lie in their HDI (with ground truth)."""
    evs = [o["evaluation"] for o in d["objects"] if "evaluation" in o]
    if not evs:
        return []
    many = len(d["objects"]) > 1
    err = lambda key: float(np.median([e[key] for e in evs]))
    text = f"location error against the ground truth{' (median over the objects)' if many else ''}: " \
           f"MAP {err('location_pct_error'):.2f} %"
    if all(e.get("posterior_location_pct_error") is not None for e in evs):
        text += f", posterior mean {err('posterior_location_pct_error'):.2f} %"
    out = ["", text + " (distance to the true location, as a share of its distance from the camera)"]
    cam = d["camera"].get("evaluation") or {}
    if "in_hdi" not in cam and not any("in_hdi" in e for e in evs):
        return out
    prob = d["camera"].get("posterior", {}).get("hdi", {}).get("prob", d.get("hdi_prob", 0.9))
    inside = [k for k, v in cam.get("in_hdi", {}).items() if v]
    outside = [k for k, v in cam.get("in_hdi", {}).items() if not v]
    fixed = [k for k in cam.get("truth", {}) if k not in cam.get("in_hdi", {})]
    for key in ("x", "y", "z", "yaw", "distance_m"):
        flags = [e["in_hdi"][key] for e in evs if key in e.get("in_hdi", {})]
        if flags and not many:
            (inside if flags[0] else outside).append(key)
        elif flags:
            inside.append(f"{key} {sum(flags)} of {len(flags)}")
    out.append(f"truth inside the {prob:.0%} HDI: {', '.join(inside) or 'none'}"
               + (f"; outside: {', '.join(outside)}" if outside else "")
               + (f"; not checked (fixed, no spread in the posterior): {_fixed_list(fixed, d['camera'])}" if fixed else ""))
    return out


def _fixed_list(keys: list[str], cam: dict) -> str:
    """``focal_length_px (given in the scene), pitch and roll (from the exact horizon)``."""
    why: dict[str, list[str]] = {}
    for key in keys:
        why.setdefault(_why_fixed(key, cam), []).append(key)
    return ", ".join(f"{' and '.join(names)} ({reason})" for reason, names in why.items())


def _references_line(refs: dict) -> str | None:
    if refs.get("used_as") == "likelihood" and refs.get("n_references"):
        left = refs.get("left_out") or {}
        why = f" (left out: {', '.join(f'{k}: {v}' for k, v in left.items())})" if left else ""
        return f"references: {refs['in_likelihood']} of {refs['n_references']} used as measurements{why}"
    if refs.get("used_as") == "pairwise bounds":
        used = sum(o["pairs_used"] for o in refs["objects"])
        total = used + sum(o["pairs_skipped"] for o in refs["objects"])
        return f"references: as bounds from {used} of {total} pairs" if total else "references: none"
    return None


def confidence_map_option(value: str | None, model: str):
    """The map named by ``--confidence-map`` (None: the default), read and checked before any work:
    ``"default"``, ``"none"``, ``"identity"`` or a :class:`ConfidenceMap` read from the file."""
    from ..models.confidence_map import MAP_NAMES, ConfidenceMap, ConfidenceMapError

    if value is None:
        return "default"
    from ..pipeline import check_confidence_map

    with usage_errors():
        check_confidence_map(model, value, "--confidence-map")
    if value in MAP_NAMES:
        return value
    if not Path(value).exists():  # a typo of a name, or a file that is not there
        from ..io.validation import near_miss

        guess = near_miss(value, MAP_NAMES)
        raise UsageError(f"--confidence-map: {value!r} is none of {', '.join(MAP_NAMES)} and no such file"
                         + (f"; did you mean {guess!r}?" if guess else ""))
    with usage_errors("--confidence-map: ", ConfidenceMapError):
        return ConfidenceMap.load(value)


def add_confidence_map_option(p: argparse.ArgumentParser) -> None:
    """``--confidence-map`` (estimate, demo, batch), among the advanced options."""
    from ..models.confidence_map import DEFAULT_CONFIDENCE_MAP

    advanced_group(p).add_argument(
        "--confidence-map", default=None, metavar="none|identity|MAP.json",
        help="how a reference range stated with a confidence (\"90 %% sure: 4-6 m\") is read by the "
             "metrology model: none (the confidence ignored), identity (the range taken as a central "
             "interval of that probability) or a map fitted by `creference confidence fit` (default: "
             f"{DEFAULT_CONFIDENCE_MAP}; docs/confidence.md)")


def check_posterior_values(args) -> None:
    """``--hdi-prob``, ``--temperature`` and ``--min-ess`` (shared with ``batch``)."""
    require(0.0 < args.hdi_prob < 1.0, "--hdi-prob", "a probability in (0, 1)", args.hdi_prob)
    t = args.temperature
    require(t is None or (np.isfinite(t) and t > 0), "--temperature", "a number > 0", t)
    require(args.min_ess is None or args.min_ess >= 1, "--min-ess", "a number ≥ 1", args.min_ess)


def sampling_options(args) -> dict:
    """The sampler settings ``--min-ess`` and ``--max-steps`` ask for (shared with ``batch``); empty
    for the sampler's defaults."""
    sampling = {} if args.min_ess is None else {"min_ess": args.min_ess}
    if args.max_steps is not None:
        require(args.max_steps >= 10, "--max-steps", "an integer >= 10", args.max_steps)
        # the sampler checks convergence every `chunk` steps: a smaller cap gets a smaller chunk
        sampling.update(max_steps=args.max_steps, chunk=min(100, args.max_steps))
    return sampling


def estimate_fields(args, classes=None, scene=None) -> dict:
    """The :class:`~creference_bayes.pipeline.EstimateSettings` fields the options shared by
    ``estimate``, ``demo`` and ``batch`` ask for (each checked: a usage error naming the option)."""
    check_posterior_values(args)
    return dict(model=args.model, preset=args.preset, posterior=not args.no_posterior, hdi_prob=args.hdi_prob,
                temperature=args.temperature, use_references=not args.no_references,
                sampling=sampling_options(args), focal_prior=args.focal_prior, orientation=args.orientation,
                location_prior=args.location_prior, distance_range=args.distance_range,
                confidence_map=confidence_map_option(args.confidence_map, args.model), classes=classes or {},
                options=model_options(args, scene))


def _run_estimate(args, banner: str | None = None) -> int:
    from ..io.files import atomic_path
    from ..io.scene import load_scene
    from ..pipeline import EstimateSettings, estimate

    classes = load_classes(args.classes)
    scene = load_scene(args.scene, classes=classes)
    for w in scene.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.no_posterior and args.netcdf:
        raise UsageError("--netcdf: there is no posterior to write with --no-posterior")
    check_output_file("--out", args.out)
    check_output_file("--netcdf", args.netcdf)
    settings = EstimateSettings(**estimate_fields(args, classes, scene))
    if banner and not args.quiet:  # once the command line is known to be good
        print(banner)
    result = estimate(scene, settings, seed=args.seed, progress=not args.quiet and sys.stderr.isatty())
    d = result.to_dict()
    if args.out:  # it records where the scene is, so that plot and advise find it wherever it is written
        result.save(args.out)
    idata = result.to_inference_data() if args.netcdf else None
    if idata is not None:
        with atomic_path(args.netcdf) as tmp:
            idata.to_netcdf(tmp)
    elif args.netcdf:
        print(f"warning: no posterior, so {args.netcdf} was not written", file=sys.stderr)
    printed = set(scene.warnings)  # already printed as "warning:" when the scene was read
    notes = [f"note: {w}" for w in result.warnings if w not in printed]
    if args.quiet:  # no tables, but what the result warns of (a posterior not converged, a box that misses)
        for line in notes:
            print(line, file=sys.stderr)
        return 0
    print(f"{args.scene}: {len(d['objects'])} object{'s' if len(d['objects']) > 1 else ''}, model {d['model']}, "
          f"preset {d['preset']}, MAP in {d['map_info']['seconds']:.2f} s")
    print(format_tables(d))
    for line in notes:
        print(line)
    for path in (args.out, idata is not None and args.netcdf):
        if path:
            print(f"wrote {path}")
    return 0


def _run_demo(args) -> int:
    args.scene = str(example_scene_path())
    args.classes = None
    return _run_estimate(args, banner=f"example scene (synthetic, with ground truth): {args.scene}")


def add_distance_range_option(p: argparse.ArgumentParser) -> None:
    """``--distance-range`` (``estimate``, ``demo``, ``batch``), among the everyday options."""
    p.add_argument("--distance-range", type=distance_range_arg, default=None, metavar="LOW,HIGH",
                   help="the ground distances in metres the targets stand at, for example 3,80 for a street "
                        "camera: distances outside become unlikely (docs/method.md, A distance range)")


def add_camera_options(p: argparse.ArgumentParser) -> None:
    """``--focal-prior``, ``--orientation`` and ``--location-prior`` (``estimate``, ``demo``,
    ``batch``), among the advanced options."""
    g = advanced_group(p)
    g.add_argument("--focal-prior", default="auto", choices=FOCAL_PRIORS,
                   help="what is assumed of the focal length when the scene does not give it: auto (the "
                        "scene's camera.focal_length_prior, else the photo's EXIF, else a broad prior "
                        "around a 26 mm-equivalent lens), default (that broad prior, ignoring scene and "
                        "EXIF), none (any focal length within the bounds) (default: %(default)s)")
    g.add_argument("--orientation", default="auto", choices=ORIENTATIONS,
                   help="how the camera's pitch and roll are found: auto (from an exact horizon; "
                        "otherwise estimated, using a horizon found in the photo when there is one), "
                        "free (estimated even when the scene gives a horizon), level (a scene without a "
                        "horizon is assumed taken with a level camera: pitch and roll 0) "
                        "(default: %(default)s)")
    g.add_argument("--location-prior", default="auto", choices=("auto",) + LOCATION_PRIORS,
                   help="what is assumed of where a target stands before the annotations are read: "
                        "log-depth (every distance equally likely on a log scale), flat (every ground "
                        "position equally likely) or inverse-square (1/d², a comparison only); auto: "
                        "log-depth with the default preset, flat with the paper presets "
                        "(docs/method.md, Priors)")


def distance_range_arg(text: str) -> tuple[float, float]:
    """``--distance-range LOW,HIGH``: two numbers of metres, 0 < LOW < HIGH."""
    from ..models.location_prior import LocationPrior

    try:
        lo, hi = (float(v) for v in text.split(","))
        return LocationPrior(distance_m=(lo, hi)).distance_m
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH in metres with 0 < LOW < HIGH, got {text!r}") from None


def add_model_option(p: argparse.ArgumentParser) -> None:
    """``--option KEY=VALUE`` (``estimate``, ``demo``, ``batch``), among the advanced options."""
    advanced_group(p).add_argument(
        "--option", action="append", default=[], metavar="KEY=VALUE",
        help="change one setting of the model, repeatable (e.g. --option target_dof=30 reads the "
             "annotations' errors as nearly normal). Keys of the metrology model: "
             f"{', '.join(MODEL_OPTIONS['metrology'])}; of the paper model: "
             f"{', '.join(MODEL_OPTIONS['paper'])}. What each does, with its default: "
             "docs/user_guide.md, Model options")


def model_options(args, scene=None) -> dict:
    """The ``--option`` values, typed for ``args.model`` and checked by building the model of
    ``scene`` (default: the package's example scene, before a batch reads any of its own): a usage
    error naming the option and its value."""
    from ..io.scene import load_scene
    from ..pipeline import build_model, parse_model_options

    with usage_errors():
        options = parse_model_options(args.model, args.option)
    distance_range = getattr(args, "distance_range", None)
    if options or distance_range is not None:
        scene = scene if scene is not None else load_scene(example_scene_path())
    if options:
        with usage_errors("--option "):  # a value out of the model's range
            build_model(scene, model=args.model, preset=args.preset, **options)
    if distance_range is not None:
        from ..inference.map import preset_bounds
        from ..pipeline import check_distance_range

        with usage_errors("--distance-range: "):  # beyond the preset's bounds
            check_distance_range(distance_range, preset_bounds(args.preset, scene.image_size), scene.image_size)
    return options


def _add_estimate_options(p: argparse.ArgumentParser, classes: bool = True) -> None:
    """The options of ``estimate`` (``classes``: with ``--classes``) and ``demo``: the everyday ones
    first, then the advanced ones (:func:`~.main.advanced_group`)."""
    p.add_argument("--out", metavar="RESULT.json", help="write a creference-result/2 file")
    p.add_argument("--seed", type=seed_value, default=0, help="random seed (default: %(default)s)")
    if classes:
        p.add_argument("--classes", metavar="CLASSES.json", default=None,
                       help="size priors of your own classes (docs/overview.md, Class size priors); the "
                            "scene's own win")
    add_distance_range_option(p)
    p.add_argument("--no-posterior", action="store_true",
                   help="the MAP only: no credible intervals, much faster")
    p.add_argument("--hdi-prob", type=float, default=0.9, metavar="P",
                   help="probability of the credible intervals (default: %(default)s)")
    p.add_argument("--netcdf", metavar="PATH", help="write the full posterior (arviz InferenceData) as NetCDF")
    p.add_argument("--quiet", action="store_true",
                   help="no tables and no progress bar: only errors, warnings and notes, on standard error")
    g = advanced_group(p)
    g.add_argument("--model", default=DEFAULT_MODEL, choices=MODELS,
                   help="how annotations are weighed: metrology (each annotation and reference a noisy "
                        "measurement) or paper (the paper's cost with pairwise soft constraints, to compare "
                        "or reproduce it) (default: %(default)s; docs/studies/benchmark.md)")
    g.add_argument("--preset", default="default", choices=PRESETS,
                   help="how the MAP is searched for and within which bounds: default (this package's "
                        "optimiser), paper (the paper's system study: 200 random restarts, its bounds; "
                        "slow), paper-controlled (the paper's controlled study: 100 restarts, its bounds) "
                        "(default: %(default)s; docs/method.md, Bounds)")
    g.add_argument("--no-references", action="store_true",
                   help="ignore the scene's reference annotations (to see what they add)")
    add_confidence_map_option(p)
    add_model_option(p)
    add_camera_options(p)
    g.add_argument("--temperature", type=float, default=None, metavar="T",
                   help="widen (T > 1) or narrow (T < 1) the posterior: log p = -cost/T + log prior (default: "
                        "the model's calibrated one: 1 for metrology and the paper presets, 3 for the paper "
                        "model with the default preset)")
    g.add_argument("--min-ess", type=float, default=None, metavar="N",
                   help="the sampler runs until every checked quantity has this bulk effective sample size "
                        "(default: 400)")
    g.add_argument("--max-steps", type=int, default=None, metavar="N",
                   help="cap on the sampler's steps; a posterior that has not converged by then says so "
                        "(default: 20000)")


def register(subparsers) -> None:
    """Add ``estimate`` and ``demo`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "estimate", help="estimate every target of a scene file and its camera",
        description="Estimate the 3D location of every target of a scene and the camera: the MAP, then "
                    "(unless --no-posterior) the posterior with credible intervals and diagnostics. "
                    "Prints a table for the camera and one for the objects; --out writes a "
                    "creference-result/2 file (docs/result_format.md).")
    p.add_argument("scene", metavar="SCENE.json",
                   help="a scene file: creference-scene/1 (one target) or creference-scene/2 (one or more; "
                        "docs/scene_format.md)")
    _add_estimate_options(p)
    p.set_defaults(func=_run_estimate)
    p = subparsers.add_parser(
        "demo", help="estimate the synthetic example scene shipped with the package",
        description="Run `creference estimate` on the example scene shipped with the package: a "
                    "synthetic scene (simulated annotations of a TV stand in a room, no photo) "
                    "with five references and its ground truth, so the output also shows the "
                    "error of the estimate.")
    _add_estimate_options(p, classes=False)
    p.set_defaults(func=_run_demo)
