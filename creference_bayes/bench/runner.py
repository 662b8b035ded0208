"""The benchmark (benchmark.md): the paper's method, a peer, our models and the Cramér–Rao bound,
side by side on the same simulated scenes in one process.

The command line (``creference bench``, ``creference simulate``) is :mod:`creference_bayes.cli.bench`.

What runs on every scene (13 target annotations and 5 references are simulated; estimators get
the first 5 annotations, as in the paper's §7.1, and the first k references):

- ``paper``: the paper's method as published (preset ``paper``: basin hopping with random
  restarts, σ = 100, its bounds, per-corner median, pairwise sigmoid bounds), with 5 references;
  in ``--quick`` with fewer restarts, labelled so;
- ``p4pf``: PoseLib's P4Pf with least-squares refinement on the target corners (:mod:`.peers`);
- ``ours-paper`` and ``ours-metrology``: the package's MAP (preset ``default``) of each model with
  k = 0…5 references, and its posterior (mean, credible regions, ranks of the truth) for the
  configured k;
- ``crb-target`` and ``crb-refs``: the Cramér–Rao bound with target annotations only, and with
  the 5 references as the metrology model sees them (:mod:`.crb`).

Plus: the same-human-time comparison (10 target annotations against 5 + 5 references, the paper's
Analysis 2, task times 183.5 s and 64.4 s), every pair of references alone (skipped against used
pairs, Fig. 11), and a calibration sweep of the paper model's posterior over σ (Eq. 5) and the
temperature T. Tables: :mod:`.report`; figures: :mod:`.figures`.
"""

from __future__ import annotations

import errno
import json
import platform
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from itertools import combinations
from pathlib import Path

import numpy as np

from .. import __version__
from ..core.geometry import Camera
from ..core.metrics import location_percentage_error
from ..models.params import wrap_angle
from ..io.scene import Scene, parse_scene
from .simulate import SETTINGS, TIERS, simulate_scene

__all__ = ["BenchConfig", "CONFIGS", "bench_scenes", "variant", "calibration_of", "run_bench",
           "write_scenes", "plain"]

BENCH_FORMAT = "creference-bench/1"
CREDIBLE_LEVELS = (0.5, 0.9)
MODELS = ("paper", "metrology")


@dataclass(frozen=True)
class BenchConfig:
    """How much of the benchmark runs.

    Attributes
    ----------
    name : ``quick`` or ``full``
    scenes : ((tier, setting, count), …) scenes simulated per tier and setting
    ref_counts : numbers of references for the MAP of our models (Fig. 10)
    posterior_ref_counts : numbers of references for which our posteriors are sampled
    paper_restarts : basin-hopping restarts of the ``paper`` preset (None: the paper's 200)
    paper_baseline_scenes : scenes per tier on which the ``paper`` preset also runs on 10 target
        annotations without references (Analysis 2)
    pair_scenes : scenes per tier on which every reference pair is run alone (Fig. 11)
    paper_posterior_grid : ((σ px, T), …) of the paper model's posterior in the calibration sweep
    sweep_scenes : scenes per tier in that sweep
    sampler : emcee settings for the bench (:class:`~creference_bayes.inference.sampling.SamplerSettings` options)
    n_target, n_target_baseline : target annotations the estimators get (5) and the baseline (10)
    camera_studies : also run the metrology model on every scene without its horizon
        (``ours-metrology-nohorizon``: pitch and roll estimated) and with a flat focal-length prior
        (``ours-metrology-flatfocal``), with the Cramér–Rao bound for free pitch and roll
    exact_scenes : noise-free scenes with 20 exact references, estimated with and without them
        (:func:`exact_reference_records`)
    """

    name: str
    scenes: tuple[tuple[str, str, int], ...]
    ref_counts: tuple[int, ...] = (0, 1, 2, 3, 4, 5)
    posterior_ref_counts: tuple[int, ...] = (0, 5)
    paper_restarts: int | None = None
    paper_baseline_scenes: int = 0
    pair_scenes: int = 2
    paper_posterior_grid: tuple[tuple[float, float], ...] = ()
    sweep_scenes: int = 0
    sampler: dict = field(default_factory=dict)
    n_target: int = 5
    n_target_baseline: int = 10
    camera_studies: bool = True
    exact_scenes: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def _grid(counts: dict[str, tuple[int, int]]) -> tuple[tuple[str, str, int], ...]:
    return tuple((t, s, n) for t, (ni, no) in counts.items() for s, n in (("indoor", ni), ("outdoor", no)) if n)


