"""Fitting a confidence map g from a data set: with ground truth, or from the annotations alone.

**With ground truth** (:func:`fit_with_truth`). g(c) is the probability that a range stated at
confidence c holds its truth, so at each stated level it is estimated by the share of ranges that
do, made non-decreasing in c by weighted isotonic regression (pool-adjacent-violators). The
uncertainty per level is posterior: each level's share gets a Jeffreys Beta(k + ½, n − k + ½)
posterior, and every joint draw is projected onto the monotone maps by the same isotonic
regression (a resampling bootstrap would give a zero-width interval at a level where every range
held the truth, which is common for under-confident workers at 95 % and 99 %). It treats ranges
as independent; workers who answer many times with an own calibration make the real uncertainty
larger. The shape of the distribution a range is read through (normal or Student-t, the map's
``dof``) is the one under which the truths are most likely given g.

**Without ground truth** (:func:`fit_marginal`). Each range j comes with draws of its real length
given all the other annotations of its scene (:mod:`creference_bayes.workflows.confidence.loo`). Its marginal likelihood at
coverage p is

    L_j(p) = mean_d f_D((m_j − log ℓ_jd) / S_j(p)) / S_j(p),   S_j(p)² = (w_j / q_D((1 + p)/2))² + σ²_line,j

(m_j, w_j its log-centre and log half-width, σ²_line,j its line's noise). g at each level
maximises the sum of log L_j of the level's ranges, under the same monotone constraint (PAVA on
the summed likelihoods: exact for unimodal terms), and ``dof`` maximises the total. The profile is
tabulated on a grid of p; the uncertainty per level comes from a bootstrap over scenes (scenes,
not ranges, are resampled: the ranges of one scene share its posterior), which costs sums only.

Levels: the distinct stated confidences (up to :data:`MAX_LEVELS`, else that many quantile bins,
each at its mean confidence); levels with fewer than ``min_per_level`` ranges are left out (the
map interpolates there). A measure and mode (``"length/direct"``, …) with at least ``min_group``
ranges gets a curve of its own; the others use the pooled curve.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import isotonic_regression
from scipy.special import expit, gammaln, logit

from ...models.confidence_map import ConfidenceMap, CoverageCurve, interval_quantile

__all__ = ["DOF_GRID", "MAX_LEVELS", "assign_levels", "kept_levels", "fit_with_truth", "fit_marginal"]

#: The shapes a fit chooses from: Student-t degrees of freedom, None for the normal.
DOF_GRID = (1.0, 2.0, 3.0, 5.0, 10.0, 30.0, None)
#: At most this many levels; more distinct confidences are binned.
MAX_LEVELS = 12
#: The coverage grid of the marginal likelihood (uniform in logit).
_P_GRID = expit(np.linspace(logit(0.01), logit(0.999), 161))


def assign_levels(conf, max_levels: int = MAX_LEVELS) -> tuple[np.ndarray, np.ndarray]:
    """(levels (k,), level index of each confidence (n,)): the distinct confidences, or
    ``max_levels`` quantile bins at their mean confidence."""
    conf = np.asarray(conf, float)
    r = np.round(conf, 4)
    u = np.unique(r)
    if len(u) <= max_levels:
        return u, np.searchsorted(u, r)
    edges = np.unique(np.quantile(conf, np.linspace(0, 1, max_levels + 1)))
    idx = np.clip(np.searchsorted(edges, conf, side="right") - 1, 0, len(edges) - 2)
    used = np.unique(idx)
    idx = np.searchsorted(used, idx)
    return np.array([conf[idx == k].mean() for k in range(len(used))]), idx


def kept_levels(conf, min_per_level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The levels of ``conf`` (:func:`assign_levels`), each range's level, the ranges per level and
    which levels have at least ``min_per_level``. ValueError when none has, or when only one of
    several has: a map of one level reads every other confidence as that one (it is flat outside
    its levels)."""
    levels, idx = assign_levels(conf)
    n = np.bincount(idx, minlength=len(levels))
    keep = n >= min_per_level
    counts = ", ".join(f"{c:g}: {k}" for c, k in zip(levels, n))
    if not keep.any() or (keep.sum() == 1 and len(levels) > 1):
        raise ValueError(f"{'no' if not keep.any() else 'only one'} confidence level has {min_per_level} ranges or "
                         f"more (--min-per-level; ranges per level {counts}): fit on more scenes, or lower "
                         "--min-per-level")
    return levels, idx, n, keep


def _scene_index(ranges) -> tuple[np.ndarray, int]:
    keys = {}
    idx = np.array([keys.setdefault(r.scene, len(keys)) for r in ranges])
    return idx, len(keys)


