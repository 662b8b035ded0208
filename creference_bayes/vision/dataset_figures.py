"""The data set's figure (matplotlib, imported with this module only): what each frame read of a
quantity its frames share, against the pool ``creference batch`` handed back
(``batch.json``'s ``dataset`` block, :meth:`~creference_bayes.workflows.batch.dataset.DataSet.summary`).

One panel per quantity and group (a camera, the crowd, a setting): each frame's reading (a
target's, for the distances) with its one-sd interval, sorted, in grey where the pool left it out
(too weak); the pooled value and its uncertainty as a band; for a quantity whose frames draw their
values around a common one (a camera's height, the targets' distances), a lighter band of what a
frame is handed (the pool's uncertainty with the spread between frames). The crowd's corner scale
read from the first pass's residuals: each frame's reading √(squares / dof) against the pool and,
where the frames' scales spread, the spread's prior a frame's own reading updates.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

from ..io.validation import _short

__all__ = ["dataset_panels", "dataset_figure"]

_USED, _LEFT_OUT, _POOL = "#1f77b4", "#9a9a9a", "#d62728"


def _number(v, where: str, *, none: bool = False):
    if v is None and none:
        return math.nan
    try:  # (an integer too large for a float: OverflowError)
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(float(v))
    except OverflowError:
        ok = False
    if not ok:
        raise ValueError(f"{where}: expected a finite number, got {_short(v)}")
    return float(v)


#: The widest log-sd a pool's band is drawn for (a factor of e¹⁰ each side: no batch writes more).
MAX_LOG_SD = 10.0


def dataset_panels(summary) -> list[dict]:
    """The panels of :func:`dataset_figure` from a ``dataset`` block, each checked: ``label``,
    ``shared_by``, ``group``, ``log`` (a positive quantity, drawn on a log axis), ``values``
    (n, 3) each reading's value, low and high (NaN: unbounded), ``used`` (n,), ``frames`` (n,)
    whose reading each is, ``center`` and the
    bands ``pool`` and ``prior`` as (low, high) (``prior`` None for a quantity the frames share one
    value of), ``title``. ``ValueError`` names the first key that is not as ``batch`` writes it."""
    if not isinstance(summary, dict):
        raise ValueError(f"dataset: expected an object, got {type(summary).__name__}")
    panels = []
    for label, entry in summary.items():
        where = f"dataset.{label}"
        if not isinstance(entry, dict) or not isinstance(entry.get("groups"), dict):
            raise ValueError(f"{where}.groups: expected an object")
        if entry.get("kind") == "choice":  # the crowd's tail: no readings to draw
            continue
        for group, b in entry["groups"].items():
            at = f"{where}.groups.{group}"
            if not isinstance(b, dict):
                raise ValueError(f"{at}: expected an object")
            if entry.get("kind") == "residuals":  # the corner scale: each frame's reading of its residuals
                if not b.get("values"):
                    continue  # a batch that kept none, or frames whose residuals read no squares
                b = {**b, "median": b.get("sd")}
            values = b.get("values")
            if not isinstance(values, list) or not values:
                raise ValueError(f"{at}.values: expected a list of readings (a batch of this version writes them)")
            rows, used, whose = [], [], []
            for i, r in enumerate(values):
                if not isinstance(r, dict) or not isinstance(r.get("used"), bool):
                    raise ValueError(f"{at}.values[{i}]: expected an object with value, low, high and used")
                rows.append([_number(r.get("value"), f"{at}.values[{i}].value"),
                             _number(r.get("low"), f"{at}.values[{i}].low", none=True),
                             _number(r.get("high"), f"{at}.values[{i}].high", none=True)])
                used.append(r["used"])
                whose.append(str(r.get("frame", i))[:20])
            log = "median" in b
            if log:
                center = _number(b.get("median"), f"{at}.median")
                sd = _number(b.get("log_sd"), f"{at}.log_sd")
                spread = _number(b["spread_log_sd"], f"{at}.spread_log_sd") if "spread_log_sd" in b else None
                if center <= 0:
                    raise ValueError(f"{at}.median: expected a positive number, got {center!r}")
                for key, x in (("log_sd", sd), ("spread_log_sd", spread)):
                    if x is not None and not 0.0 <= x <= MAX_LOG_SD:
                        raise ValueError(f"{at}.{key}: expected a number in [0, {MAX_LOG_SD:g}] (a log-sd), got {x!r}")
                band = lambda s: (center * math.exp(-s), center * math.exp(s))  # noqa: E731
                value = f"{center:.4g}"
            else:
                center = _number(b.get("mean"), f"{at}.mean")
                sd = _number(b.get("sd"), f"{at}.sd")
                spread = _number(b.get("spread_sd"), f"{at}.spread_sd")
                band = lambda s: (center - s, center + s)  # noqa: E731
                value = f"{center:.3g}°"
            frames = b.get("frames")
            held = ", held by every frame" if b.get("held") else ""
            warns = [w for w in b.get("warnings") or [] if isinstance(w, str)] if isinstance(b.get("warnings"), list) else []
            title = (f"{str(label)[:40]}, {str(entry.get('shared_by', ''))[:20]} {str(group)[:40]}: pooled {value} "
                     f"from {frames if isinstance(frames, int) else '?'} frames{held}"
                     + "".join(f"\n{w[:120]}" for w in warns[:3]))
            prior = None if spread is None else band(math.hypot(sd, spread))
            if entry.get("kind") == "residuals" and spread is not None:  # a frame's prior: the frames' spread
                typical = _number(b.get("spread_sd"), f"{at}.spread_sd")
                if typical <= 0:
                    raise ValueError(f"{at}.spread_sd: expected a positive number, got {typical!r}")
                prior = (typical * math.exp(-spread), typical * math.exp(spread))
            panels.append({"label": str(label), "shared_by": str(entry.get("shared_by", "")), "group": str(group),
                           "log": log, "values": np.array(rows), "used": np.array(used), "frames": whose, "center": center,
                           "pool": band(sd), "prior": prior, "title": title, "warned": bool(warns)})
    return panels


def dataset_figure(summary, *, fig: Figure | None = None) -> Figure:
    """The data set's figure (module docstring) from ``batch.json``'s ``dataset`` block; checked by
    :func:`dataset_panels` (``ValueError`` naming the key). A block with nothing to draw (only the
    crowd's tail) gives ``ValueError`` too."""
    panels = dataset_panels(summary)
    if not panels:
        raise ValueError("dataset: no quantity with readings to draw (the batch learnt only the crowd's tail, or a "
                         "corner scale no frame's residuals read)")
    cols = 1 if len(panels) == 1 else 2
    rows = -(-len(panels) // cols)
    if fig is None:
        fig = Figure(figsize=(6.2 * cols, 3.4 * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, p in zip(axes, panels):
        _panel(ax, p)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    return fig


def _panel(ax, p: dict) -> None:
    v, used = p["values"], p["used"]
    order = np.argsort(v[:, 0], kind="stable")
    v, used = v[order], used[order]
    x = np.arange(len(v))
    if p["prior"] is not None:
        ax.axhspan(*p["prior"], color=_POOL, alpha=0.08, lw=0, label="a frame's prior: the pool with the spread")
    ax.axhspan(*p["pool"], color=_POOL, alpha=0.22, lw=0, label="the pool's uncertainty (1 sd)")
    ax.axhline(p["center"], color=_POOL, lw=1.2, label="pooled")
    for sel, colour, name in ((used, _USED, "a reading (1 sd)"), (~used, _LEFT_OUT, "too weak to pool")):
        if not np.any(sel):
            continue
        lo = np.where(np.isfinite(v[sel, 1]), v[sel, 1], v[sel, 0])  # an unbounded side: no whisker
        hi = np.where(np.isfinite(v[sel, 2]), v[sel, 2], v[sel, 0])
        ax.errorbar(x[sel], v[sel, 0], yerr=[v[sel, 0] - lo, hi - v[sel, 0]], fmt="o", ms=3.5, lw=0.8,
                    color=colour, mfc=colour if colour == _USED else "white", label=name)
    if p["log"]:
        ax.set_yscale("log")
        plain = FuncFormatter(lambda y, _: f"{y:g}")
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain)
        ax.tick_params(axis="y", which="minor", labelsize="x-small")
    shown = np.concatenate([v[used, 0], [p["center"]]]) if np.any(used) else v[:, 0]
    lo, hi = float(np.min(shown)), float(np.max(shown))
    if p["log"]:
        ax.set_ylim(lo / 1.5, hi * 1.5)
    else:
        pad = max(hi - lo, 1e-3)
        ax.set_ylim(lo - 0.5 * pad, hi + 0.5 * pad)
    bottom, top = ax.get_ylim()
    for i in np.flatnonzero((v[:, 0] < bottom) | (v[:, 0] > top)):  # a reading off the scale: at its edge
        below = v[i, 0] < bottom
        ax.plot(x[i], bottom if below else top, "v" if below else "^", ms=6, clip_on=False,
                color=_USED if used[i] else _LEFT_OUT, mfc=_USED if used[i] else "white")
        ax.annotate(f"{v[i, 0]:.3g}", (x[i], bottom if below else top), xytext=(3, 4 if below else -10),
                    textcoords="offset points", fontsize="x-small", color=_LEFT_OUT, annotation_clip=False)
    ax.set_xlabel("each frame's reading, sorted" if len(v) == len(set(p["frames"])) else "readings, sorted")
    ax.set_ylabel(p["label"])
    if len(v) > 30:
        ax.set_xticks([])
    else:
        ax.set_xticks(x, [p["frames"][i] for i in order], rotation=90, fontsize="x-small")
    ax.set_title(p["title"], fontsize="small", loc="left", color=_POOL if p["warned"] else "black")
    ax.legend(loc="best", fontsize="x-small")
