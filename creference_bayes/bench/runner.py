"""The benchmark (docs/studies/benchmark.md, "What was run"): the paper's method, a peer, our models
and the Cramér–Rao bound on the same simulated scenes in one process, in four sizes
(``creference bench --quick|--full|--frames|--sbc``; command line :mod:`creference_bayes.cli.bench`,
``--sbc`` is :mod:`.sbc`). Tables: :mod:`.report`; figures: :mod:`.figures`.

One-target scenes (``quick``, ``full``) have 13 target annotations and 5 references; estimators
get the first 5 annotations (the paper's §7.1) and the first k references. Estimators: ``paper``
(preset ``paper``, 5 references; fewer restarts in ``quick``, labelled so), ``p4pf``
(:mod:`.peers`), ``ours-paper`` and ``ours-metrology`` (MAP with k = 0…5 references, posterior
for the configured k), ``crb-target`` and ``crb-refs`` (:mod:`.crb`), the camera studies
(``-nohorizon`` with its bound, ``-flatfocal``), the same-human-time comparison (Analysis 2),
every pair of references alone (Fig. 11), a calibration sweep of the paper model over σ and T,
and noise-free scenes with 20 exact references (``exact-metrology``).

Several targets (``frames``): street scenes of 3–15 objects (:data:`FRAME_TIERS`), every object
estimated jointly (MAP and posterior) and alone (MAP), beside the scene's Bayesian bound.
"""

from __future__ import annotations

import platform
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from itertools import combinations

import numpy as np

from .. import __version__
from ..io.result import hdi
from ..io.scene import Scene, parse_scene
from .simulate import SETTINGS, TIERS, NoiseTier, simulate_scene

__all__ = ["BenchConfig", "CONFIGS", "FRAME_TIERS", "bench_scenes", "street_scene", "variant", "calibration_of", "run_bench", "plain"]

BENCH_FORMAT = "creference-bench/1"
CREDIBLE_LEVELS = (0.5, 0.9)
MODELS = ("paper", "metrology")
#: The camera studies' estimators and the estimate options that make them (the first on the scene
#: without its horizon).
CAMERA_STUDIES = {"ours-metrology-nohorizon": {}, "ours-metrology-flatfocal": {"focal_prior": "none"}}
#: Noise of the scenes of several targets: 2 px Gaussian corners, and 5 px heavy-tailed ones
#: (Student-t, 3 degrees of freedom).
FRAME_TIERS = {"low": NoiseTier("low", 2.0, 5.0, "10%"), "high": NoiseTier("high", 5.0, 10.0, "40%", 3.0)}


@dataclass(frozen=True)
class BenchConfig:
    """How much of the benchmark runs.

    Attributes
    ----------
    name : ``quick``, ``full``, ``frames`` or ``frames-full``
    scenes : ((tier, setting, count), …) one-target scenes simulated per tier and setting
    ref_counts : numbers of references for the MAP of our models (Fig. 10)
    posterior_ref_counts : numbers of references for which our posteriors are sampled
    paper_restarts : basin-hopping restarts of the ``paper`` preset (None: the paper's 200)
    paper_baseline_scenes : scenes per tier on which the ``paper`` preset also runs on 10 target
        annotations without references (Analysis 2)
    pair_scenes : scenes per tier on which every reference pair is run alone (Fig. 11)
    paper_posterior_grid : ((σ px, T), …) of the paper model's posterior in the calibration sweep
    sweep_scenes : scenes per tier in that sweep
    sampler : sampler settings (:class:`~creference_bayes.inference.sampler.SamplerSettings` fields)
    n_target, n_target_baseline : target annotations the estimators get (5) and the baseline (10)
    camera_studies : also run the camera studies (module docstring)
    exact_scenes : noise-free scenes with 20 exact references, estimated with and without them
    frame_counts, frames_per_count, frame_tiers : scenes of several targets: objects per scene,
        scenes per count and tier, tiers (:data:`FRAME_TIERS`)
    cameras : where every scene's camera comes from: ``setting`` (each setting's ranges) or
        ``real`` (:data:`~.simulate.REAL_CAMERAS`, :func:`~.simulate.draw_camera`)
    """

    name: str
    scenes: tuple[tuple[str, str, int], ...] = ()
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
    frame_counts: tuple[int, ...] = ()
    frames_per_count: int = 0
    frame_tiers: tuple[str, ...] = ()
    cameras: str = "setting"

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
    # the documented run (docs/studies/benchmark.md)
    "full": BenchConfig(
        name="full", scenes=_grid({t: (5, 3) for t in TIERS}),
        ref_counts=(0, 1, 2, 3, 4, 5), posterior_ref_counts=(0, 2, 5), paper_restarts=None,
        paper_baseline_scenes=2, pair_scenes=3, sweep_scenes=8,
        paper_posterior_grid=((100.0, 1.0), (100.0, 0.1), (2.0, 1.0), (2.0, 2.0), (2.0, 3.0), (2.0, 4.0),
                              (3.0, 3.0), (3.0, 4.0)),
        sampler={"min_ess": 400}, exact_scenes=10),
    "frames": BenchConfig(name="frames", frame_counts=(3, 6), frames_per_count=1, frame_tiers=("low",),
                          sampler={"min_ess": 200, "max_steps": 2000}, camera_studies=False),
    "frames-full": BenchConfig(name="frames-full", frame_counts=(3, 8, 15), frames_per_count=4,
                               frame_tiers=("low", "high"), sampler={"min_ess": 400}, camera_studies=False),
}


