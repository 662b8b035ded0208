"""Calibration of data-rich one-target scenes whose reference segments are drawn with noise, read
two ways (docs/studies/method.md, "A drawn reference's end points").

Scenes of the simulator's crowds (``creference_bayes.bench.simulate.CROWDS``): ``light`` (2 px
corners, 5 px reference end points, log-sd 0.1) and ``heavy`` (5 px corners, 10 px end points,
log-sd 0.55, 12 % outliers); each scene has 13 sets of dimension lines, 20 references cycling
through the paper's ten formats (direct and relative, values and ranges, lengths, widths and
distances; with ``--references relative`` only the relative values, lengths and widths, as in issue
66), the exact horizon, the focal length unknown; indoor and outdoor alternate. Every scene is
estimated once per ``--readings`` (the metrology model's ``line_reading``, or ``learned``: the
marginal reading with the crowd's segment floor fitted to the run's other scenes, as ``creference
batch`` hands it; or ``tail``: the marginal reading with the crowd's reference tail chosen from
the run's other scenes, a first pass of MAPs, as ``creference batch`` chooses it), with the same seed. Per crowd and reading: the 90 % HDI's coverage of the
target's distance and of the focal length, the mean quantile of each truth in its posterior, the
share of truths above the posterior median, the median HDI width over the distance, the MAP's and
posterior mean's location errors, and CPU seconds; under the table, 95 % bootstrap intervals over
scenes.

Usage::

    python examples/reference_reading_study.py --n 100 --crowds light --out rr_light
    python examples/reference_reading_study.py --n 100 --crowds heavy --out rr_heavy
    python examples/reference_reading_study.py --n 100 --crowds light --references relative --out rr_relative
    python examples/reference_reading_study.py --report --out rr_light
    python examples/reference_reading_study.py --monte-carlo     # the reading alone (no estimates)
    python examples/reference_reading_study.py --bench --out rr_bench   # the bench's tiers
    python examples/reference_reading_study.py --bench --seeds 1,2 --out rr_bench12   # more of its scenes
    python examples/reference_reading_study.py --populations light,heavy,low,medium,high --n 40
    python examples/reference_reading_study.py --timing          # CPU of one evaluation, each reading
    python examples/reference_reading_study.py --n 40 --crowds light --readings marginal,learned --out rr_floor
    python examples/reference_reading_study.py --bench --readings linear,marginal,learned --out rr_bench
    python examples/reference_reading_study.py --n 100 --crowds light,heavy --readings marginal,tail --out rr_tail

``--bench`` estimates the 32 one-target scenes of ``creference bench --full`` (tiers none, low,
medium and high: reference end points off by 0, 5, 10 and 30 px) from 5 sets of dimension lines
and 5 references, as the bench's ``ours-metrology`` estimator with 5 references, each reading in
turn, and tabulates the MAP's and the posterior mean's location errors and the 90 % HDI's coverage
per tier, and the per-scene difference of the posterior mean's error between the readings (with
a bootstrap interval); ``--seeds`` takes the scenes the bench draws with other seeds as well.

``--populations`` reads the simulator's own reference segments (its objects' edges and distance
lines, of a crowd of ``CROWDS`` or a bench tier) at the true camera with the model's σ_line, each
way (``learned``: with the floor the population's other scenes teach), and tabulates where the
true error falls in what each reading states, by the drawn segment's length over σ_line. With
``--bench``, each tier's scenes are the data set a ``learned`` floor is fitted to.

``--monte-carlo`` reads, at a known camera, 2000 ground segments a band (any direction, 0.3–10 m,
log-uniform) 3–8 m and 30–60 m away, drawn with 2 and 5 px of end-point noise, each way, and
prints per band the error of the mean reading (median and sd, log-length), the stated sd (rms),
and where the truths fall in the stated error (share in the central 80 %; the mean of their
quantiles).

Records go to ``OUT/records.jsonl`` (one line per estimate; a run continues where a previous one
into the same folder stopped), the table to ``OUT/table.md``. About 3–4 s of CPU per estimate.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import CROWDS, FORMATS, simulate_scene
from creference_bayes.evaluation.reliability import cluster_bootstrap
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.contract import O_X, O_Z
from creference_bayes.models.metrology import LINE_READINGS
from creference_bayes.pipeline import estimate
from creference_bayes.workflows.batch import segment_floors

SETTINGS = ("indoor", "outdoor")
#: The readings a run compares: the model's, and ``learned``: the marginal one with the crowd's
#: segment floor learnt from the run's other scenes (the population's, or the bench tier's), as
#: ``creference batch`` hands it (``read_floor_px``, :func:`~creference_bayes.workflows.batch.segment_floors`).
LEARNED = "learned"
#: ... and ``tail``: the marginal reading with the crowd's reference tail (``ref_dof``) chosen from the
#: run's other scenes' first pass, as ``creference batch`` chooses it (:class:`~creference_bayes.workflows.batch.dataset.TailPool`).
TAIL = "tail"
READINGS = (*LINE_READINGS, LEARNED, TAIL)
#: The references' formats (indices of FORMATS): all ten, or the relative values only.
REFERENCES = {"mixed": None, "relative": tuple(i for i, (_, mode, rng) in enumerate(FORMATS) if mode == "relative" and not rng)}


def scene(crowd: str, k: int, references: str = "mixed"):
    """The k-th scene of a crowd (module docstring); indoor for even k, outdoor for odd."""
    d = simulate_scene(np.random.default_rng([66, list(CROWDS).index(crowd), k]), setting=SETTINGS[k % 2],
                       tier=crowd, n_target_annotations=13, n_references=20, format_offset=5 * k,
                       formats=REFERENCES[references])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def record(sc, result, crowd: str, k: int, reading: str, seconds: float, references: str = "mixed") -> dict:
    """What one estimate says about its truth (module docstring)."""
    cams, objs = result.draws.cameras, result.draws.objects[..., 0, :]
    d = result.to_dict()
    x, _, z = sc.targets[0].ground_truth["location_m"]
    truth = {"distance_m": float(np.hypot(x, z)), "focal_length_px": float(sc.ground_truth["focal_length_px"])}
    draws = {"distance_m": np.hypot(objs[..., 0], objs[..., 1]).ravel(), "focal_length_px": cams[..., 0].ravel()}
    hdis = {"distance_m": d["objects"][0]["posterior"]["hdi"]["distance_m"],
            "focal_length_px": d["camera"]["posterior"]["hdi"]["focal_length_px"]}
    o = d["objects"][0]
    return {"crowd": crowd, "scene": k, "setting": SETTINGS[k % 2], "reading": reading, "references": references,
            **{f"quantile_{q}": float(np.mean(draws[q] < truth[q])) for q in truth},
            **{f"covered_{q}": bool(hdis[q][0] <= truth[q] <= hdis[q][1]) for q in truth},
            "hdi_over_distance": (hdis["distance_m"][1] - hdis["distance_m"][0]) / truth["distance_m"],
            "map_error": o["evaluation"]["location_pct_error"], "post_error": o["evaluation"]["posterior_location_pct_error"],
            "converged": bool(result.converged), "seconds": seconds}


def reading_options(reading: str, floor: dict | None, tail: dict | None = None) -> dict:
    """The estimate's options of a reading of :data:`READINGS` (``floor``: what
    :func:`~creference_bayes.workflows.batch.segment_floors` hands the scene, or None; ``tail``:
    the crowd's tail the other scenes favour, :meth:`~creference_bayes.workflows.batch.dataset.TailPool.estimate`)."""
    if reading == TAIL:
        return {"line_reading": "marginal", **({"ref_dof": tail["dof"]} if tail else {})}
    if reading != LEARNED:
        return {"line_reading": reading}
    return {"line_reading": "marginal", **({"read_floor_px": floor["floor_px"]} if floor else {})}


