"""Is the advice worth following on real street geometry? Good labels per human hour, advised
against fixed designs, on KITTI frames (docs/studies/advice.md).

    python examples/kitti_advice_study.py KITTI_DIR --out DIR [--split all|even|odd] [--start-k 1]
        [--noise-px 2] [--budget-s S] [--max-frames N] [--max-steps N] [--seed 0] [--focal-unknown]
        [--score-iou 0.7] [--min-quality 0.5]
    python examples/kitti_advice_study.py KITTI_DIR --out DIR --tables-only

1. Frames as examples/kitti_study.py makes them (``creference simulate --from-kitti``: one scene per
   image, the class size priors, P2's focal length given, or left out with ``--focal-unknown``), with
   ``--start-k`` sets of dimension lines per object at ``--noise-px``.
2. Round 0: ``creference batch``, then ``creference labels``. A label is *good* when its
   P(IoU ≥ T) ≥ Q (``--score-iou``, ``--min-quality``); *truly good* when it is good and its 3D IoU
   with KITTI's own box is ≥ T.
3. Designs, each the round-0 scenes with answers added, estimated again (a copy of the round-0
   batch folder, resumed: ``creference batch`` re-estimates only the scenes that changed) and
   labelled again:

   - ``advised``: ``creference advise`` on round 0 with ``--budget S`` (default: the human time of
     ``dims``, so that the plans compare at equal cost); each request answered from the truth;
     requests for a reference are not answered (counted as not realised);
   - ``dims``: one more set of dimension lines on every object (PAPER_TARGET_SECONDS each);
   - ``sizes``: every object's size from a catalogue (SIZE_SECONDS each);
   - ``mounting``: every camera's mounting (MOUNTING_SECONDS once per camera id).

   Answers from the truth: a set of lines is ``kitti_scene``'s, drawn again with a fresh seed at
   the same noise; a size is the true one times exp(N(0, CATALOGUE_LOG_SD)) per dimension; a
   mounting is the frame's true camera (kitti_study's: the objects' median bottom, level). The
   advised plan and the fixed designs get the same answer to the same question.
4. A Markdown table per design (human seconds, good and truly good labels before → after, good
   labels gained per human hour; for ``advised`` the predicted gain, the sum of the executed
   requests' ``good_gain`` in the plan, beside the realised one), also written to
   ``DIR/advice_study.json``.
5. Predicted against realised per design (``accuracy`` in the JSON): a design's prediction is its
   requests answered together as the plan states them (``combined_chance``: their changes of
   each label's P(IoU ≥ T) add), the labels lifted less those dropped, beside the sum of each
   request's gain weighed alone, with the ratio's 90 % interval from resampling the frames; the
   same in each band of the labels' round-0 P(IoU ≥ T)
   (``BAND_EDGES``; the last, the labels already good, predicted to lose), with the realised
   count's 90 % interval if the predicted chances are right; and the advised plan's gain on the
   futures its requests were chosen by beside the one it states from the others.
   ``--tables-only`` computes these again from an earlier run's folder, estimating nothing.

The advised plan stops where no request is worth ``--min-good-per-hour`` (advise's default), so it
may spend less than ``S``: compare good labels per human hour, or pass 0 to spend it all.
``--max-frames``, ``--max-steps``, ``--draws`` and ``--futures`` make a tiny run (the tests).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kitti_study import _load_frame, _truth_state  # noqa: E402  (examples/ is not a package)

def creference(*args) -> subprocess.CompletedProcess:
    """The ``creference`` command in this interpreter; exit 1 (some scenes failed) is not an error."""
    proc = subprocess.run([sys.executable, "-m", "creference_bayes", *map(str, args)], capture_output=True, text=True)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"creference {' '.join(map(str, args))}: exit {proc.returncode}\n{proc.stderr[-3000:]}")
    return proc


def estimate_and_label(scenes: list[Path], batch: Path, labels: Path, args) -> dict:
    """``creference batch`` the scenes into ``batch`` (resumed) and ``creference labels`` it: the
    counts of labels, good and truly good ones, the batch's scenes by status and each step's seconds."""
    t0 = time.perf_counter()
    run = ["--workers", args.workers] if args.workers else []
    run += ["--max-steps", args.max_steps] if args.max_steps else []
    creference("batch", *scenes, "--out", batch, "--seed", args.seed, "--quiet", *run)
    t1 = time.perf_counter()
    creference("labels", batch, "--out", labels, "--score-iou", args.score_iou, "--min-quality", args.min_quality,
               "--no-figure", "--quiet")
    status = [s["status"] for s in json.loads((batch / "batch.json").read_text())["scenes"]]
    with open(labels / "labels.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    good = [r for r in rows if _is_good(r, args)]
    true = [r for r in good if r["true_iou"] and float(r["true_iou"]) >= args.score_iou]
    return {"labels": len(rows), "good": len(good), "truly_good": len(true),
            "true_iou_ge": sum(bool(r["true_iou"]) and float(r["true_iou"]) >= args.score_iou for r in rows),
            "estimated": status.count("done"), "unchanged": status.count("skipped"), "failed": status.count("failed"),
            "batch_s": round(t1 - t0, 2), "labels_s": round(time.perf_counter() - t1, 2)}


class Truth:
    """What answers a frame's requests: a new set of lines per target (``kitti_scene`` drawn again
    with a fresh seed), a catalogue size per target and the camera's mounting."""

    def __init__(self, scene, key: str, kitti: Path, args):
        from creference_bayes.bench.kitti import kitti_scene
        from creference_bayes.models.contract import C_HEIGHT, C_PITCH, C_ROLL
        from creference_bayes.workflows.advice.answers import CATALOGUE_LOG_SD

        stream = [args.seed, zlib.crc32(key.encode())]
        stem = scene.ground_truth["frame"]
        image = kitti / "image_2" / f"{stem}.png"
        again, _ = kitti_scene(kitti / "label_2" / f"{stem}.txt", kitti / "calib" / f"{stem}.txt",
                               image.resolve() if image.exists() else None, rng=[*stream, 1], n_annotations=1,
                               noise_px=args.noise_px)
        self.lines = {t["id"]: np.array(t["dimension_lines"][0]["corners"]) for t in again["targets"]}
        noise = np.random.default_rng([*stream, 2]).normal(0.0, CATALOGUE_LOG_SD, (len(scene.targets), 3))
        self.sizes = {t.id: np.array([t.ground_truth["dimensions_m"][k] for k in ("length", "width", "height")])
                      * np.exp(e) for t, e in zip(scene.targets, noise)}
        cam = _truth_state(scene)[0]
        self.mounting = float(cam[C_HEIGHT]), float(cam[C_PITCH]), float(cam[C_ROLL])

    def answer(self, scene, kind: str, target: str | None):
        from creference_bayes.workflows.advice.answers import with_dimension_lines, with_mounting, with_size

        if kind == "dims":
            return with_dimension_lines(scene, target, self.lines[target])
        if kind == "size":
            return with_size(scene, target, self.sizes[target])
        if kind == "mounting":
            return with_mounting(scene, *self.mounting)
        raise ValueError(kind)