# ------------------------------------------------------------------------------------------------
# scenes


def _parse(d: dict) -> Scene:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def bench_scenes(config: BenchConfig, seed: int = 0) -> list[tuple[str, Scene]]:
    """The bench's one-target scenes, tier by tier, indoor and outdoor interleaved in proportion
    (so the first few scenes of a tier mix both settings); deterministic for ``seed``; the
    references' formats cycle so that every two scenes cover all ten once."""
    tier_names, setting_names = list(TIERS), list(SETTINGS)
    order = []
    for tier, setting, n in config.scenes:
        order += [(tier_names.index(tier), (i + 0.5) / n, setting_names.index(setting), i) for i in range(n)]
    out = []
    for k, (t, _, s, i) in enumerate(sorted(order)):
        d = simulate_scene(np.random.default_rng([seed, t, s, i]), setting=setting_names[s], tier=tier_names[t],
                           format_offset=5 * k, cameras=config.cameras)
        out.append((f"{tier_names[t]}-{setting_names[s]}-{i:02d}", _parse(d)))
    return out


def variant(scene: Scene, n_target: int, references) -> Scene:
    """``scene`` with each target's first ``n_target`` annotations and the given references (indices)."""
    refs = tuple(references)
    return replace(scene, targets=tuple(replace(t, dimension_lines=t.dimension_lines[:n_target]) for t in scene.targets),
                   references=tuple(scene.references[i] for i in refs),
                   reference_targets=tuple(scene.reference_targets[i] for i in refs))


# ------------------------------------------------------------------------------------------------
# estimators


def _estimate(scene: Scene, model: str, preset: str, seed, *, posterior: bool = False, sampling: dict | None = None,
              **options):
    """The package's own :func:`~creference_bayes.pipeline.estimate` (MAP, and the posterior when asked)."""
    from ..pipeline import estimate

    return estimate(scene, preset=preset, model=model, seed=seed, posterior=posterior, sampling=sampling or None,
                    keep_draws=0, **options)


def _truth(scene: Scene) -> dict:
    g, t = scene.ground_truth, scene.targets[0].ground_truth
    x, y, z = t["location_m"]
    return {"x": x, "y": y, "z": z, "yaw": t["yaw_rad"], "focal_length_px": g["focal_length_px"],
            "pitch": g["pitch_rad"], "roll": g["roll_rad"], "distance_m": float(np.hypot(x, z))}