def tails(scenes: list, cache: Path) -> list[dict | None]:
    """Each scene's crowd tail from the other scenes, as ``creference batch`` chooses it: a first
    pass (a MAP each, seeded by the scene's index), each read (:func:`~creference_bayes.workflows.batch.dataset.read_tail`),
    pooled leaving the scene out. Kept in ``cache`` (JSON) for a rerun of the same scenes."""
    from creference_bayes.pipeline import rebuild_model, result_draws
    from creference_bayes.workflows.batch.dataset import LAPLACE_DRAWS, TailPool, read_tail

    if cache.exists() and len(got := json.loads(cache.read_text())) == len(scenes):
        return got
    readings, own = {}, None
    for k, sc in enumerate(scenes):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = estimate(sc, seed=k, posterior=False).to_dict()
            model = rebuild_model(d, sc)
            cams, objs, _ = result_draws(d, model, n=LAPLACE_DRAWS, seed=0)
        if (t := read_tail(model, cams, objs)) is not None:
            readings[str(k)], own = t, model.ref_dof
    pool = TailPool(readings, own) if readings else None
    got = [pool and pool.estimate(str(k)) for k in range(len(scenes))]
    cache.write_text(json.dumps(got))
    return got


def run(args) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "records.jsonl"
    done = {(r["crowd"], r["scene"], r["reading"]) for r in _load(path)}
    floors = {crowd: segment_floors([scene(crowd, k, args.references) for k in range(args.n)])
              if LEARNED in args.readings else [None] * args.n for crowd in args.crowds}
    tail = {crowd: tails([scene(crowd, k, args.references) for k in range(args.n)],
                         out / f"tails_{crowd}_{args.references}_{args.n}.json")
            if TAIL in args.readings else [None] * args.n for crowd in args.crowds}
    with open(path, "a") as f:
        for k in range(args.n):
            for crowd in args.crowds:
                sc = None
                for reading in args.readings:
                    if (crowd, k, reading) in done:
                        continue
                    sc = sc or scene(crowd, k, args.references)
                    t0 = time.process_time()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        r = estimate(sc, seed=k, sampling={"min_ess": args.min_ess}, keep_draws=0,
                                     **reading_options(reading, floors[crowd][k], tail[crowd][k]))
                    rec = record(sc, r, crowd, k, reading, time.process_time() - t0, args.references)
                    if reading == TAIL:
                        rec["ref_dof"] = r.to_dict()["provenance"]["options"].get("ref_dof")
                    f.write(json.dumps(rec) + "\n")
                    f.flush()
                    if not args.quiet:
                        print(f"{crowd} {k} {reading}: distance q {rec['quantile_distance_m']:.2f} "
                              f"covered {rec['covered_distance_m']}, focal q {rec['quantile_focal_length_px']:.2f} "
                              f"covered {rec['covered_focal_length_px']}, {rec['seconds']:.1f} s", flush=True)


