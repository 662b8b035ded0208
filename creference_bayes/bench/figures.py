"""The benchmark's figures (matplotlib). Each function takes a bench document (or its summary)
and returns a Figure; :func:`write_figures` saves them all as PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .report import TIER_ORDER as TIERS
from .report import _sel, estimator_rows

__all__ = ["error_by_tier", "error_vs_refs", "same_time", "pairs", "calibration", "sweep", "timing",
           "write_figures"]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _figure(fig, size):
    """``fig``, or a new figure of ``size`` inches."""
    return fig or _plt().figure(figsize=size)


def _laid_out(fig):
    fig.tight_layout()
    return fig


#: The families of estimators by colour (tab10, far apart), for :func:`error_by_tier`.
_FAMILY_COLOURS = {"paper": "C0", "p4pf": "C7", "ours-paper": "C1", "ours-metrology": "C3",
                   "ours-metrology-nohorizon": "C4", "ours-metrology-flatfocal": "C2", "crb": "k"}


def _tier_panels(doc: dict) -> list[tuple[str, list]]:
    """The rows of :func:`~.report.estimator_rows` split into two readable panels: the estimators
    with the references, and the metrology MAP's camera studies (the other rows are in bench.md)."""
    rows = estimator_rows(doc)
    nref = max(doc["config"]["ref_counts"])

    def pick(est, k=None, key="error"):
        return [r for r in rows if r[1].get("estimator") == est and r[2] == key
                and (k is None or r[1].get("n_refs") == k)]

    first = (pick("paper") + pick("p4pf") + pick("ours-paper", nref) + pick("ours-metrology", nref)
             + pick("ours-metrology", nref, "post_error") + pick("crb-refs"))
    second = (pick("ours-metrology", 0) + pick("ours-metrology", nref) + pick("ours-metrology-nohorizon", 0)
              + pick("ours-metrology-nohorizon", nref) + pick("ours-metrology-flatfocal", 0)
              + pick("ours-metrology-flatfocal", nref) + pick("crb-target") + pick("crb-refs-nohorizon"))
    return [(f"the estimators ({nref} references; p4pf: the target only)", first),
            ("the metrology MAP: references, the horizon, the focal prior", second)]


def _style(sel: dict, key: str) -> dict:
    """Colour by family, marker by quantity (MAP ●, posterior mean ◆, bound ▬), open for no references."""
    est = sel.get("estimator", "")
    family = "crb" if est.startswith("crb") else est
    colour = "0.55" if est == "crb-refs-nohorizon" else _FAMILY_COLOURS.get(family, "C9")
    marker = "_" if family == "crb" else ("D" if key == "post_error" else "o")
    no_refs = sel.get("n_refs") == 0 or est in ("crb-target", "crb-target-nohorizon", "p4pf")
    return dict(color=colour, marker=marker, ms=14 if marker == "_" else 6, mew=2 if marker == "_" else 1.2,
                mfc="white" if no_refs and marker != "_" else colour,
                ls=":" if "nohorizon" in est and family == "crb" else "-")


def error_by_tier(doc: dict, fig=None):
    """Median location error per tier (bars: interquartile range), log scale, in two panels of a
    few distinct series each: colour = estimator family, marker = MAP (●) / posterior mean (◆) /
    Cramér–Rao bound (▬), open marker = no references."""
    panels = _tier_panels(doc)
    fig = _figure(fig, (12, 6.4))
    axes = fig.subplots(1, len(panels), sharey=True)
    for ax, (title, rows) in zip(np.atleast_1d(axes), panels):
        width = 0.8 / max(len(rows), 1)
        for i, (label, sel, key) in enumerate(rows):
            style = _style(sel, key)
            ls = style.pop("ls")
            for j, t in enumerate(TIERS):
                v = np.array([r.get(key) for r in _sel(doc["records"], tier=t, **sel) if r.get(key) is not None],
                             float)
                v = np.maximum(v[np.isfinite(v)], 1e-4)
                if v.size == 0:
                    continue
                q1, med, q3 = np.percentile(v, [25, 50, 75])
                x = j - 0.4 + (i + 0.5) * width
                bars = ax.errorbar(x, med, yerr=[[med - q1], [q3 - med]], fmt="none", ecolor=style["color"],
                                   elinewidth=1.2, alpha=0.6)
                if ls != "-":
                    bars[2][0].set_linestyle(ls)
                ax.plot([x], [med], ls="none", label=label if j == 0 or label not in
                        ax.get_legend_handles_labels()[1] else None, **style)
        ax.set_xticks(range(len(TIERS)), list(TIERS))
        for j in range(1, len(TIERS)):
            ax.axvline(j - 0.5, color="0.85", lw=0.8)
        ax.set(yscale="log", xlabel="noise tier")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", axis="y", alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        uniq = dict(zip(labels, handles))
        ax.legend(uniq.values(), uniq.keys(), fontsize=7.5, loc="upper center", ncol=2,
                  bbox_to_anchor=(0.5, -0.13), frameon=False)
    np.atleast_1d(axes)[0].set_ylabel("location error, % (Eq. 3)")
    fig.suptitle("Location error by noise tier: median (marker) and interquartile range (bar); "
                 "errors below 1e-4 % drawn at 1e-4 %; open marker: no references", fontsize=10)
    return _laid_out(fig)