def _summary(point, boots, levels, n, prob) -> CoverageCurve:
    a = (1.0 - prob) / 2.0
    low, high = np.nanquantile(boots, [a, 1.0 - a], axis=0)
    return CoverageCurve(tuple(float(v) for v in levels), tuple(float(v) for v in point),
                         tuple(float(v) for v in np.minimum(low, point)),
                         tuple(float(v) for v in np.maximum(high, point)),
                         tuple(float(v) for v in np.nanstd(boots, axis=0, ddof=1)), tuple(int(v) for v in n))


def _groups(ranges, min_group: int) -> dict[str, list[int]]:
    by: dict[str, list[int]] = {}
    for i, r in enumerate(ranges):
        by.setdefault(r.group, []).append(i)
    return {g: ix for g, ix in sorted(by.items()) if len(ix) >= min_group and len(by) > 1}


# -- with ground truth ------------------------------------------------------------------------------
def _truth_curve(covered, conf, draws, rng, min_per_level, prob):
    levels, idx, n, keep = kept_levels(conf, min_per_level)
    n = n.astype(float)
    k = np.bincount(idx, weights=covered.astype(float), minlength=len(levels))
    n, k, levels = n[keep], k[keep], levels[keep]
    point = isotonic_regression(k / n, weights=n).x
    post = rng.beta(k + 0.5, n - k + 0.5, size=(draws, len(n)))
    post = np.array([isotonic_regression(row, weights=n).x for row in post])
    return _summary(point, post, levels, n, prob), int((~keep).sum())


def _truth_dof(ranges, cmap: ConfidenceMap, dof_grid) -> tuple[float | None, dict]:
    """The shape under which the truths are most likely, given the map's coverage."""
    m = np.array([r.centre for r in ranges])
    w = np.array([r.half_width for r in ranges])
    x = np.log([r.truth for r in ranges])
    g = np.array([float(cmap.coverage(r.confidence, r.measure, r.mode)) for r in ranges])
    ll = {}
    for dof in dof_grid:
        s = w / interval_quantile(g, dof)
        u = (x - m) / s
        ll[dof] = float(np.sum(_log_density(u, dof) - np.log(s)))
    best = max(ll, key=ll.get)
    return best, {("normal" if k is None else f"t{k:g}"): round(v, 3) for k, v in ll.items()}


def fit_with_truth(ranges, *, draws: int = 1000, seed=0, interval_prob: float = 0.95,
                   min_per_level: int = 10, min_group: int = 200, dof_grid=DOF_GRID) -> ConfidenceMap:
    """Fit g from ranges with a known truth (module docstring).

    Parameters
    ----------
    ranges : :class:`~creference_bayes.workflows.confidence.data.StatedRange` (those without a truth are left out)
    draws : posterior draws of the curve
    seed : seed of the draws
    interval_prob : probability of each level's interval
    min_per_level : fewer ranges at a level leave it out
    min_group : a measure and mode with at least this many ranges gets its own curve
    dof_grid : the shapes to choose from

    Returns
    -------
    ConfidenceMap (``kind`` "fitted", ``fit["method"]`` "truth")
    """
    ranges = [r for r in ranges if r.truth is not None]
    if not ranges:
        raise ValueError("no range with a stated confidence and a known truth: nothing to fit")
    rng = np.random.default_rng(seed)
    _, n_scenes = _scene_index(ranges)
    covered = np.array([r.covered for r in ranges])
    conf = np.array([r.confidence for r in ranges])
    pooled, dropped = _truth_curve(covered, conf, draws, rng, min_per_level, interval_prob)
    groups = {}
    for g, ix in _groups(ranges, min_group).items():
        ix = np.array(ix)
        groups[g], _ = _truth_curve(covered[ix], conf[ix], draws, rng, min_per_level, interval_prob)
    cmap = ConfidenceMap(kind="fitted", pooled=pooled, groups=groups, interval_prob=interval_prob)
    dof, ll = _truth_dof(ranges, cmap, dof_grid)
    sources = sorted({r.truth_source for r in ranges})
    return ConfidenceMap(kind="fitted", pooled=pooled, groups=groups, dof=dof, interval_prob=interval_prob,
                         fit={"method": "truth", "truth": sources, "scenes": n_scenes, "ranges": len(ranges),
                              "levels_left_out": dropped, "uncertainty": "posterior (Jeffreys per level, "
                              "projected onto monotone maps)", "draws": draws, "seed": seed,
                              "dof_log_likelihood": ll})


# -- without ground truth -----------------------------------------------------------------------------
def _log_density(u: np.ndarray, dof: float | None) -> np.ndarray:
    """log f_D(u) of the standard normal (``dof`` None) or Student-t."""
    if dof is None:
        return -0.5 * u * u - 0.5 * np.log(2.0 * np.pi)
    const = gammaln(0.5 * (dof + 1.0)) - gammaln(0.5 * dof) - 0.5 * np.log(dof * np.pi)
    return const - 0.5 * (dof + 1.0) * np.log1p(u * u / dof)