def calibration_of(draws: dict, truth: dict) -> tuple[dict, dict]:
    """Whether each true value lies in the 50 % and 90 % HDI, and its rank (fraction of draws
    below it) — yaw measured as a wrapped offset from the posterior's circular mean.

    Parameters
    ----------
    draws : name → (n,) posterior draws (x, y, z, yaw, focal_length_px, pitch, roll, distance_m)
    truth : name → true value
    """
    cover, ranks = {}, {}
    for name, col in draws.items():
        col, t = np.asarray(col, float), truth.get(name)
        if t is None:
            continue
        if name == "yaw":
            centre = np.arctan2(np.mean(np.sin(col)), np.mean(np.cos(col)))
            col, t = (col - centre + np.pi) % (2 * np.pi) - np.pi, float((t - centre + np.pi) % (2 * np.pi) - np.pi)
        if np.ptp(col) == 0:  # a fixed parameter
            continue
        cover[name] = {f"{int(100 * p)}": bool(lo <= t <= hi) for p in CREDIBLE_LEVELS for lo, hi in hdi(col[:, None], p)}
        ranks[name] = float(np.mean(col < t))
    return cover, ranks


def _fields(res, scene: Scene) -> dict:
    """A one-target estimate's record fields: MAP error and time, handedness, the paper model's
    pairs used, and with a posterior its mean's error, time, convergence and calibration."""
    from ..models.contract import OBJECT_REPORT, object_report

    d = res.to_dict()
    o = d["objects"][0]
    refs = d["references"]
    out = {"error": o["evaluation"]["location_pct_error"], "seconds": d["map_info"]["seconds"],
           "handedness_ok": o["handedness"] == scene.targets[0].ground_truth["handedness"],
           "pairs_used": refs["objects"][0]["pairs_used"] if "objects" in refs else None}
    if res.draws is not None:
        cams = res.draws.cameras.reshape(-1, 5)
        table = object_report(cams, res.draws.objects.reshape(len(cams), -1, 7))[:, 0]
        draws = {k: table[:, OBJECT_REPORT.index(k)] for k in ("x", "y", "z", "yaw", "distance_m")}
        draws.update({k: cams[:, j] for j, k in enumerate(("focal_length_px", "pitch", "roll"))
                      if k in d["camera"]["free"]})  # pitch and roll derived from a horizon: not checked
        cover, ranks = calibration_of(draws, _truth(scene))
        out.update(post_error=o["evaluation"]["posterior_location_pct_error"], post_seconds=d["diagnostics"]["seconds"],
                   converged=bool(res.converged), temperature=d["provenance"]["temperature"], coverage=cover,
                   ranks=ranks)
    return out


def _record(sid, scene, estimator, **kw) -> dict:
    g = scene.ground_truth
    return {"scene": sid, "tier": g["tier"], "setting": g["setting"], "estimator": estimator, **kw}


def _bounds(sid, scene, nt, suffix="") -> list[dict]:
    """The Cramér–Rao bound with the target only and with every reference (the data alone)."""
    from .crb import measurement_log_sd, scene_bound

    tier = TIERS[scene.ground_truth["tier"]]
    base = variant(scene, nt, range(len(scene.references)))
    out = []
    for name, refs in (("crb-target", False), ("crb-refs", True)):
        b = scene_bound(base, tier.target_px, reference_log_sd=measurement_log_sd(tier.measurement) if refs else None,
                        reference_sigma_px=tier.reference_px, priors=False)
        out.append(_record(sid, scene, name + suffix, n_target=nt, n_refs=len(scene.references) if refs else 0,
                           error=float(b.median_pct[0]), rmse=float(b.rmse_pct[0])))
    return out