def error_vs_refs(summary: dict, fig=None):
    """Mean (solid) and median (dashed) error against the number of references (Fig. 10)."""
    fig = _figure(fig, (11, 4.5))
    cmap = _plt().get_cmap("tab10")
    for p, setting in enumerate(("indoor", "outdoor")):
        ax = fig.add_subplot(1, 2, p + 1)
        block = summary["vs_refs"].get(setting, {})
        for i, (name, row) in enumerate(block.items()):
            ks = sorted(int(k) for k in row)
            mean = [row[k if k in row else str(k)]["mean"] for k in ks]
            med = [row[k if k in row else str(k)]["median"] for k in ks]
            style = dict(color=cmap(i), marker="o" if len(ks) > 1 else "s", ms=5)
            ax.plot(ks, mean, "-", label=f"{name} (mean)", **style)
            ax.plot(ks, med, "--", alpha=0.7, **style)
        ax.set(yscale="log", xlabel="number of references", ylabel="location error, %",
               title=f"{setting}: mean (solid), median (dashed)")
        ax.grid(True, alpha=0.3)
        if p == 1:
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _laid_out(fig)


def same_time(summary: dict, fig=None):
    """Analysis 2: 10 target annotations against 5 target + 5 references (mean and median)."""
    fig = _figure(fig, (7.5, 4.2))
    ax = fig.add_subplot(111)
    st = summary["same_time"]
    names = [k for k in st if k != "human_seconds"]
    hs = st["human_seconds"]
    x = np.arange(len(names))
    ticks = [f"{n}\n(n = {st[n]['baseline']['n']} scenes)" for n in names]
    for off, key, label in ((-0.2, "baseline", f"10 target ({hs['baseline']:.0f} s of work)"),
                            (0.2, "c-reference", f"5 target + 5 refs ({hs['c-reference']:.0f} s)")):
        means = [st[n][key]["mean"] for n in names]
        meds = [st[n][key]["median"] for n in names]
        ax.bar(x + off, means, 0.38, label=f"{label}: mean", alpha=0.8)
        ax.scatter(x + off, meds, color="k", marker="_", s=300, zorder=3)
    ax.set_xticks(x, ticks)
    ax.set(yscale="log", ylabel="location error, % (bar: mean, line: median)",
           title="Same human time (paper Analysis 2)")
    ax.legend(fontsize=8)
    return _laid_out(fig)


def pairs(summary: dict, fig=None):
    """Fig. 11: mean error with two references, skipped against used pairs, per pair type."""
    blocks = summary["pairs"]
    fig = _figure(fig, (11, 4.2))
    for p, (model, block) in enumerate(blocks.items()):
        ax = fig.add_subplot(1, len(blocks), p + 1)
        kinds = list(block)
        x = np.arange(len(kinds))
        for off, g, c in ((-0.2, "skipped", "tab:red"), (0.2, "used", "tab:blue")):
            vals = [block[k][g].get("mean", np.nan) for k in kinds]
            ns = [block[k][g]["n"] for k in kinds]
            ax.bar(x + off, vals, 0.38, color=c, alpha=0.8, label=g)
            for xi, v, n in zip(x + off, vals, ns):
                if n:
                    ax.annotate(str(n), (xi, v), ha="center", va="bottom", fontsize=7)
        ax.set_xticks(x, kinds, rotation=30, ha="right", fontsize=8)
        ax.set(yscale="log", ylabel="mean location error, %",
               title=f"ours-{model}, 2 references (n above bars)")
        ax.legend(fontsize=8)
    return _laid_out(fig)