def advised_plan(round0: Path, out: Path, scenes: dict, budget_s: float, args) -> tuple[list, list[dict]]:
    """``creference advise`` on round 0: the answers to give (key, kind, target) and every request
    row (``realised`` says whether it was answered)."""
    proc = creference("advise", round0, "--out", out, "--budget", f"{budget_s:g}", "--seed", args.seed, "--score-iou",
               args.score_iou, "--min-quality", args.min_quality, "--quiet", "--requests", "dims,size,mounting",
               *(["--draws", args.draws] if args.draws else []), *(["--futures", args.futures] if args.futures else []),
               *([] if args.min_good_per_hour is None else ["--min-good-per-hour", args.min_good_per_hour]),
               *(["--workers", args.workers] if args.workers else []))
    if not (out / "requests.csv").exists():
        raise SystemExit(f"creference advise wrote no requests.csv:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    with open(out / "requests.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    plan = []
    for r in rows:
        r["realised"] = r["kind"] in ("dims", "size", "mounting")
        if r["kind"] == "mounting":  # once per camera: every frame of it gets its own mounting
            plan += [(k, "mounting", None) for k, s in scenes.items() if s.camera_id == r["camera"]] or [
                (r["key"], "mounting", None)]
        elif r["realised"]:
            plan.append((r["key"], r["kind"], r["target"]))
    return list(dict.fromkeys(plan)), rows


def _is_good(row: dict, args) -> bool:
    """A ``labels.csv`` row is good: its P(IoU ≥ --score-iou) ≥ --min-quality."""
    return float(row[f"p_iou_ge_{args.score_iou:g}"]) >= args.min_quality


def _good_by_target(labels_csv: Path, args) -> dict:
    """Whether each label of a ``labels.csv`` is good, by (scene, target)."""
    with open(labels_csv, newline="") as f:
        return {(r["scene"], r["target"]): _is_good(r, args) for r in csv.DictReader(f)}


def _lifted(moments: list, scene: dict) -> np.ndarray:
    """Per target of a frame's advice (``scene``, an entry of advice.json), the expected change of
    its goodness when the requests of ``moments`` (their ``moments`` there) are answered together,
    as the plan states them (:func:`~creference_bayes.workflows.advice.combined_chance`): for a target
    below the bar its chance to become good, for one good now minus its chance to fall. 0 for every
    target of a frame no request is asked in (it is not estimated again)."""
    from creference_bayes.workflows.advice import Moments, combined_chance, futures_scale

    p_now, q = np.asarray(scene["now"]["p_iou"], float), scene["settings"]["min_quality"]
    base, bar = futures_scale(p_now, scene.get("shift"), q)
    below = p_now < q
    if any(m is None for m in moments):
        raise SystemExit(f"{scene['key']}: its advice has no moments (advice.json lacks them): advise again")
    chance = combined_chance(base, bar, [Moments.from_dict(m) for m in moments])
    return np.where(below, chance, chance - 1.0)


#: The bands of a label's round-0 P(IoU ≥ T) the predictions are checked in; the last, from the
#: bar up, holds the labels already good (predicted to fall with the chance :func:`_lifted` gives).
BAND_EDGES = (0.0, 0.1, 0.3)


def _interval(r: np.ndarray, p: np.ndarray, idx: np.ndarray):
    """90 % interval of Σ r / Σ p over the frame resamples ``idx`` (None when no resample predicts)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = r[idx].sum(axis=1) / p[idx].sum(axis=1)
    ratios = ratios[np.isfinite(ratios)]   # resamples whose predicted gain is 0 have no ratio
    return [float(q) for q in np.quantile(ratios, [0.05, 0.95])] if len(ratios) else None


def accuracy(out: Path, camera_of: dict, args, n_boot: int = 2000) -> list[dict]:
    """Predicted against realised good labels gained, per design, over the frames and in each band
    of the labels' round-0 P(IoU ≥ T) (:data:`BAND_EDGES`). A design's prediction is its requests'
    chances combined per target (:func:`_lifted`); ``predicted_alone`` sums each request's
    ``good_gain`` weighed alone instead (the advice weighs one request at a time, a design answers
    them all at once). The ratio's 90 % interval resamples frames (the labels of a frame share its
    camera, so they are not independent). In a band below the bar, ``expected_90`` is the 90 %
    interval of the realised count if each label became good with its predicted chance, and the
    band ``agrees`` when the realised count lies in it. In the band of labels already good the
    prediction is minus their chances of falling, and the interval runs from minus the labels
    that may fall to 0. ``lifted`` and ``dropped`` split a design's predicted and
    realised net change into the labels below the bar that became good and the good ones that
    fell."""
    advice = json.loads((out / "advice" / "advice.json").read_text())
    with open(out / "advice" / "requests.csv", newline="") as f:
        planned = list(csv.DictReader(f))
    kind_design = {"dims": "dims", "size": "sizes", "mounting": "mounting"}
    chosen = {(r["key"], f"{r['target']}:{r['kind']}" if r["kind"] != "mounting" else "camera:mounting")
              for r in planned if r["kind"] != "mounting" or not r["camera"]}
    cameras = {r["camera"] for r in planned if r["kind"] == "mounting" and r["camera"]}
    pred = {d: {} for d in ("advised", "dims", "sizes", "mounting")}  # design -> frame -> per target
    alone = {d: {} for d in pred}
    ranked = {}  # the advised requests' gain on the futures they were chosen by
    now = {}     # frame -> (target ids, round-0 P(IoU ≥ T))
    for sc in advice["scenes"]:
        k = sc["key"]
        p_now = np.asarray(sc["now"]["p_iou"], float)
        now[k] = (list(sc["targets"]), p_now)
        told, rank = {d: [] for d in pred}, []
        for p in sc.get("predictions") or []:
            c = p["candidate"]
            designs = [kind_design[c["kind"]]] if c["kind"] in kind_design else []
            if (k, c["key"]) in chosen or (c["kind"] == "mounting" and camera_of.get(k) in cameras):
                designs.append("advised")
                rank.append(p["rank_moments"])
            for d in designs:
                told[d].append(p["moments"])
                alone[d][k] = alone[d].get(k, 0.0) + float(p["good_gain"])
        for d in pred:
            pred[d][k] = _lifted(told[d], sc)
        ranked[k] = float(_lifted(rank, sc).sum())
    good0 = _good_by_target(out / "round0" / "labels" / "labels.csv", args)
    frames = sorted(now)
    edges = [*BAND_EDGES, args.min_quality]
    names = [f"{lo:g}–{hi:g}" for lo, hi in zip(edges[:-1], edges[1:])] + [f"≥ {args.min_quality:g} (good)"]
    band = {k: np.digitize(now[k][1], edges[1:]) for k in frames}  # 0 .. len(names) - 1
    idx = np.random.default_rng(0).integers(len(frames), size=(n_boot, len(frames)))
    rows = []
    for name, by_frame in pred.items():
        if not (out / name / "labels" / "labels.csv").exists():
            continue
        good1 = _good_by_target(out / name / "labels" / "labels.csv", args)
        f_, b_, p_, r_ = [], [], [], []  # per label: frame, band, predicted chance, realised (net) gain
        for i, k in enumerate(frames):
            ids = now[k][0]
            f_ += [i] * len(ids)
            b_ += list(band[k])
            p_ += list(by_frame.get(k, np.zeros(len(ids))))
            r_ += [good1.get((k, t), False) - good0.get((k, t), False) for t in ids]
        f_, b_, p_, r_ = np.array(f_), np.array(b_), np.array(p_, float), np.array(r_, float)
        p, r = np.bincount(f_, p_, len(frames)), np.bincount(f_, r_, len(frames))
        # the labels as predicted: each below the bar lifted, each good one dropped, with its chance
        outcomes = np.sign(p_) * (np.random.default_rng(1).random((n_boot, len(p_))) < np.abs(p_))
        bands = []
        for b, label in enumerate(names):
            m = b_ == b
            pb, rb = float(p_[m].sum()) + 0.0, float(r_[m].sum()) + 0.0
            lo, hi = (float(q) + 0.0 for q in np.quantile(outcomes[:, m].sum(axis=1), [0.05, 0.95]))
            bands.append({"band": label, "labels": int(m.sum()), "predicted": pb, "realised": rb,
                          "expected_90": [lo, hi], "agrees": bool(lo <= rb <= hi)})
        up, down = p_ > 0, p_ < 0
        rows.append({"design": name, "predicted": float(p.sum()), "realised": float(r.sum()),
                     "lifted": {"predicted": float(p_[up].sum()), "realised": float(r_[r_ > 0].sum())},
                     "dropped": {"predicted": float(-p_[down].sum()) + 0.0, "realised": float(-r_[r_ < 0].sum()) + 0.0},
                     "predicted_alone": float(sum(alone[name].values())),
                     "predicted_on_ranking_futures": float(sum(ranked.values())) if name == "advised" else None,
                     "ratio": float(r.sum() / p.sum()) if p.sum() else None, "ratio_90": _interval(r, p, idx),
                     "bands": bands})
    return rows


def _ratio(a: dict) -> str:
    ratio = "-" if a["ratio"] is None else f"{a['ratio']:.2f}"
    return ratio + ("" if a["ratio_90"] is None else f" ({a['ratio_90'][0]:.2f} to {a['ratio_90'][1]:.2f})")


def print_accuracy(rows: list[dict]) -> None:
    print("\n| design | lifted: predicted → realised | dropped: predicted → realised | net predicted (requests combined) "
          "| sum of single requests' lifts | net realised | realised / predicted (90 % interval, frames resampled) |")
    print("|---|---|---|---|---|---|---|")
    for a in rows:
        print(f"| {a['design']} | {a['lifted']['predicted']:.1f} → {a['lifted']['realised']:.0f} | "
              f"{a['dropped']['predicted']:.1f} → {a['dropped']['realised']:.0f} | {a['predicted']:.1f} | "
              f"{a['predicted_alone']:.1f} | {a['realised']:.0f} | {_ratio(a)} |")
    print("\nBy the label's round-0 P(IoU ≥ T): labels, predicted → realised net change of the good labels (the "
          "realised count's 90 % interval if the predicted chances are right; ✗ outside it)\n")
    names = [b["band"] for b in rows[0]["bands"]] if rows else []
    print("| design | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for a in rows:
        cells = [f"{b['labels']}: {b['predicted']:.1f} → {b['realised']:.0f} "
                 f"({b['expected_90'][0]:.0f}–{b['expected_90'][1]:.0f}){'' if b['agrees'] else ' ✗'}"
                 for b in a["bands"]]
        print(f"| {a['design']} | " + " | ".join(cells) + " |")
    for a in rows:
        if a["predicted_on_ranking_futures"] is not None:
            print(f"\nadvised: {a['predicted_on_ranking_futures']:.1f} good labels on the futures the requests were "
                  f"chosen by, {a['predicted']:.1f} on the others (stated), {a['realised']:.0f} realised")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("kitti", type=Path, help="a KITTI folder (label_2/, calib/, image_2/)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--split", choices=("all", "even", "odd"), default="all",
                   help="every frame, or those with an even or odd number (as kitti_study.py)")
    p.add_argument("--start-k", type=int, default=1, help="sets of dimension lines per object in round 0")
    p.add_argument("--focal-unknown", action="store_true",
                   help="leave P2's focal length out of the scenes (simulate --from-kitti --focal-unknown): the "
                        "batch's data-set layer then holds each camera's focal length")
    p.add_argument("--noise-px", type=float, default=2.0)
    p.add_argument("--budget-s", type=float, default=None,
                   help="the advised plan's human seconds (default: those of one more set on every object)")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--max-steps", type=int, default=None, help="the sampler's cap on steps per scene (batch's default)")
    p.add_argument("--draws", type=int, default=None, help="the advice's posterior draws (advise's default)")
    p.add_argument("--futures", type=int, default=None, help="the advice's simulated outcomes (advise's default)")
    p.add_argument("--min-good-per-hour", type=float, default=None,
                   help="the advice's least worthwhile request (advise's default); 0 spends the whole budget")
    p.add_argument("--workers", type=int, default=None, help="local workers of batch (default: the cores) and advise (default: 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--score-iou", type=float, choices=(0.5, 0.7), default=0.7)
    p.add_argument("--min-quality", type=float, default=0.5)
    p.add_argument("--tables-only", action="store_true",
                   help="compute and print the tables of an earlier run in --out again (nothing estimated)")
    args = p.parse_args(argv)
    if args.tables_only:
        if not (args.out / "advice_study.json").exists():
            p.error(f"--tables-only: {args.out / 'advice_study.json'} does not exist (run the study first)")
        return tables_again(args.out)
    if args.start_k < 1:
        p.error(f"--start-k: expected an integer >= 1, got {args.start_k}")

    from creference_bayes.bench.kitti import kitti_scenes
    from creference_bayes.io.files import atomic_write_json
    from creference_bayes.io.scene import scene_to_dict
    from creference_bayes.workflows.advice.answers import MOUNTING_SECONDS, SIZE_SECONDS
    from creference_bayes.workflows.advice.candidates import PAPER_TARGET_SECONDS

    out = args.out
    for old in ("round0", "advice"):  # a run is one piece: no result of an earlier run's frames
        shutil.rmtree(out / old, ignore_errors=True)
    kitti_scenes(args.kitti, out / "frames", n_annotations=args.start_k, noise_px=args.noise_px, seed=args.seed,
                 focal_known=not args.focal_unknown)
    paths = sorted((out / "frames").glob("*.json"))
    if args.split != "all":
        paths = [q for q in paths if int(q.stem) % 2 == (args.split == "odd")]
    paths = paths[:args.max_frames]
    if not paths:
        p.error(f"{args.kitti}: no frame with an annotatable object (split {args.split})")
    scenes = {q.stem: _load_frame(q, "unknown") for q in paths}
    truth = {k: Truth(s, k, args.kitti, args) for k, s in scenes.items()}
    targets = [(k, t) for k, s in scenes.items() for t in s.targets]
    cameras = {s.camera_id for s in scenes.values()}
    print(f"{len(scenes)} frames, {len(targets)} objects, {len(cameras)} cameras; K = {args.start_k}", flush=True)

    before = estimate_and_label(paths, out / "round0" / "batch", out / "round0" / "labels", args)
    print(f"round 0: {before['good']} of {before['labels']} labels good, {before['truly_good']} truly "
          f"({before['batch_s']:.0f} s batch, {before['batch_s'] / len(paths):.1f} s a frame)", flush=True)
    budget = args.budget_s or PAPER_TARGET_SECONDS * len(targets)
    t0 = time.perf_counter()
    plan, requests = advised_plan(out / "round0" / "batch", out / "advice", scenes, budget, args)
    before["advise_s"] = round(time.perf_counter() - t0, 2)
    print(f"advice: {len(requests)} requests within {budget:g} s ({before['advise_s']:.0f} s)", flush=True)
    designs = {
        "advised": (plan, sum(float(r["seconds"]) for r in requests if r["realised"])),
        "dims": ([(k, "dims", t.id) for k, t in targets], PAPER_TARGET_SECONDS * len(targets)),
        "sizes": ([(k, "size", t.id) for k, t in targets if t.dimensions is None],
                  SIZE_SECONDS * sum(t.dimensions is None for _, t in targets)),
        "mounting": ([(k, "mounting", None) for k in scenes], MOUNTING_SECONDS * len(cameras)),
    }
    report = {"settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
              "frames": list(scenes), "objects": len(targets), "cameras": len(cameras), "budget_s": budget,
              "round0": before, "designs": {}}
    for name, (answers, seconds) in designs.items():
        folder = out / name
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(out / "round0" / "batch", folder / "batch")  # resumed: only changed scenes run
        files = []
        for key, scene in scenes.items():
            for k, kind, target in answers:
                if k == key:
                    scene = truth[key].answer(scene, kind, target)
            files.append(atomic_write_json(folder / "scenes" / f"{key}.json", scene_to_dict(scene)))
        after = estimate_and_label(files, folder / "batch", folder / "labels", args)
        gain = after["good"] - before["good"]
        d = {"human_s": seconds, "answers": len(answers), **{f"{k}_after": v for k, v in after.items()},
             "good_gain": gain, "good_per_hour": gain / (seconds / 3600) if seconds else None}
        if name == "advised":
            d.update(requests=len(requests), not_realised=sum(not r["realised"] for r in requests),
                     not_realised_s=sum(float(r["seconds"]) for r in requests if not r["realised"]),
                     predicted_good_gain=sum(float(r["good_gain"]) for r in requests if r["realised"]),
                     predicted_good_loss=sum(float(r["good_loss"]) for r in requests if r["realised"]),
                     rows=requests)
        report["designs"][name] = d
        print(f"{name}: {after['estimated']} scenes estimated again, {after['unchanged']} unchanged; "
              f"{after['batch_s']:.0f} s", flush=True)

    report["accuracy"] = accuracy(out, {k: s.camera_id for k, s in scenes.items()}, args)
    return finish(report, out, args)


def finish(report: dict, out: Path, args) -> int:
    """Print the tables of a run's ``report`` and write it to ``out/advice_study.json``."""
    from creference_bayes.io.files import atomic_write_json

    before = report["round0"]
    print(f"\n{len(report['frames'])} frames, {report['objects']} objects; good: P(IoU ≥ {args.score_iou:g}) ≥ "
          f"{args.min_quality:g}; truly good: also IoU ≥ {args.score_iou:g} with KITTI's box\n")
    print("| design | human s | good | truly good | good gained per human h | predicted net gain | realised net gain |")
    print("|---|---|---|---|---|---|---|")
    predicted = {a["design"]: a["predicted"] for a in report["accuracy"]}
    for name, d in report["designs"].items():
        rate = "-" if d["good_per_hour"] is None else f"{d['good_per_hour']:.2f}"
        pred = f"{predicted[name]:.1f}" if name == "advised" else ""
        print(f"| {name} | {d['human_s']:g} | {before['good']} → {d['good_after']} | {before['truly_good']} → "
              f"{d['truly_good_after']} | {rate} | {pred} | {d['good_gain']} |")
    print_accuracy(report["accuracy"])
    adv = report["designs"]["advised"]
    print(f"\nadvised: {adv['requests']} requests within {report['budget_s']:g} s, {adv['not_realised']} not realised "
          f"(references, {adv['not_realised_s']:g} s)")
    atomic_write_json(out / "advice_study.json", report)
    print(f"wrote {out / 'advice_study.json'}")
    return 0


def tables_again(out: Path) -> int:
    """``--tables-only``: the accuracy of an earlier run in ``out`` computed again from its folders
    (its own settings; nothing estimated), its tables printed and its JSON rewritten."""
    report = json.loads((out / "advice_study.json").read_text())
    args = argparse.Namespace(**report["settings"])
    camera_of = {k: _load_frame(out / "frames" / f"{k}.json", "unknown").camera_id for k in report["frames"]}
    report["accuracy"] = accuracy(out, camera_of, args)
    return finish(report, out, args)


if __name__ == "__main__":
    raise SystemExit(main())