CONFIGS = {
    # CI-sized: 5 scenes, the paper preset with 8 restarts instead of 200 (labelled in the output)
    "quick": BenchConfig(
        name="quick", scenes=_grid({"none": (1, 0), "low": (1, 0), "medium": (0, 1), "high": (1, 1)}),
        ref_counts=(0, 5), posterior_ref_counts=(5,), paper_restarts=8, paper_baseline_scenes=0,
        pair_scenes=0, sampler={"min_ess": 200, "n_ensembles": 2, "max_steps": 3000}, exact_scenes=1),
    # the documented run (docs/benchmark_results.md)
    "full": BenchConfig(
        name="full", scenes=_grid({t: (5, 3) for t in TIERS}),
        ref_counts=(0, 1, 2, 3, 4, 5), posterior_ref_counts=(0, 2, 5), paper_restarts=None,
        paper_baseline_scenes=2, pair_scenes=3, sweep_scenes=8,
        paper_posterior_grid=((100.0, 1.0), (100.0, 0.1), (2.0, 1.0), (2.0, 2.0), (2.0, 3.0), (2.0, 4.0),
                              (3.0, 3.0), (3.0, 4.0)),
        sampler={"min_ess": 400}, exact_scenes=10),
}


# ------------------------------------------------------------------------------------------------
# scenes


def bench_scenes(config: BenchConfig, seed: int = 0) -> list[tuple[str, Scene]]:
    """The bench's scenes, tier by tier, indoor and outdoor interleaved in proportion (so the
    first few scenes of a tier mix both settings); deterministic for ``seed``; the references'
    formats cycle so that every two scenes cover all ten once."""
    tier_names, setting_names = list(TIERS), list(SETTINGS)
    order = []
    for tier, setting, n in config.scenes:
        order += [(tier_names.index(tier), (i + 0.5) / n, setting_names.index(setting), i) for i in range(n)]
    out = []
    for k, (t, _, s, i) in enumerate(sorted(order)):
        rng = np.random.default_rng([seed, t, s, i])
        d = simulate_scene(rng, setting=setting_names[s], tier=tier_names[t], format_offset=5 * k)
        out.append((f"{tier_names[t]}-{setting_names[s]}-{i:02d}", _parse(d)))
    return out


def _parse(d: dict) -> Scene:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def variant(scene: Scene, n_target: int, references) -> Scene:
    """``scene`` with its first ``n_target`` annotations and the given references (indices)."""
    refs = tuple(scene.references[i] for i in references)
    target = replace(scene.target, dimension_lines=scene.target.dimension_lines[:n_target])
    return replace(scene, target=target, references=refs)


def write_scenes(outdir, n: int, seed: int = 0, tier: str = "all", setting: str | None = None,
                 *, overwrite: bool = False, **options) -> list[Path]:
    """Write ``n`` simulated scenes ``scene_0000.json`` … to ``outdir`` (deterministic for ``seed``).

    ``tier`` is a tier name or ``all`` (cycling none, low, medium, high); reference formats cycle
    so that every ten references cover the ten formats once each. Each file is written whole or
    not at all (:func:`~creference_bayes.io.files.atomic_write_text`). ``options`` go to
    :func:`~.simulate.simulate_scene` (e.g. ``confidence``, ``n_references``).

    Raises
    ------
    FileExistsError
        When ``outdir`` exists and is not empty, unless ``overwrite`` (files of the same name are
        then replaced; other files are left alone).
    """
    from ..io.files import atomic_write_text

    outdir = Path(outdir)
    if not overwrite and outdir.is_dir() and any(outdir.iterdir()):
        raise FileExistsError(errno.EEXIST, "folder is not empty (overwrite=True replaces its scenes)",
                              str(outdir))
    outdir.mkdir(parents=True, exist_ok=True)
    tiers = list(TIERS) if tier == "all" else [tier]
    paths = []
    for i in range(n):
        d = simulate_scene(np.random.default_rng([seed, i]), setting=setting, tier=tiers[i % len(tiers)],
                           format_offset=5 * i, **options)
        p = outdir / f"scene_{i:04d}.json"
        atomic_write_text(p, json.dumps(d, indent=1) + "\n")
        paths.append(p)
    return paths


# ------------------------------------------------------------------------------------------------
# estimators


def _estimate(scene: Scene, model: str, preset: str, seed, *, posterior: bool = False,
              temperature: float | None = None, sampling: dict | None = None, **options):
    """The package's own :func:`~creference_bayes.pipeline.estimate` (MAP, and the posterior when asked)."""
    from ..pipeline import estimate

    return estimate(scene, preset=preset, model=model, seed=seed, posterior=posterior,
                    temperature=temperature, sampling=sampling or None, **options)


def _posterior_fields(result, truth: dict) -> dict:
    from ..inference.summary import draws_from_inference_data

    draws = {k: np.asarray(v).ravel() for k, v in draws_from_inference_data(result.inference_data).items()}
    cover, ranks = calibration_of(draws, truth)
    return dict(post_error=result.evaluation.posterior_location_pct_error,
                post_seconds=result.diagnostics.seconds, converged=bool(result.diagnostics.converged),
                temperature=result.posterior.temperature, coverage=cover, ranks=ranks)


