"""The data-set report of a label export: quality across the data set, the objects below a
user-set quality (the list to send back for more annotations) and, with ground truth, how well
the quality is calibrated. Writes ``report.md``, ``labels.csv``, ``needs_annotation.csv`` and
``quality.png``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...io.files import atomic_path, atomic_write_csv, atomic_write_text
from .quality import IOU_THRESHOLDS, reliability_table

__all__ = ["LABEL_COLUMNS", "NEEDS_COLUMNS", "label_rows", "advice_verdicts", "calibration", "write_report"]

LABEL_COLUMNS = ("image", "line", "scene", "target", "type", "p_iou_ge_0.5", "p_iou_ge_0.7",
                 "iou_mean", "true_iou", "distance_sd_m", "converged", "dimension_lines",
                 "references", "calib_mismatch_px")
#: ``needs_annotation.csv``: the label's columns and the advice's verdict on it (``creference
#: advise BATCH_DIR`` with the same threshold and quality): ``lift`` (``best_request`` is more
#: likely than not to lift it), ``none`` (no single request is) or empty without an advice.
NEEDS_COLUMNS = LABEL_COLUMNS + ("verdict", "best_request", "p_expected", "chance", "advice")


def advice_verdicts(batch_dir: str | Path, fingerprints: dict, *, score_iou: float, min_quality: float,
                    advice_path: str | Path | None = None) -> tuple[dict, str | None]:
    """The verdicts of ``creference advise BATCH_DIR`` (``BATCH_DIR/advice/advice.json``, or
    ``advice_path``) by (scene key, target id), and a note when there is none to use: no advice,
    an advice for another bar (``iou_threshold``, ``min_quality``), of results since re-estimated
    (the fingerprint it records differs from ``fingerprints[key]``, the labelled result's) or of
    frames with no labelled result now (no ``key`` in ``fingerprints``)."""
    from ...io.validation import read_json

    path = Path(advice_path) if advice_path is not None else Path(batch_dir) / "advice" / "advice.json"
    rerun = (f"run `creference advise {batch_dir} --score-iou {score_iou:g} --min-quality {min_quality:g}` "
             "for what would lift them")
    if not path.is_file():
        return {}, rerun
    try:
        d = read_json(path)
        scenes = d["scenes"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return {}, f"the advice {path} cannot be read ({exc}); {rerun}"
    out, stale, gone = {}, 0, 0
    for sc in scenes:
        s = sc.get("settings") or {}
        if (s.get("iou_threshold"), s.get("min_quality")) != (float(score_iou), float(min_quality)):
            return {}, (f"the advice {path} is for P(IoU ≥ {s.get('iou_threshold')}) ≥ {s.get('min_quality')}; "
                        f"{rerun}")
        if sc["key"] not in fingerprints:  # no result of that frame is labelled now
            gone += 1
            continue
        now = fingerprints[sc["key"]]
        if now is None or now != sc.get("scene_sha256"):
            stale += 1
            continue
        for v in sc.get("verdicts") or []:
            out[(sc["key"], v["target"])] = v
    said = ([f"{stale} frame(s) were re-estimated since the advice {path} was made: their verdicts are left "
             f"out; {rerun}"] if stale else []) + \
        ([f"{gone} frame(s) of the advice {path} have no result labelled now: their verdicts are left out"]
         if gone else [])
    return out, "; ".join(said) or None


def label_rows(objects) -> list[dict]:
    """One row per exported object (plain values), in export order."""
    rows = []
    for o in objects:
        e = o.sidecar
        q = o.quality.to_dict()
        rows.append({"image": o.name, "line": e["line"], "scene": o.key, "target": o.target,
                     "type": o.kitti.type, "p_iou_ge_0.5": q["p_iou_ge_0.5"], "p_iou_ge_0.7": q["p_iou_ge_0.7"],
                     "iou_mean": q["iou_mean"], "true_iou": o.true_iou,
                     "distance_sd_m": ((e.get("posterior") or {}).get("sd") or {}).get("distance_m"),
                     "converged": e["evidence"]["converged"], "dimension_lines": e["evidence"]["dimension_lines"],
                     "references": e["evidence"]["references"], "calib_mismatch_px": e["calib_mismatch_px"]})
    return rows


def calibration(objects, n_bins: int | None = None) -> dict[float, list[dict]]:
    """IoU threshold → reliability table of P(IoU ≥ t) against the true IoU (objects with truth).

    ``n_bins`` defaults to 10 with at least 200 such objects, else 5.
    """
    known = [o for o in objects if o.true_iou is not None]
    if not known:
        return {}
    if n_bins is None:
        n_bins = 10 if len(known) >= 200 else 5
    true = np.array([o.true_iou for o in known])
    return {t: reliability_table([o.quality.p_iou[t] for o in known], true >= t, n_bins) for t in IOU_THRESHOLDS}


def _csv(path: Path, rows: list[dict], columns) -> Path:
    return atomic_write_csv(path, ({k: _cell(r.get(k)) for k in columns} for r in rows), columns)


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _table(header: list[str], rows: list[list]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return out + ["| " + " | ".join(_cell(c) for c in r) + " |" for r in rows]


def write_report(export, out: str | Path, *, min_quality: float = 0.5, score_iou: float = 0.7,
                 batch_dir: str | Path | None = None, figure: bool = True,
                 advice_path: str | Path | None = None) -> dict[str, Path]:
    """Write the report files into ``out``; returns their paths by name. The labels below
    ``min_quality`` carry the verdicts of the batch's advice (:func:`advice_verdicts`)."""
    out = Path(out)
    key = f"p_iou_ge_{score_iou:g}"
    score_label = f"P(IoU ≥ {score_iou:g})"
    rows = label_rows(export.objects)
    low = sorted((r for r in rows if r[key] < min_quality), key=lambda r: (r[key], r["image"], r["line"]))
    verdicts, advice_note = ({}, None) if batch_dir is None else advice_verdicts(
        batch_dir, export.fingerprints, score_iou=score_iou, min_quality=min_quality, advice_path=advice_path)
    for r in low:
        v = verdicts.get((r["scene"], r["target"]))
        if v is not None:
            r.update(verdict=v["verdict"], best_request=v["best"], p_expected=v["p_expected"], chance=v["chance"],
                     advice=v["text"])
    paths = {"labels_csv": _csv(out / "labels.csv", rows, LABEL_COLUMNS),
             "needs_annotation_csv": _csv(out / "needs_annotation.csv", low, NEEDS_COLUMNS)}
    calib = calibration(export.objects)
    if figure and rows:
        from ...vision.label_figures import quality_figure

        fig = quality_figure([r[key] for r in rows], min_quality, score_label=score_label, reliability=calib)
        with atomic_path(out / "quality.png") as tmp:
            fig.savefig(tmp, dpi=110)
        paths["figure"] = out / "quality.png"
    text = _markdown(export, rows, low, calib, min_quality=min_quality, key=key, score_label=score_label,
                     batch_dir=batch_dir, figure="figure" in paths, advice_note=advice_note)
    paths["report"] = atomic_write_text(out / "report.md", text)
    return paths


def _markdown(export, rows, low, calib, *, min_quality, key, score_label, batch_dir, figure, advice_note=None) -> str:
    n = len(rows)
    lines = ["# Label quality report", ""]
    src = f" from the batch folder `{batch_dir}`" if batch_dir is not None else ""
    lines += [f"{n} object{'s' if n != 1 else ''} in {len(export.images)} image label file"
              f"{'s' if len(export.images) != 1 else ''}{src} (KITTI layout: `label_2/`, `calib/`, "
              f"`uncertainty/`). The label is the MAP box; its score is {score_label}, the posterior "
              f"probability that its 3D IoU with the true box is at least that, from the posterior draws.", ""]
    if export.failed_scenes or export.skipped:
        lines += [f"Not labelled: {len(export.failed_scenes)} scene(s) that failed in the batch, "
                  f"{len(export.skipped)} result(s) skipped:", ""]
        lines += [f"- `{f['key']}`: failed in the batch: {f['error']}" for f in export.failed_scenes]
        lines += [f"- `{s['key']}`: {s['reason']}" for s in export.skipped]
        lines.append("")
    if not rows:
        return "\n".join(lines + ["No labels were written."]) + "\n"
    scores = np.array([r[key] for r in rows])
    p5, p7 = np.array([r["p_iou_ge_0.5"] for r in rows]), np.array([r["p_iou_ge_0.7"] for r in rows])
    lines += ["## Label quality across the data set", ""]
    lines += _table(["", "mean", "median", "min", "max"],
                    [["P(IoU ≥ 0.5)", p5.mean(), np.median(p5), p5.min(), p5.max()],
                     ["P(IoU ≥ 0.7)", p7.mean(), np.median(p7), p7.min(), p7.max()]])
    edges = [0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0]
    counts = [int(np.sum((scores >= lo) & ((scores < hi) if hi < 1 else (scores <= hi))))
              for lo, hi in zip(edges[:-1], edges[1:])]
    lines += ["", *_table([score_label, "objects"],
                          [[f"{lo:g}–{hi:g}", c] for lo, hi, c in zip(edges[:-1], edges[1:], counts)])]
    if figure:
        lines += ["", "![label quality](quality.png)"]
    lines += ["", f"## Below the minimum quality {score_label} < {min_quality:g}: send back for more annotations", ""]
    if not low:
        lines.append("None.")
    else:
        lines += [f"{len(low)} of {n} objects (also in `needs_annotation.csv`), worst first; the verdict is "
                  f"the advice's (`creference advise`): which request would lift the label to the bar, or "
                  f"that no single request would.", ""]
        if advice_note:
            lines += [f"No verdicts: {advice_note}." if not any(r.get("verdict") for r in low)
                      else f"Note: {advice_note}.", ""]
        lines += _table(["image", "line", "scene", "target", "P(IoU ≥ 0.5)", "P(IoU ≥ 0.7)",
                         "distance sd (m)", "dimension lines", "references", "verdict"],
                        [[r["image"], r["line"], r["scene"], r["target"], r["p_iou_ge_0.5"], r["p_iou_ge_0.7"],
                          r["distance_sd_m"], r["dimension_lines"], r["references"], r.get("advice")] for r in low])
    if calib:
        n_truth = sum(r["count"] for r in next(iter(calib.values())))
        lines += ["", f"## Calibration against ground truth ({n_truth} objects)", "",
                  "Among labels whose predicted probability falls in a bin, the share whose true IoU "
                  "reaches the threshold; calibrated labels have observed ≈ predicted, within about "
                  "2 se by chance.", ""]
        for t, table in calib.items():
            lines += [f"P(IoU ≥ {t:g}):", ""]
            lines += _table(["predicted", "objects", "mean predicted", "observed share", "se"],
                            [[f"{r['low']:.1f}–{r['high']:.1f}", r["count"], r["mean_predicted"],
                              r["observed_share"], r["se"]] for r in table])
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"