def _run_scene(sid: str, scene: Scene, config: BenchConfig, seed: int, temperature: float | None,
               pairs: bool, sweep: bool, baseline: bool, say) -> list[dict]:
    nt, n_refs = config.n_target, len(scene.references)
    all_refs = tuple(range(n_refs))
    recs = _bounds(sid, scene, nt)

    # the paper's method
    for n_ann, refs in [(nt, all_refs)] + ([(config.n_target_baseline, ())] if baseline else []):
        res = _estimate(variant(scene, n_ann, refs), "paper", "paper", seed, restarts=config.paper_restarts)
        f = _fields(res, scene)
        recs.append(_record(sid, scene, "paper", model="paper", preset="paper", n_target=n_ann, n_refs=len(refs),
                            error=f["error"], seconds=f["seconds"], restarts=config.paper_restarts or 200,
                            pairs_used=f["pairs_used"]))
    paper_seconds = recs[2]["seconds"]

    from .peers import estimate_p4pf, poselib_available

    if poselib_available():
        p = estimate_p4pf(variant(scene, nt, ()))
        recs.append(_record(sid, scene, "p4pf", n_target=nt, n_refs=0, seconds=p.seconds, fallback=p.info["fallback"],
                            error=p.location_error(scene.targets[0].ground_truth["location_m"])))

    for model in MODELS:  # ours
        for n_ann, k in [(nt, k) for k in config.ref_counts] + [(config.n_target_baseline, 0)]:
            post = n_ann == nt and k in config.posterior_ref_counts
            res = _estimate(variant(scene, n_ann, all_refs[:k]), model, "default", seed, posterior=post,
                            temperature=temperature if model == "paper" else None, sampling=config.sampler)
            recs.append(_record(sid, scene, f"ours-{model}", model=model, preset="default", n_target=n_ann, n_refs=k,
                                paper_seconds=paper_seconds, **_fields(res, scene)))

    if config.camera_studies:  # the metrology model without the horizon and with a flat focal prior
        recs += _bounds(sid, replace(scene, horizon=None), nt, "-nohorizon")
        for estimator, options in CAMERA_STUDIES.items():
            base = replace(scene, horizon=None) if estimator.endswith("nohorizon") else scene
            for k in sorted({0, n_refs}):
                res = _estimate(variant(base, nt, all_refs[:k]), "metrology", "default", seed,
                                posterior=k in config.posterior_ref_counts, sampling=config.sampler, **options)
                recs.append(_record(sid, scene, estimator, model="metrology", preset="default", n_target=nt, n_refs=k,
                                    **_fields(res, scene)))

    if pairs:  # Fig. 11: each pair of references alone; "skipped" is the paper aggregation's verdict
        for i, j in combinations(all_refs, 2):
            v = variant(scene, nt, (i, j))
            kinds = "+".join(sorted(scene.references[r].measure for r in (i, j)))
            skipped = None
            for model in MODELS:
                f = _fields(_estimate(v, model, "default", seed), scene)
                skipped = f["pairs_used"] == 0 if skipped is None else skipped
                recs.append(_record(sid, scene, f"pair-{model}", model=model, n_target=nt, n_refs=2, pair=kinds,
                                    error=f["error"], skipped=bool(skipped)))

    if sweep:  # the paper model's posterior for several (σ, T), with all references
        v = variant(scene, nt, all_refs)
        for sigma, T in config.paper_posterior_grid:
            f = _fields(_estimate(v, "paper", "default", seed, posterior=True, temperature=T, sampling=config.sampler,
                                  sigma=sigma), scene)
            recs.append(_record(sid, scene, "sweep-paper", model="paper", n_target=nt, n_refs=n_refs, sigma=sigma,
                                map_error=f.pop("error"), **{k: v for k, v in f.items() if k != "seconds"}))
    say(f"{sid}: paper {recs[2]['error']:.1f} %, crb {recs[0]['error']:.2f}/{recs[1]['error']:.2f} %")
    return recs


def _exact_records(n: int, seed: int, say, cameras: str = "setting") -> list[dict]:
    """Noise-free outdoor scenes as annotation tools store them (0.01 px: targets 25–45 m away,
    pitch, roll up to 5°, an off-centre principal point, 13 exact annotations and 20 exact
    single-valued references), the default estimator's MAP with and without the references
    (exact references must help, never hurt)."""
    recs = []
    for i in range(n):
        scene = _parse(simulate_scene(np.random.default_rng([seed, 99, i]), setting="outdoor", tier="none",
                                      n_references=20, principal_offset=0.08, roll_deg=5.0,
                                      distance_range=(25.0, 45.0), single_values=True, cameras=cameras))
        sid, nt, errors = f"exact-outdoor-{i:02d}", len(scene.targets[0].dimension_lines), {}
        for k in (0, len(scene.references)):
            errors[k] = _fields(_estimate(variant(scene, nt, range(k)), "metrology", "default", seed), scene)["error"]
            recs.append(_record(sid, scene, "exact-metrology", n_target=nt, n_refs=k, error=errors[k]))
        say(f"{sid}: exact references {errors}")
    return recs