def _pairs_used(result) -> int | None:
    """Reference pairs the result's model used (None when the pipeline reports none)."""
    ref = result.references
    if ref is None:
        return None
    return int(ref["pairs_used"] if isinstance(ref, dict) else ref.pairs_used)


def _truth(scene: Scene) -> dict:
    g = scene.ground_truth
    x, y, z = g.location_m
    return {"x": x, "y": y, "z": z, "yaw": g.yaw_rad, "focal_length_px": g.focal_length_px,
            "pitch": g.extra.get("pitch_rad"), "roll": g.extra.get("roll_rad"), "distance_m": float(np.hypot(x, z))}


def _hdi(values: np.ndarray, prob: float) -> tuple[float, float]:
    """Shortest interval holding ``prob`` of the values."""
    v = np.sort(values)
    n = len(v)
    k = max(1, int(np.ceil(prob * n)))
    if k >= n:
        return float(v[0]), float(v[-1])
    widths = v[k - 1:] - v[:n - k + 1]
    i = int(np.argmin(widths))
    return float(v[i]), float(v[i + k - 1])


def calibration_of(draws: dict, truth: dict) -> tuple[dict, dict]:
    """Whether each true value lies in the 50 % and 90 % HDI, and its rank (fraction of draws
    below it) — yaw measured as a wrapped offset from the posterior's circular mean.

    Parameters
    ----------
    draws : name → (n,) posterior draws (x, y, z, yaw, focal_length_px, distance_m)
    truth : name → true value
    """
    cover, ranks = {}, {}
    for name, col in draws.items():
        col = np.asarray(col, float)
        t = truth.get(name)
        if t is None:
            continue
        if name == "yaw":
            centre = np.arctan2(np.mean(np.sin(col)), np.mean(np.cos(col)))
            col, t = wrap_angle(col - centre), float(wrap_angle(t - centre))
        if np.ptp(col) == 0:  # a fixed parameter
            continue
        cover[name] = {f"{int(100 * p)}": bool(lo <= t <= hi) for p in CREDIBLE_LEVELS
                       for lo, hi in [_hdi(col, p)]}
        ranks[name] = float(np.mean(col < t))
    return cover, ranks


def _err(params, scene) -> float:
    return float(location_percentage_error(np.asarray(params)[:3], scene.ground_truth.location_m))


def _record(sid, scene, estimator, **kw) -> dict:
    g = scene.ground_truth.extra
    return {"scene": sid, "tier": g["tier"], "setting": g["setting"], "estimator": estimator, **kw}