def _load(path: Path) -> list[dict]:
    return [json.loads(line) for line in open(path)] if path.exists() else []


def table(records: list[dict]) -> str:
    """One row per crowd, setting (and both) and reading; bootstrap intervals under it."""
    head = ("| crowd | setting | reading | estimates | distance: 90 % HDI covers | mean quantile | truth above the median "
            "| focal length: 90 % HDI covers | mean quantile | median HDI / distance | MAP error % median / mean "
            "| posterior-mean error % median / mean | converged | CPU s median / max |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows, intervals = [], []
    keys = sorted({(r["crowd"], r["reading"]) for r in records}, key=lambda c: (list(CROWDS).index(c[0]), c[1]))
    for crowd, reading in keys:
        for setting in (*SETTINGS, "both"):
            s = [r for r in records if r["crowd"] == crowd and r["reading"] == reading
                 and setting in ("both", r["setting"])]
            if not s:
                continue
            col = lambda key: np.array([r[key] for r in s], float)  # noqa: E731
            me, pe, sec = col("map_error"), col("post_error"), col("seconds")
            rows.append(f"| {crowd} | {setting} | {reading} | {len(s)} | {100 * col('covered_distance_m').mean():.0f} % | "
                        f"{col('quantile_distance_m').mean():.2f} | {100 * np.mean(col('quantile_distance_m') > 0.5):.0f} % | "
                        f"{100 * col('covered_focal_length_px').mean():.0f} % | {col('quantile_focal_length_px').mean():.2f} | "
                        f"{np.median(col('hdi_over_distance')):.3f} | {np.median(me):.1f} / {me.mean():.1f} | "
                        f"{np.median(pe):.1f} / {pe.mean():.1f} | {100 * col('converged').mean():.0f} % | "
                        f"{np.median(sec):.1f} / {sec.max():.1f} |")
        s = [r for r in records if r["crowd"] == crowd and r["reading"] == reading]
        lo, hi = cluster_bootstrap([[r["covered_distance_m"], r["quantile_distance_m"], r["covered_focal_length_px"],
                                     r["quantile_focal_length_px"]] for r in s], [r["scene"] for r in s])
        intervals.append(f"- {crowd}, {reading}: distance coverage {100 * lo[0]:.0f}–{100 * hi[0]:.0f} %, mean quantile "
                         f"{lo[1]:.2f}–{hi[1]:.2f}; focal length coverage {100 * lo[2]:.0f}–{100 * hi[2]:.0f} %, mean "
                         f"quantile {lo[3]:.2f}–{hi[3]:.2f}")
    return "\n".join([head, *rows]) + "\n\n95 % bootstrap intervals over scenes:\n\n" + "\n".join(intervals) + "\n"


def monte_carlo(n: int = 2000, seed: int = 3) -> str:
    """The reading of drawn segments against the truth (module docstring), as a Markdown table."""
    from scipy.special import ndtr

    from creference_bayes.core.geometry import project, rotation_from_pitch_roll
    from creference_bayes.models.metrology import ground_lengths, linear_line_variances, marginal_reading

    pp, cam = np.array([1440.0, 900.0]), np.array([1800.0, 0.05, 0.0, 1.6, 0.3])
    horizon_row = pp[1] - cam[0] * np.tan(cam[1])
    rng = np.random.default_rng(seed)
    rows = []
    for band in ((3.0, 8.0), (30.0, 60.0)):
        for sigma in (2.0, 5.0):
            z = rng.uniform(*band, n)
            x = rng.uniform(-0.3, 0.3, n) * z
            ang, length = rng.uniform(0, 2 * np.pi, n), np.exp(rng.uniform(np.log(0.3), np.log(10.0), n))
            half = 0.5 * length[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
            ends = np.stack([np.column_stack([x, z]) - half, np.column_stack([x, z]) + half], axis=1)
            pts = np.stack([ends[..., 0], np.full((n, 2), cam[3]), ends[..., 1]], axis=-1).reshape(-1, 3)
            uv, depth = project(pts, rotation_from_pitch_roll(cam[1], cam[2]), cam[0], pp)
            drawn = uv.reshape(n, 2, 2) + sigma * rng.standard_normal((n, 2, 2))
            keep = np.all(depth.reshape(n, 2) > 0.5, axis=1) & np.all(drawn[..., 1] > horizon_row + 2.0, axis=1)
            drawn, truth = drawn[keep], np.log(length[keep])
            raw = np.log(ground_lengths(drawn, pp, cam[None])[0])
            lin = linear_line_variances(drawn, pp, cam, sigma)
            bins, var = marginal_reading(drawn, pp, cam, sigma)
            q_lin = ndtr((truth - raw) / np.sqrt(lin))
            q_mar = np.mean(ndtr((truth[:, None] - (raw[:, None] - bins)) / np.sqrt(np.maximum(var, 1e-300))), axis=1)
            total = np.mean(var + (bins - bins.mean(1, keepdims=True)) ** 2, axis=1)
            for name, err, sd, q in (("linear", raw - truth, np.sqrt(lin), q_lin),
                                     ("marginal", raw - bins.mean(1) - truth, np.sqrt(total), q_mar)):
                rows.append(f"| {band[0]:g}–{band[1]:g} m | {sigma:g} px | {name} | {len(truth)} | {np.median(err):+.3f} | "
                            f"{np.std(err):.3f} | {np.sqrt(np.mean(sd**2)):.3f} | "
                            f"{100 * np.mean((q > 0.1) & (q < 0.9)):.0f} % | {np.mean(q):.2f} |")
    return ("| segments | end-point noise | reading | segments | error of the reading: median | sd | stated sd (rms) | "
            "truths in the central 80 % | mean quantile of the truth |\n|---|---|---|---|---|---|---|---|---|\n"
            + "\n".join(rows) + "\n")


def populations(names, n: int) -> str:
    """The readings of the simulator's own reference segments at the true camera (module
    docstring, ``--populations``), as a Markdown table: per population (a crowd of ``CROWDS`` with
    20 references a scene, or a bench tier with 5) and band of drawn length over σ_line, where the
    true error of the segment's reading falls in what each reading states (mean quantile, shares
    beyond its 5 % and 95 % quantiles)."""
    from scipy.special import ndtr

    from creference_bayes.bench.simulate import TIERS
    from creference_bayes.models.metrology import ground_lengths, linear_line_variances, marginal_reading
    from creference_bayes.pipeline import build_model

    bands = ((0.0, 4.0), (4.0, 8.0), (8.0, np.inf))
    rows = []
    for name in names:
        found = {"linear": [], "marginal": [], LEARNED: []}
        scenes = []
        for k in range(n):
            crowd = name in CROWDS
            d = simulate_scene(np.random.default_rng([67, list((*CROWDS, *TIERS)).index(name), k]), tier=name,
                               setting=SETTINGS[k % 2], n_references=20 if crowd else 5,
                               n_target_annotations=13 if crowd else 5, format_offset=5 * k)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                scenes.append(parse_scene(d))
        for sc, floor in zip(scenes, segment_floors(scenes)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m, _ = build_model(sc)
            gt = sc.ground_truth
            cam = m.complete_camera(np.array([[gt["focal_length_px"], gt["pitch_rad"], gt["roll_rad"],
                                               gt["camera_height_m"], 0.0]]))[0]
            lines, sigma = np.array([r.line for r in sc.references], float), m.ref_line_sigma
            if sigma == 0:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                error = np.log(ground_lengths(lines, m.principal_point, cam[None])[0]) - np.log(gt["reference_lengths_m"])
            length = np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1) / sigma
            lin = linear_line_variances(lines, m.principal_point, cam, sigma)
            ok = np.isfinite(error) & (lin > 0)
            found["linear"] += list(zip(ndtr(error / np.sqrt(np.where(ok, lin, 1.0)))[ok], length[ok]))
            for reading, floor_px in (("marginal", None), (LEARNED, floor and floor["floor_px"])):
                bins, var = marginal_reading(lines, m.principal_point, cam, sigma, floor_px=floor_px)
                q = np.mean(ndtr((error[:, None] - bins) / np.sqrt(np.maximum(var, 1e-300))), axis=1)
                found[reading] += list(zip(q[ok], length[ok]))
        for reading, pairs in found.items():
            q, length = np.array(pairs).T
            cells = []
            for lo, hi in ((0.0, np.inf), *bands):
                s = q[(length >= lo) & (length < hi)]
                cells.append(f"{len(s)}: {s.mean():.2f}, {100 * np.mean(s < 0.05):.0f} / {100 * np.mean(s > 0.95):.0f} %"
                             if len(s) else "–")
            rows.append(f"| {name} | {reading} | " + " | ".join(cells) + " |")
    return ("| population | reading | all segments | drawn < 4 σ_line | 4–8 σ_line | ≥ 8 σ_line |\n|---|---|---|---|---|---|\n"
            + "\n".join(rows) + "\n\nEach cell: segments: the true error's mean quantile in the reading, the shares "
            "below its 5 % and above its 95 % quantiles.\n")


def bench(args) -> str:
    """The bench's tiers, each reading (module docstring): records to OUT/bench.jsonl, a table."""
    from creference_bayes.bench.runner import CONFIGS, bench_scenes, variant

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.jsonl"
    done = {(r["scene"], r["reading"]) for r in _load(path)}
    with open(path, "a") as f:
        for seed in args.seeds:
            scenes = [(sid, variant(sc, 5, range(5))) for sid, sc in bench_scenes(CONFIGS["full"], seed)[: args.n]]
            floors, tail = {}, {}  # each tier's scenes are a data set
            for tier in sorted({sc.ground_truth["tier"] for _, sc in scenes}):
                at = [sid for sid, sc in scenes if sc.ground_truth["tier"] == tier]
                floors.update(zip(at, segment_floors([sc for sid, sc in scenes if sid in at])))
                if TAIL in args.readings:
                    tail.update(zip(at, tails([sc for sid, sc in scenes if sid in at],
                                              out / f"tails_bench_{tier}_seed{seed}_{args.n}.json")))
            for k, (sid, sc) in enumerate(scenes):
                floor, scene_tail = floors[sid], tail.get(sid)
                sid = sid if seed == 0 else f"{sid}-seed{seed}"
                x, _, z = sc.targets[0].ground_truth["location_m"]
                for reading in args.readings:
                    if (sid, reading) in done:
                        continue
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        r = estimate(sc, seed=k, sampling={"min_ess": args.min_ess}, keep_draws=0,
                                     **reading_options(reading, floor, scene_tail))
                    o = r.to_dict()["objects"][0]
                    lo, hi = o["posterior"]["hdi"]["distance_m"]
                    distance = np.hypot(r.draws.objects[..., 0, O_X], r.draws.objects[..., 0, O_Z])
                    f.write(json.dumps({"scene": sid, "tier": sc.ground_truth["tier"], "reading": reading,
                                        "map_error": o["evaluation"]["location_pct_error"],
                                        "post_error": o["evaluation"]["posterior_location_pct_error"],
                                        "covered": bool(lo <= np.hypot(x, z) <= hi),
                                        "quantile": float(np.mean(distance < np.hypot(x, z)))}) + "\n")
                    f.flush()
    seed_of = lambda sid: int(sid.rpartition("-seed")[2]) if "-seed" in sid else 0  # noqa: E731
    recs = [r for r in _load(path) if seed_of(r["scene"]) in args.seeds]
    rows, paired = [], []
    for tier in ("none", "low", "medium", "high", "all noisy"):
        both = {}
        for r in recs:
            if r["tier"] == tier or (tier == "all noisy" and r["tier"] != "none"):
                both.setdefault(r["scene"], {})[r["reading"]] = r["post_error"]
        for reading in (r for r in args.readings if r != "linear"):
            diff = [d[reading] - d["linear"] for d in both.values() if {reading, "linear"} <= set(d)]
            if diff:
                lo, hi = cluster_bootstrap(diff, np.arange(len(diff)))
                paired.append(f"- {tier}, {reading}: {np.mean(diff):+.1f} points over {len(diff)} scenes "
                              f"({lo:+.1f} to {hi:+.1f})")
        for reading in args.readings:
            s = [r for r in recs if r["reading"] == reading and (r["tier"] == tier or (tier == "all noisy" and r["tier"] != "none"))]
            if s:
                me, pe = np.array([r["map_error"] for r in s]), np.array([r["post_error"] for r in s])
                q = np.array([r.get("quantile", np.nan) for r in s])
                rows.append(f"| {tier} | {reading} | {len(s)} | {np.median(me):.1f} / {me.mean():.1f} | "
                            f"{np.median(pe):.1f} / {pe.mean():.1f} | {100 * np.mean([r['covered'] for r in s]):.0f} % | "
                            f"{np.nanmean(q):.2f} |")
    return ("| tier | reading | scenes | MAP error % median / mean | posterior-mean error % median / mean | "
            "distance: 90 % HDI covers | mean quantile |\n|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
            + ("\nPosterior-mean error, each reading less linear, mean over the scenes (95 % bootstrap):\n\n"
               + "\n".join(paired) + "\n" if paired else ""))


def timing(readings, rounds: int = 15, calls: int = 50) -> str:
    """CPU seconds of one evaluation of the posterior's terms at 64 states of the paper-study-size
    scene of ``examples/profile_posterior.py`` (seed 0: outdoor, 20 line references), with and
    without its horizon, per reading: the minimum over ``rounds`` interleaved rounds of ``calls``
    calls; and of fixing the reading at the pilot."""
    import sys

    from creference_bayes.bench.simulate import true_state
    from creference_bayes.pipeline import build_model

    sys.path.insert(0, str(Path(__file__).parent))
    from profile_posterior import study_scene

    lines = []
    for horizon in (True, False):
        sc = study_scene(0, horizon)
        cam, obj = true_state(sc)
        rng = np.random.default_rng(0)
        cams = cam[None] * (1 + 0.01 * rng.standard_normal((64, 5)))
        objs = obj[None] * (1 + 0.01 * rng.standard_normal((64,) + obj.shape))
        models, pilot = {}, {}
        for reading in readings:
            m, _ = build_model(sc, line_reading=reading)
            m.handedness = np.array([t.ground_truth["handedness"] for t in sc.targets], float)
            m.set_pilot(cam)
            t0 = time.process_time()
            m.set_pilot(cam)
            pilot[reading] = time.process_time() - t0
            models[reading] = m
        best = dict.fromkeys(readings, np.inf)
        for _ in range(rounds):
            for reading, m in models.items():
                t0 = time.process_time()
                for _ in range(calls):
                    m.terms(cams, objs)
                best[reading] = min(best[reading], (time.process_time() - t0) / calls)
        lines += [f"horizon {'given' if horizon else 'free'}, {r}: {1e3 * best[r]:.2f} ms of CPU per evaluation "
                  f"of 64 states; the reading at the pilot {1e3 * pilot[r]:.1f} ms" for r in readings]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=100, help="scenes per crowd (default: %(default)s)")
    p.add_argument("--crowds", default="light,heavy", type=lambda v: v.split(","),
                   help=f"comma-separated, of {list(CROWDS)} (default: %(default)s)")
    p.add_argument("--readings", default="linear,marginal", type=lambda v: v.split(","),
                   help=f"comma-separated, of {list(READINGS)} (default: %(default)s)")
    p.add_argument("--references", default="mixed", choices=list(REFERENCES),
                   help="the references' formats: all ten (mixed) or relative values only (default: %(default)s)")
    p.add_argument("--min-ess", type=int, default=400, help="bulk ESS of each posterior (default: %(default)s)")
    p.add_argument("--out", default="reference_reading", help="output folder (default: %(default)s)")
    p.add_argument("--report", action="store_true", help="only write the table of the records in --out")
    p.add_argument("--bench", action="store_true", help="only the bench's tiers (module docstring)")
    p.add_argument("--seeds", default="0", type=lambda v: [int(x) for x in v.split(",")],
                   help="with --bench: comma-separated seeds of the bench's scenes, 32 a seed (default: %(default)s)")
    p.add_argument("--timing", action="store_true", help="only the CPU of one evaluation per reading")
    p.add_argument("--monte-carlo", action="store_true", help="only the reading against a Monte Carlo of end-point noise")
    p.add_argument("--populations", default=None, type=lambda v: v.split(","),
                   help="only the reading of the simulator's own segments at the true camera, for these crowds "
                        "or bench tiers (comma-separated; --n scenes each)")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    if args.populations:
        print(populations(args.populations, args.n))
        return
    if args.monte_carlo:
        print(monte_carlo())
        return
    if args.bench:
        print(bench(args))
        return
    if args.timing:
        print(timing(args.readings))
        return
    for name, values, allowed in (("--crowds", args.crowds, CROWDS), ("--readings", args.readings, READINGS)):
        bad = [v for v in values if v not in allowed]
        if bad:
            p.error(f"{name}: unknown {bad} (expected some of {list(allowed)})")
    if not args.report:
        run(args)
    text = table(_load(Path(args.out) / "records.jsonl"))
    (Path(args.out) / "table.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