def street_scene(tier: str, n_objects: int, k: int, seed: int = 0, cameras: str = "setting",
                 sizes: str = "prior") -> Scene:
    """The bench's ``k``-th street scene of ``n_objects`` targets in a :data:`FRAME_TIERS` tier: 5
    sets of dimension lines per object, no references, no focal length and no horizon given, sizes
    left to the class priors (``sizes="known"``: given, a catalogue's); deterministic for ``seed``."""
    return _parse(simulate_scene([seed, n_objects, k, len(tier)], setting="street", tier=FRAME_TIERS[tier],
                                 n_objects=n_objects, n_references=0, n_target_annotations=5, sizes=sizes,
                                 horizon="none", cameras=cameras))


def _frame_records(config: BenchConfig, seed: int, say, tick) -> list[dict]:
    """Scenes of several targets: every object jointly, alone, and its bound (module docstring)."""
    from .crb import scene_bound

    recs = []
    for tier in config.frame_tiers:
        noise = FRAME_TIERS[tier]
        for n in config.frame_counts:
            for k in range(config.frames_per_count):
                scene = street_scene(tier, n, k, seed, cameras=config.cameras)
                sid = f"frame-{tier}-{n}-{k}"
                d = _estimate(scene, "metrology", "default", k, posterior=True, sampling=config.sampler).to_dict()
                bound = scene_bound(scene, noise.target_px)
                for i, (t, o) in enumerate(zip(scene.targets, d["objects"])):
                    alone = _estimate(replace(scene, targets=(t,)), "metrology", "default", k).to_dict()
                    ev = o.get("evaluation", {})
                    x, _, z = t.ground_truth["location_m"]
                    recs.append(_record(sid, scene, "frame", n_objects=len(scene.targets), frame=k,
                                        target=t.id, cls=t.cls, distance_m=float(np.hypot(x, z)),
                                        error=ev["location_pct_error"], post_error=ev.get("posterior_location_pct_error"),
                                        alone_error=alone["objects"][0]["evaluation"]["location_pct_error"],
                                        crb=float(bound.median_pct[i]), in_hdi90=bool(ev.get("distance_in_hdi")),
                                        converged=bool((d["diagnostics"] or {}).get("converged")),
                                        seconds=d["map_info"]["seconds"], post_seconds=(d["diagnostics"] or {}).get("seconds")))
                say(f"{sid}: {d['seconds']:.1f} s, converged {(d['diagnostics'] or {}).get('converged')}")
                tick()
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
    n_frames = len(config.frame_tiers) * len(config.frame_counts) * config.frames_per_count
    seen: dict[str, int] = {}
    records = []
    with _bar(progress_bar, len(scenes) + n_frames, desc="bench scenes", unit="scene") as bar:
        def say(line: str) -> None:
            if progress is not None:
                with bar.external_write_mode(file=sys.stderr):  # above the bar, not through it
                    progress(line)

        for sid, scene in scenes:
            tier = scene.ground_truth["tier"]
            seen[tier] = seen.get(tier, 0) + 1
            records += _run_scene(sid, scene, config, seed, temperature, pairs=seen[tier] <= config.pair_scenes,
                                  sweep=bool(config.paper_posterior_grid) and seen[tier] <= config.sweep_scenes,
                                  baseline=seen[tier] <= config.paper_baseline_scenes, say=say)
            bar.update(1)
        records += _exact_records(config.exact_scenes, seed, say, config.cameras)
        records += _frame_records(config, seed, say, lambda: bar.update(1))
    from .report import summarise

    doc = {"format": BENCH_FORMAT, "version": __version__, "seed": seed, "config": config.to_dict(),
           "paper_temperature_override": temperature, "seconds": time.perf_counter() - t0,
           "cpu_seconds": time.process_time() - c0,
           "environment": {"python": sys.version.split()[0], "platform": platform.platform(), "numpy": np.__version__},
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
