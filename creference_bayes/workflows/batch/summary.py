"""The batch's summary table (``summary.csv``, one row per target of every scene) and its closing line."""

from __future__ import annotations

from pathlib import Path

from ...io.files import atomic_write_csv
from ...io.validation import read_json

__all__ = ["SUMMARY_COLUMNS", "summary_rows", "write_summary", "summary_line"]

#: Columns of ``summary.csv``. Distances are the ground distance √(x² + z²) from the camera's foot
#: point, metres; errors are Eq. 3's location error, percent, present only with ground truth.
#: ``class`` is the target's class (empty without one); ``converged`` is the scene's (its sampler
#: converges for all its targets or not at all).
SUMMARY_COLUMNS = ("scene", "target", "class", "image", "status", "map_distance_m", "mean_distance_m",
                   "sd_distance_m", "hdi_low_m", "hdi_high_m", "hdi_prob", "converged",
                   "location_error_pct", "posterior_location_error_pct", "n_warnings", "warnings",
                   "error")


def _read(path: Path) -> dict | None:
    try:
        return read_json(path)
    except (OSError, ValueError):
        return None


def _rows(out: Path, key: str, status: str, error: str | None) -> list[dict]:
    """The rows of one scene: one per target of its result, or one naming its error."""
    base = dict.fromkeys(SUMMARY_COLUMNS, "")
    base.update(scene=key, status={"done": "ok", "skipped": "ok"}.get(status, status))
    copy = _read(out / "scenes" / f"{key}.json") or {}
    image = (copy.get("image") or {}).get("path")
    base["image"] = Path(image).name if image else ""
    if status not in ("done", "skipped"):
        return [dict(base, error=error or "")]
    d = _read(out / "results" / f"{key}.json") or {}
    diag, warns = d.get("diagnostics"), d.get("warnings", [])
    rows = []
    for o in d.get("objects", []):
        row = dict(base, target=o.get("id", ""), **{"class": o.get("class") or ""})
        row["map_distance_m"] = _num((o.get("map") or {}).get("distance_m"))
        post = o.get("posterior")
        if post:
            row["mean_distance_m"] = _num(post["mean"].get("distance_m"))
            row["sd_distance_m"] = _num(post["sd"].get("distance_m"))
            lo, hi = post["hdi"].get("distance_m", [None, None])
            row.update(hdi_low_m=_num(lo), hdi_high_m=_num(hi), hdi_prob=post["hdi"].get("prob", ""))
        if diag is not None:
            row["converged"] = str(bool(diag.get("converged"))).lower()
        ev = o.get("evaluation") or {}
        row["location_error_pct"] = _num(ev.get("location_pct_error"))
        row["posterior_location_error_pct"] = _num(ev.get("posterior_location_pct_error"))
        row.update(n_warnings=len(warns), warnings=" | ".join(warns))
        rows.append(row)
    return rows or [base]


def _num(v) -> str:
    return "" if v is None else f"{float(v):.6g}"


def summary_rows(out: str | Path, scenes, report) -> list[dict]:
    """One row per target of the batch (a scene's targets in their order; one row for a scene that
    failed), scenes in the order of the inputs."""
    out = Path(out)
    return [row for si in scenes for row in _rows(out, si.key, report.status[si.key], report.errors.get(si.key))]


def write_summary(out: str | Path, scenes, report, rows: list[dict] | None = None) -> Path:
    """Write ``summary.csv`` in the batch folder (atomically; ``rows``: :func:`summary_rows`, if
    already read) and return its path."""
    return atomic_write_csv(Path(out) / "summary.csv", summary_rows(out, scenes, report) if rows is None else rows,
                            SUMMARY_COLUMNS)


def summary_line(report, out: str | Path | None = None) -> str:
    """``47 scenes: 38 estimated, 2 already done, 7 failed in 95.2 s (24.0 targets/min on …)``; a scene
    whose posterior did not converge (estimated now or already done) is counted apart: ``48 scenes:
    46 estimated and converged, 1 already done, 1 not converged (see summary.csv), 0 failed …``."""
    n = len(report.status)
    bad = set(report.not_converged)
    count = lambda status: sum(k not in bad for k in report.keys(status))
    parts = [f"{count('done')} estimated" + (" and converged" if bad else "")]
    if count("skipped"):
        parts.append(f"{count('skipped')} already done")
    if bad:
        parts.append(f"{len(bad)} not converged (see summary.csv)")
    parts.append(f"{len(report.keys('failed'))} failed")
    if report.keys("not run"):
        parts.append(f"{len(report.keys('not run'))} not run")
    rate = report.targets_per_minute
    speed = f"{rate:.1f} targets/min on {report.engine}" if rate else report.engine
    line = f"{n} scene{'s' if n != 1 else ''}: {', '.join(parts)} in {report.seconds:.1f} s ({speed})"
    if out is not None:
        line += f"; summary: {Path(out) / 'summary.csv'}"
    return line