def _run_scene(sid: str, scene: Scene, config: BenchConfig, seed: int, temperature: float | None,
               pairs: bool, sweep: bool, baseline: bool, say) -> list[dict]:
    from .crb import cramer_rao_scene

    recs = []
    nt, n_refs = config.n_target, len(scene.references)
    all_refs = tuple(range(n_refs))
    truth = _truth(scene)

    # the limit
    for name, refs in (("crb-target", False), ("crb-refs", True)):
        c = cramer_rao_scene(scene, n_annotations=nt, references=refs)
        recs.append(_record(sid, scene, name, n_target=nt, n_refs=n_refs if refs else 0,
                            error=c.median_pct, rmse=c.rmse_pct))
    crb_t, crb_r = recs[0]["error"], recs[1]["error"]

    # the paper's method
    runs = [(nt, all_refs)] + ([(config.n_target_baseline, ())] if baseline else [])
    for n_ann, refs in runs:
        res = _estimate(variant(scene, n_ann, refs), "paper", "paper", seed,
                        restarts=config.paper_restarts)
        recs.append(_record(sid, scene, "paper", model="paper", preset="paper", n_target=n_ann,
                            n_refs=len(refs), error=res.evaluation.location_pct_error,
                            seconds=res.map.seconds, restarts=config.paper_restarts or 200,
                            pairs_used=_pairs_used(res)))
    paper_seconds = recs[2]["seconds"]

    # the peer
    from .peers import estimate_p4pf, poselib_available

    if poselib_available():
        p = estimate_p4pf(variant(scene, nt, ()))
        recs.append(_record(sid, scene, "p4pf", n_target=nt, n_refs=0, error=_err(p.params, scene),
                            seconds=p.seconds, fallback=p.info["fallback"]))

    # ours
    for model in MODELS:
        T = temperature if model == "paper" else None
        runs = [(nt, k) for k in config.ref_counts] + [(config.n_target_baseline, 0)]
        for n_ann, k in runs:
            post = n_ann == nt and k in config.posterior_ref_counts
            res = _estimate(variant(scene, n_ann, all_refs[:k]), model, "default", seed, posterior=post,
                            temperature=T, sampling=config.sampler)
            rec = _record(sid, scene, f"ours-{model}", model=model, preset="default", n_target=n_ann,
                          n_refs=k, error=res.evaluation.location_pct_error, seconds=res.map.seconds,
                          paper_seconds=paper_seconds, pairs_used=_pairs_used(res),
                          handedness_ok=res.map.handedness == scene.ground_truth.extra["handedness"])
            if post:
                rec.update(_posterior_fields(res, truth))
            recs.append(rec)

    if config.camera_studies:
        from .studies import camera_records

        recs += camera_records(sid, scene, config, seed, truth)

    if pairs:  # Fig. 11: each pair of references alone
        from ..core.metrology import aggregate_references

        for i, j in combinations(all_refs, 2):
            v = variant(scene, nt, (i, j))
            kinds = "+".join(sorted(scene.references[r].measure for r in (i, j)))
            skipped = aggregate_references(v, Camera.from_scene(v)).pairs_used == 0
            for model in MODELS:  # "skipped" is the paper aggregation's verdict, for both models
                res = _estimate(v, model, "default", seed)
                recs.append(_record(sid, scene, f"pair-{model}", model=model, n_target=nt, n_refs=2,
                                    pair=kinds, error=res.evaluation.location_pct_error, skipped=bool(skipped)))

    if sweep:  # the paper model's posterior for several (σ, T), with all references
        v = variant(scene, nt, all_refs)
        for sigma, T in config.paper_posterior_grid:
            res = _estimate(v, "paper", "default", seed, posterior=True, temperature=T,
                            sampling=config.sampler, sigma=sigma)
            recs.append(_record(sid, scene, "sweep-paper", model="paper", n_target=nt, n_refs=n_refs,
                                sigma=sigma, map_error=res.evaluation.location_pct_error,
                                **_posterior_fields(res, truth)))
    say(f"{sid}: paper {recs[2]['error']:.1f} %, crb {crb_t:.2f}/{crb_r:.2f} %")
    return recs


def run_bench(config: BenchConfig | str = "quick", seed: int = 0, *, temperature: float | None = None,
              progress=None, progress_bar: bool = False) -> dict:
    """Run the benchmark; returns the JSON-able document (records, summary, environment).

    Parameters
    ----------
    config : a :class:`BenchConfig` or the name of one of :data:`CONFIGS`
    seed : the seed of the scenes and of every estimator
    temperature : the paper model's posterior temperature (default: the package's)
    progress : callable taking a line of text (one per scene), or None
    progress_bar : show a bar of the scenes on standard error (the lines then print above it)
    """
    if isinstance(config, str):
        if config not in CONFIGS:
            raise ValueError(f"config: expected one of {list(CONFIGS)}, got {config!r}")
        config = CONFIGS[config]
    from ..inference.progress import progress_bar as _bar

    t0, c0 = time.perf_counter(), time.process_time()
    scenes = bench_scenes(config, seed)
    seen: dict[str, int] = {}
    records = []
    with _bar(progress_bar, len(scenes), desc="bench scenes", unit="scene") as bar:
        def say(line: str) -> None:
            if progress is not None:
                with bar.external_write_mode(file=sys.stderr):  # above the bar, not through it
                    progress(line)

        for sid, scene in scenes:
            tier = scene.ground_truth.extra["tier"]
            seen[tier] = seen.get(tier, 0) + 1
            records += _run_scene(sid, scene, config, seed, temperature,
                                  pairs=seen[tier] <= config.pair_scenes,
                                  sweep=bool(config.paper_posterior_grid) and seen[tier] <= config.sweep_scenes,
                                  baseline=seen[tier] <= config.paper_baseline_scenes, say=say)
            bar.update(1)
    if config.exact_scenes:
        from .studies import exact_reference_records

        records += exact_reference_records(config.exact_scenes, seed, say)
    from .report import summarise

    doc = {"format": BENCH_FORMAT, "version": __version__, "seed": seed, "config": config.to_dict(),
           "paper_temperature_override": temperature, "seconds": time.perf_counter() - t0,
           "cpu_seconds": time.process_time() - c0,
           "environment": {"python": sys.version.split()[0], "platform": platform.platform(),
                           "numpy": np.__version__},
           "records": records}
    doc["summary"] = summarise(doc)
    return doc


def plain(o):
    """JSON-able copy: numpy to Python, non-finite numbers (an infinite bound) to None."""
    if isinstance(o, dict):
        return {str(k): plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple, np.ndarray)):
        return [plain(v) for v in o]
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not np.isfinite(o):
        return None
    return o