def _marginal_table(preds, dof) -> np.ndarray:
    """(n, P) log L_j(p) on the coverage grid (module docstring)."""
    q = interval_quantile(_P_GRID, dof)  # (P,)
    out = np.empty((len(preds), len(_P_GRID)))
    for j, pr in enumerate(preds):
        r = pr.range
        S = np.sqrt((r.half_width / q) ** 2 + pr.line_var)  # (P,)
        u = (r.centre - pr.log_length[:, None]) * (1.0 / S)[None, :]  # (D, P)
        dens = _log_density(u, dof)
        top = dens.max(axis=0)
        out[j] = top + np.log(np.exp(dens - top).mean(axis=0)) - np.log(S)
    return out


def _argmax(f: np.ndarray) -> tuple[float, float]:
    """(p, value) at the maximum of a profile on the grid, refined by a parabola in logit p."""
    i = int(np.argmax(f))
    if 0 < i < len(f) - 1:
        den = f[i - 1] - 2.0 * f[i] + f[i + 1]
        d = 0.5 * (f[i - 1] - f[i + 1]) / den if den < 0 else 0.0
        lg = logit(_P_GRID)
        return float(expit(lg[i] + d * (lg[1] - lg[0]))), float(f[i])
    return float(_P_GRID[i]), float(f[i])


def _pava(tables: np.ndarray) -> tuple[np.ndarray, float]:
    """Non-decreasing maximisers of the (L, P) level profiles: (p (L,), total log-likelihood)."""
    blocks = []  # [summed profile, first level, last level, argmax]
    for lvl, f in enumerate(tables):
        blocks.append([f.copy(), lvl, lvl, _argmax(f)])
        while len(blocks) > 1 and blocks[-2][3][0] > blocks[-1][3][0]:
            f2, a, _, _ = blocks.pop(-2)
            top = blocks[-1]
            top[0] = top[0] + f2
            top[1] = a
            top[3] = _argmax(top[0])
    p = np.empty(len(tables))
    for f, a, b, (pb, _) in blocks:
        p[a:b + 1] = pb
    return p, float(sum(val for *_, (_, val) in blocks))


def _marginal_curve(table, conf, scene_idx, n_scenes, W, min_per_level, prob):
    levels, idx, n, keep = kept_levels(conf, min_per_level)
    T = np.zeros((n_scenes, len(levels), table.shape[1]))
    np.add.at(T, (scene_idx, idx), table)
    T = T[:, keep]
    point, total = _pava(T.sum(axis=0))
    boots = np.array([_pava(t)[0] for t in np.einsum("bs,slp->blp", W, T)])
    return _summary(point, boots, levels[keep], n[keep], prob), total, int((~keep).sum())


def fit_marginal(predictions, *, draws: int = 1000, seed=0, interval_prob: float = 0.95,
                 min_per_level: int = 10, min_group: int = 200, dof_grid=DOF_GRID) -> ConfidenceMap:
    """Fit g without ground truth, from leave-one-out length posteriors (module docstring).

    Parameters
    ----------
    predictions : :class:`~creference_bayes.workflows.confidence.loo.RangePrediction` of the data set
    draws : bootstrap samples over scenes
    seed, interval_prob, min_per_level, min_group, dof_grid : as :func:`fit_with_truth`

    Returns
    -------
    ConfidenceMap (``kind`` "fitted", ``fit["method"]`` "marginal")
    """
    preds = list(predictions)
    if not preds:
        raise ValueError("no range with a stated confidence: nothing to fit")
    rng = np.random.default_rng(seed)
    ranges = [p.range for p in preds]
    scene_idx, n_scenes = _scene_index(ranges)
    W = rng.multinomial(n_scenes, np.full(n_scenes, 1.0 / n_scenes), size=draws).astype(float)  # (B, S)
    conf = np.array([r.confidence for r in ranges])
    fits, ll = {}, {}
    for dof in dof_grid:
        table = _marginal_table(preds, dof)
        curve, total, dropped = _marginal_curve(table, conf, scene_idx, n_scenes, W, min_per_level, interval_prob)
        fits[dof] = (table, curve, dropped)
        ll["normal" if dof is None else f"t{dof:g}"] = round(total, 3)
    dof = max(fits, key=lambda d: ll["normal" if d is None else f"t{d:g}"])
    table, pooled, dropped = fits[dof]
    groups = {}
    for g, ix in _groups(ranges, min_group).items():
        ix = np.array(ix)
        groups[g], _, _ = _marginal_curve(table[ix], conf[ix], scene_idx[ix], n_scenes, W, min_per_level,
                                          interval_prob)
    return ConfidenceMap(kind="fitted", pooled=pooled, groups=groups, dof=dof, interval_prob=interval_prob,
                         fit={"method": "marginal", "scenes": n_scenes, "ranges": len(preds),
                              "levels_left_out": dropped, "uncertainty": "bootstrap over scenes",
                              "draws": draws, "seed": seed, "refits": int(sum(p.refit for p in preds)),
                              "dof_log_likelihood": ll})