def _coverage_bars(ax, x, values, label: str):
    """Bars of the 50 % and 90 % HDI coverage (``values(level)`` per x) with their nominal lines."""
    for off, lvl, col in ((-0.2, "50", "tab:orange"), (0.2, "90", "tab:blue")):
        ax.bar(x + off, values(lvl), 0.38, color=col, label=label.format(lvl))
        ax.axhline(int(lvl) / 100, color=col, ls="--", lw=1)
    ax.set_ylim(0, 1.05)


def calibration(summary: dict, fig=None):
    """Coverage of the 50 % and 90 % HDIs per parameter, and rank histograms, per model."""
    cal = summary["calibration"]
    params = ("x", "y", "z", "yaw", "focal_length_px", "distance_m")
    fig = _figure(fig, (13, 3.2 * len(cal)))
    for m, (model, c) in enumerate(cal.items()):
        ax = fig.add_subplot(len(cal), 1 + len(params), m * (1 + len(params)) + 1)
        x = np.arange(len(params))
        _coverage_bars(ax, x, lambda lvl, c=c: [c["all"].get(p, {}).get(lvl, np.nan) for p in params], "{} %")
        ax.set_xticks(x, ["x", "y", "z", "yaw", "µ", "d"], fontsize=8)
        ax.set_title(f"ours-{model} (T={c['temperature']:g})\ncoverage", fontsize=9)
        ax.legend(fontsize=7, loc="lower left")
        for i, p in enumerate(params):
            a = fig.add_subplot(len(cal), 1 + len(params), m * (1 + len(params)) + 2 + i)
            h = np.asarray(c["ranks"].get(p, []), float)
            if h.size:
                a.bar(np.arange(h.size) + 0.5, h, 1.0, color="0.6", edgecolor="k", lw=0.5)
                a.axhline(h.sum() / h.size, color="r", lw=1)
            a.set_title(f"rank of true {p}", fontsize=8)
            a.set_xticks([])
            a.tick_params(labelsize=7)
    return _laid_out(fig)


def sweep(summary: dict, fig=None):
    """Coverage of the ground distance's 50 % and 90 % HDIs for each (σ, T) of the paper model."""
    sw = summary["sweep"]
    fig = _figure(fig, (8, 4))
    ax = fig.add_subplot(111)
    keys = list(sw)
    x = np.arange(len(keys))
    _coverage_bars(ax, x, lambda lvl: [sw[k]["all"].get("distance_m", {}).get(lvl, np.nan) for k in keys],
                   "{} % HDI")
    ax.set_xticks(x, [k.replace(", ", "\n") for k in keys], fontsize=8)
    ax.set(ylabel="share of scenes with the true distance inside",
           title="Paper model posterior: coverage against σ (Eq. 5) and temperature T")
    ax.legend(fontsize=8)
    return _laid_out(fig)


def timing(summary: dict, fig=None):
    """Median time per target, and its ratio to the ``paper`` preset."""
    t = summary["timing"]
    fig = _figure(fig, (7.5, 3.8))
    ax = fig.add_subplot(111)
    names = list(t)
    ax.barh(names, [t[n]["seconds"] for n in names], color="tab:gray")
    for i, n in enumerate(names):
        ax.annotate(f" ×{t[n]['ratio']:.3g}", (t[n]["seconds"], i), va="center", fontsize=8)
    ax.set(xscale="log", xlabel="seconds per target (median); label: ratio to the paper preset",
           title="Time per target")
    return _laid_out(fig)


def write_figures(doc: dict, outdir) -> list[Path]:
    """Save every figure as ``bench_*.png`` in ``outdir``; returns the paths."""
    plt = _plt()
    outdir = Path(outdir)
    s = doc["summary"]
    figs = {"bench_error_by_tier.png": error_by_tier(doc), "bench_error_vs_refs.png": error_vs_refs(s),
            "bench_same_time.png": same_time(s), "bench_timing.png": timing(s)}
    if s["pairs"]:
        figs["bench_pairs.png"] = pairs(s)
    if s["calibration"]:
        figs["bench_calibration.png"] = calibration(s)
    if s["sweep"]:
        figs["bench_sweep.png"] = sweep(s)
    paths = []
    for name, fig in figs.items():
        fig.savefig(outdir / name, dpi=110)
        plt.close(fig)
        paths.append(outdir / name)
    return paths
