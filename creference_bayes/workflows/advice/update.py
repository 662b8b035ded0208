"""The cheap update behind the advice: posterior draws reweighted by a simulated annotation, the
effective-sample-size check, the fallbacks when the weights collapse (a tempered resample-move
run; an affine transport for an answer that enters as a normal prior), and the weighted
summaries the advice reports (NumPy only).

For M simulated annotations and N current draws the weights form an (M, N) matrix: row i is the
posterior after the i-th simulated annotation, as importance weights p(new_i | θ_j) on the draws
θ_j (the draws are from the current posterior, so the ratio of the new posterior to the current
one is the new annotation's likelihood, including whatever else adding it changes in the model).
"""

from __future__ import annotations

import numpy as np

from .iou import iou_3d_at_least

__all__ = ["MIN_ESS", "MIN_ESS_FRACTION", "SHUFFLES", "SCREEN_SD", "normalise", "informative", "weighted_hdi",
           "shuffled_hdi",
           "location_sd", "mean_boxes", "p_iou", "systematic_resample", "tempered_update", "gaussian_transport"]

#: A row of weights whose effective sample size is below max(MIN_ESS, MIN_ESS_FRACTION · N) is
#: not trusted: that simulated future is recomputed by :func:`tempered_update` (an annotation) or
#: :func:`gaussian_transport` (a size, a mounting) (docs/advice_method.md).
MIN_ESS = 10.0
MIN_ESS_FRACTION = 0.01
#: Shuffles :func:`shuffled_hdi` averages over (for a row of few effective draws).
SHUFFLES = 8
#: A row of weights with more than N / SHUFFLE_SHARE effective draws is shuffled fewer times
#: (:func:`shuffled_hdi`).
SHUFFLE_SHARE = 8
#: Draws :func:`weighted_hdi` bounds together before it computes their intervals one by one.
HDI_BLOCK = 8
#: Weights (rows × quantities × draws) :func:`shuffled_hdi` passes to one call of
#: :func:`weighted_hdi` (its memory is a few dozen bytes each).
HDI_CALL_SIZE = 2_000_000
#: :func:`informative`: an object is read where one of its features' summed z² over the rows
#: exceeds its chi-square's mean by this many of its standard deviations.
SCREEN_SD = 3.0


def normalise(log_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of log-weights (M, N) → normalised weights (M, N) and each row's ESS (M,).

    A row with no finite weight gets ESS 0 (and uniform weights, to be replaced by the caller).
    """
    log_w = np.atleast_2d(np.asarray(log_w, float))
    top = np.max(np.where(np.isfinite(log_w), log_w, -np.inf), axis=1, keepdims=True)
    dead = ~np.isfinite(top[:, 0])
    with np.errstate(invalid="ignore"):
        w = np.exp(np.where(np.isfinite(log_w), log_w - np.where(dead[:, None], 0.0, top), -np.inf))
    w[dead] = 1.0
    w /= w.sum(axis=1, keepdims=True)
    ess = 1.0 / np.sum(w * w, axis=1)
    ess[dead] = 0.0
    return w, ess


def informative(features: np.ndarray, weights: np.ndarray, sd: float | None = None) -> np.ndarray:
    """(m,) whether rows of ``weights`` (M, N) say anything about each of m objects, from
    features (N, m) or (N, m, p) of its draws (its distance, say).

    Weights that say nothing about a feature f are, to f, a random order of themselves: a row's
    weighted mean then scatters around f's mean with variance var f · (N Σw² − 1) / (N − 1), and
    z² = (weighted mean − mean)² / that variance, summed over the M rows, follows a chi-square of
    M degrees of freedom. Futures simulated from the posterior keep its variance on average
    (var f = E[var f in a future] + var(a future's mean)), so the sum's excess over M is what the
    rows take off f's variance, in units of its noise: an object is informative where some
    feature's sum exceeds M + ``sd`` · √(2M) (default :data:`SCREEN_SD`). What the rows would say
    of one that is not is noise around nothing (features constant over the draws are left out).
    """
    sd = SCREEN_SD if sd is None else sd
    f = np.asarray(features, float)
    f = f[..., None] if f.ndim == 2 else f
    w = np.atleast_2d(np.asarray(weights, float))
    big_m, n = w.shape
    flat = f.reshape(n, -1)
    mean = flat.mean(axis=0)
    var = flat.var(axis=0)
    live = var > 1e-12 * np.maximum(mean * mean, 1.0)
    scale = (n * np.sum(w * w, axis=1) - 1.0) / (n - 1.0)                      # (M,)
    dev = w @ flat[:, live] - mean[live]                                        # (M, live)
    z2 = np.zeros(flat.shape[1])
    z2[live] = np.sum(dev * dev / np.maximum(scale, 1e-12)[:, None], axis=0) / var[live]
    return np.any(z2.reshape(f.shape[1:]) > big_m + sd * np.sqrt(2.0 * big_m), axis=1)


def weighted_hdi(values: np.ndarray, weights: np.ndarray, prob: float,
                 order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Shortest interval holding ``prob`` of the weight, and the weighted median, per row of
    weights and column of values.

    Each draw's weight is spread evenly around it (draw i sits at the cumulative weight
    W_{i-1} + w_i / 2) and the distribution function is interpolated linearly between draws, so
    the interval's ends and the median move continuously with the weights (counting whole draws
    overshoots ``prob`` more for uneven weights than for even ones).

    Parameters
    ----------
    values : (N,) draws of one quantity, or (N, k) of k quantities
    weights : (M, N) normalised weights (zeros allowed), or (k, M, N) each quantity's own
    prob : in (0, 1)
    order : (k, N) each column's draws in increasing order (``np.argsort(values, axis=0).T``), when
        the caller sorts once for many calls on the same values

    Returns
    -------
    width, median: (M,) for (N,) values, (M, k) for (N, k), in the unit of ``values``
    """
    values = np.asarray(values, float)
    vals = values[:, None] if values.ndim == 1 else values
    w = np.asarray(weights, float)
    own = w.ndim == 3  # each quantity its own rows of weights
    w = w if own else np.atleast_2d(w)
    big_m, n = w.shape[-2:]
    k = vals.shape[1]
    if not k:  # no quantity (none read)
        return np.zeros((big_m, 0)), np.zeros((big_m, 0))
    order = np.argsort(vals, axis=0).T if order is None else np.asarray(order).reshape(k, n)   # (k, N)
    v = np.take_along_axis(vals.T, order, axis=1)                       # (k, N) each column sorted
    sorted_w = np.empty((k, big_m, n))                                  # row t·M + i: weights i, quantity t
    for t in range(k):  # one quantity at a time: a gather (M, k, N) then transposed costs several times more
        np.take(w[t] if own else w, order[t], axis=1, out=sorted_w[t], mode="clip")  # "clip": unbuffered
    w = sorted_w.reshape(k * big_m, n)
    rows = len(w)
    every = np.arange(rows)
    vflat = v.ravel()
    to_v = every // big_m * n - every * n  # entry g of the flat weights (row r from r · n) → g + to_v[r] of vflat
    # positions of the draws on the weight axis, strictly increasing within a row
    c = np.cumsum(w, axis=1)
    c -= 0.5 * w
    c += np.arange(n) * 1e-15
    flat = c.ravel()
    shifted = c + 2.0 * every[:, None]  # rows apart on one axis (c is within [0, 1])
    shifted = shifted.ravel()

    def at(r, p):  # the values of rows r at weight positions p (1-D), interpolated between draws
        lo = r * n
        g = np.searchsorted(shifted, p + 2.0 * r)  # entry of the flat arrays (row r's own from r · n)
        np.clip(g, lo + 1, lo + n - 1, out=g)
        c0, c1 = flat[g - 1], flat[g]
        t = np.clip((p - c0) / np.maximum(c1 - c0, 1e-300), 0.0, 1.0)
        g += to_v[r]
        v0 = vflat[g - 1]
        return v0 + t * (vflat[g] - v0)

    def run(r, first, stop):  # the draws first <= i < stop of segments in rows r, as (rows, draws)
        count = np.maximum(stop - first, 0)
        return np.repeat(r, count), np.arange(count.sum()) - np.repeat(np.cumsum(count) - count - first, count)

    def shortest(r, widths):  # the least of ``widths`` per row (rows r, each row's in a run)
        out = np.full(rows, np.inf)
        if len(r):
            first = np.flatnonzero(np.diff(r, prepend=-1))
            out[r[first]] = np.minimum.reduceat(widths, first)
        return out

    def least(first, stop, up):  # per row, the shortest interval from (up) or to a draw first <= i < stop
        def far(r, g):  # the other end of row r's interval from (up) or to draw g
            return at(r, flat[g] + prob) if up else at(r, flat[g] - prob)

        # Both ends of the interval move up with the draw, so a block of HDI_BLOCK draws is at least
        # (the far end at its first draw) − (the draw end at its last) wide: a block that cannot beat
        # the width of one interval per block found (from its first draw, to its last) is skipped
        rb, kb = run(every, 0, -(-np.maximum(stop - first, 0) // HDI_BLOCK))
        s = rb * n + first[rb] + kb * HDI_BLOCK
        e = rb * n + np.minimum(first[rb] + (kb + 1) * HDI_BLOCK, stop[rb]) - 1
        end = far(rb, s) if up else far(rb, e)
        vs, ve = vflat[s + to_v[rb]], vflat[e + to_v[rb]]
        found = shortest(rb, end - vs if up else ve - end)[rb]
        bound = end - ve if up else vs - end
        keep = bound <= found + 1e-9 * (1.0 + np.abs(found))  # rounding may break ties
        r, g = run(rb[keep], s[keep], e[keep] + 1)
        return shortest(r, far(r, g) - vflat[g + to_v[r]] if up else vflat[g + to_v[r]] - far(r, g))

    def first_failing(holds):  # per row, the first draw where holds(entries g of flat) fails (a bisection:
        lo, hi = np.zeros(rows, int), np.full(rows, n)  # it holds on a run from the first draw)
        while np.any(lo < hi):
            mid = (lo + hi) // 2
            ok = holds(every * n + np.minimum(mid, n - 1))
            lo, hi = np.where((lo < hi) & ok, mid + 1, lo), np.where((lo < hi) & ~ok, mid, hi)
        return lo

    # the width is piecewise linear in the start, so the shortest interval starts or ends at a draw:
    # from each draw that can start one (c + prob within the row: a run from the first draw), and to
    # each that can end one (c − prob within the row: a run to the last)
    last, head = c[:, -1].copy(), c[:, 0].copy()
    width = least(np.zeros(rows, int), first_failing(lambda g: flat[g] + prob <= last), True)
    width = np.minimum(width, least(first_failing(lambda g: ~(flat[g] - prob >= head)), np.full(rows, n), False))
    bottom = every // big_m * n
    width = np.where(np.isfinite(width), width, vflat[bottom + n - 1] - vflat[bottom])  # too few draws to hold prob
    median = at(every, np.full(rows, 0.5))
    width, median = width.reshape(k, big_m).T, median.reshape(k, big_m).T
    return (width[:, 0], median[:, 0]) if values.ndim == 1 else (width, median)


def shuffled_hdi(values: np.ndarray, weights: np.ndarray, prob: float, rng,
                 n_shuffles: int = SHUFFLES, order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The HDI of ``values`` ((N,) or (N, k), as :func:`weighted_hdi`, ``order`` as there) as each
    row of ``weights`` (M, N) would see it if it said nothing about them: the row shuffled over the
    draws (the same effective sample size), the width and the width over the median averaged over
    shuffles.

    A shortest interval from weighted draws is too narrow, the more so the fewer the effective
    draws; scaling a row's HDI by (equal-weight HDI) / (this) takes that out. A row of at most
    N / :data:`SHUFFLE_SHARE` effective draws is shuffled ``n_shuffles`` times; one of more, fewer
    times in proportion (at least once): a shuffle's width scatters as one over the root of the
    effective draws, so every row's average is known at least as well as that of a row of N /
    :data:`SHUFFLE_SHARE` effective draws over ``n_shuffles`` shuffles.

    Returns
    -------
    width in the unit of ``values``, share (width over the median); (M,) or (M, k)
    """
    w = np.atleast_2d(np.asarray(weights, float))
    order = np.argsort(np.atleast_2d(np.asarray(values, float).T).T, axis=0).T if order is None else order
    ess = 1.0 / np.sum(w * w, axis=1)
    times = np.clip(np.ceil(n_shuffles * (w.shape[1] / SHUFFLE_SHARE) / ess), 1, n_shuffles).astype(int)
    shape = (len(w),) if np.ndim(values) == 1 else (len(w), np.shape(values)[1])
    width, share = np.zeros(shape), np.zeros(shape)
    rows = [np.flatnonzero(times > t) for t in range(int(times.max()))]
    shuffled = [np.take_along_axis(w[r], np.argsort(rng.random((len(r), w.shape[1])), axis=1), axis=1) for r in rows]
    # the shuffles' rows stacked into calls of about HDI_CALL_SIZE weights each (one call costs much the same
    # for a few rows as for many)
    per_row = w.shape[1] * max(1, int(np.prod(shape[1:])))
    start = 0
    while start < len(rows):
        stop, size = start, 0
        while stop < len(rows) and (stop == start or size + len(rows[stop]) * per_row <= HDI_CALL_SIZE):
            size += len(rows[stop]) * per_row
            stop += 1
        at = np.concatenate(rows[start:stop])
        wd, median = weighted_hdi(values, np.concatenate(shuffled[start:stop]), prob, order)
        each = times[at].reshape((-1,) + (1,) * (wd.ndim - 1))  # a row's average over its own shuffles
        np.add.at(width, at, wd / each)
        np.add.at(share, at, wd / median / each)
        start = stop
    return width, share


def location_sd(loc: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """√(var x + var y + var z) per row of weights (M,), metres; ``loc`` (N, 3) draws of a bottom
    centre.

    The weighted variance is divided by 1 − Σw², which makes it unbiased for independent draws
    whatever the weights."""
    loc = np.asarray(loc, float)
    w = np.atleast_2d(weights)
    mean = w @ loc                       # (M, 3)
    second = w @ (loc * loc)
    spread = np.maximum(np.sum(second - mean * mean, axis=1), 0.0)
    return np.sqrt(spread / np.maximum(1.0 - np.sum(w * w, axis=1), 1e-12))


def mean_boxes(boxes: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The weighted posterior-mean box per row (M, 7) of (N, 7) box draws (x, y, z, yaw, length,
    width, height): the mean of all but the yaw, whose mean is circular."""
    boxes = np.asarray(boxes, float)
    w = np.atleast_2d(weights)
    out = w @ boxes
    out[:, 3] = np.arctan2(w @ np.sin(boxes[:, 3]), w @ np.cos(boxes[:, 3]))
    return out


def systematic_resample(weights: np.ndarray, n: int, rng) -> np.ndarray:
    """``n`` indices drawn by systematic resampling from normalised ``weights`` (N,)."""
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.searchsorted(c, (rng.uniform() + np.arange(n)) / n)


def p_iou(boxes: np.ndarray, weights: np.ndarray, threshold: float, rng, n_pairs: int = 64) -> np.ndarray:
    """P(IoU(mean box, true box) ≥ threshold) per row of weights and object, (M, k), from (N, k, 7)
    box draws of k objects.

    The true box is a posterior draw; each row's share is estimated from ``n_pairs`` draws
    resampled (systematically) by its weights, which keeps the cost at M × k × ``n_pairs`` IoUs.
    """
    boxes = np.asarray(boxes, float)
    w = np.atleast_2d(weights)
    idx = np.stack([systematic_resample(row, n_pairs, rng) for row in w])       # (M, n_pairs)
    means = np.stack([mean_boxes(boxes[:, j], w) for j in range(boxes.shape[1])], axis=1)  # (M, k, 7)
    truth = boxes[idx]                                                           # (M, n_pairs, k, 7)
    good = iou_3d_at_least(np.repeat(means[:, None], n_pairs, axis=1).reshape(-1, 7), truth.reshape(-1, 7), threshold)
    return good.reshape(len(w), n_pairs, -1).mean(axis=1)


def tempered_update(log_old, log_new, particles: np.ndarray, rng, *, n_moves: int = 8,
                    ess_fraction: float = 0.5, max_stages: int = 50, labels: np.ndarray | None = None
                    ) -> tuple[np.ndarray, dict]:
    """Move draws of the current posterior to the new one when plain reweighting collapses.

    Sequential Monte Carlo along the path p_β ∝ p_old^(1−β) p_new^β: β grows in steps chosen so
    that each step's weights keep an ESS of ``ess_fraction`` · N; after each step the draws are
    resampled (systematically) and moved by ``n_moves`` random-walk Metropolis steps that leave
    p_β invariant (Gaussian proposals with the draws' covariance, scale adapted to the acceptance).

    Parameters
    ----------
    log_old, log_new : callables (n, d) → (n,), the unnormalised log-densities of the current and
        the new posterior (−∞ outside the support)
    particles : (N, d) draws of the current posterior
    rng : numpy Generator
    labels : (N, …) a discrete part of each draw that the moves keep and the resampling carries
        along (each target's handedness), or None; the densities are then called (x, labels)

    Returns
    -------
    (N, d) draws of the new posterior (equally weighted), and ``info`` (stages, acceptance and,
    with ``labels``, the draws' labels)
    """
    x = np.array(particles, float)
    n, d = x.shape
    lab = None if labels is None else np.asarray(labels)
    if lab is not None:  # the current labels, read when called (they follow each resampling)
        log_old, log_new = (lambda p, f=log_old: f(p, lab)), (lambda p, f=log_new: f(p, lab))
    lo, ln = log_old(x), log_new(x)
    base_cov = np.cov(x.T).reshape(d, d)
    jitter = 1e-8 * np.diag(np.diag(base_cov)) + 1e-300 * np.eye(d)
    beta, stages, accepted, tried = 0.0, 0, 0, 0
    step = 2.38 / np.sqrt(d)
    while beta < 1.0 and stages < max_stages:
        delta = np.where(np.isfinite(ln) & np.isfinite(lo), ln - lo, -np.inf)
        nxt = _next_beta(delta, beta, ess_fraction * n)
        w, _ = normalise(((nxt - beta) * delta)[None])
        idx = systematic_resample(w[0], n, rng)
        x, lo, ln, beta = x[idx], lo[idx], ln[idx], nxt
        lab = None if lab is None else lab[idx]
        stages += 1
        unique = len(np.unique(idx))
        cov = np.cov(x.T).reshape(d, d) if unique > d else np.diag(np.diag(base_cov)) * unique / n
        x, parts, step, acc = _random_walk(lambda p: np.stack([log_old(p), log_new(p)]), x, np.stack([lo, ln]),
                                           np.array([1.0 - beta, beta]), np.linalg.cholesky(cov + jitter), step,
                                           rng, n_moves)
        lo, ln = parts
        accepted, tried = accepted + acc, tried + n * n_moves
    return x, {"stages": stages, "acceptance": accepted / max(tried, 1), "beta": beta, "labels": lab}


def gaussian_transport(z: np.ndarray, cols, values: np.ndarray, sd: np.ndarray, moves=None, follow=None) -> np.ndarray:
    """Draws ``z`` (N, d) of the current posterior moved, by one affine map per answer, to where the
    posterior after a normal observation ``values`` (F, p) = z[:, cols] + noise of spread ``sd``
    (p,) would put them if the current posterior were normal with the draws' mean and covariance.

    The observed coordinates h go by h' = m' + B (h − m), m and m' their mean before and after
    (conditioning), B = Σ'^½ Σ^−½ (symmetric roots) taking their covariance Σ to the conditional Σ';
    every coordinate moves with its regression on h (z + (h' − h) Gᵀ, G = Cov(z, h) Σ⁻¹), so what the
    observation says nothing about given h is kept. The map's Jacobian is the same for every draw
    (det B), so a moved draw y = T(z) has density p_old(z) / det B: weighted by p_new(y) / p_old(z)
    the moved draws are draws of the new posterior whatever its shape (importance sampling; the
    caller's :func:`~creference_bayes.workflows.advice._moved`), and the closer the posterior is to
    normal the more evenly they are weighted. ``moves`` (d,) bool: the coordinates that may move
    with h (None: all); a coordinate that the posterior makes independent of h, or nearly, is
    better kept where it is than moved by its regression's sampling noise. ``follow`` (d,) bool,
    with ``moves``: of the coordinates that moved, those the others then follow by their own
    regression on them (the advice's: the camera, which the other objects depend on).

    Draws that are not all finite, or observed quantities that do not vary over them, give no map:
    the draws are returned as they are (the identity, whose weights are plain reweighting's).

    Returns
    -------
    (F, N, d) the draws moved for each answer
    """
    z = np.asarray(z, float)
    cols = np.asarray(cols, int)
    values = np.atleast_2d(np.asarray(values, float))
    n = len(z)
    mean = z.mean(axis=0)
    dz = z - mean
    h = dz[:, cols]
    s_hh = h.T @ h / (n - 1)
    if n < 2 or not (np.all(np.isfinite(z)) and np.all(np.isfinite(values))) or not np.all(np.diag(s_hh) > 0):
        return np.repeat(z[None], len(values), axis=0)
    s_hh += 1e-12 * np.trace(s_hh) * np.eye(len(cols))  # rounding: a direction the draws barely vary in
    gain_all = np.linalg.solve(s_hh, h.T @ dz / (n - 1)).T                          # (d, p) G
    if moves is not None:
        gain_all[~np.asarray(moves, bool)] = 0.0
    gain = np.linalg.solve(s_hh + np.diag(np.square(np.asarray(sd, float))), s_hh).T  # (p, p) Σ S⁻¹
    post = s_hh - gain @ s_hh
    post = 0.5 * (post + post.T)

    def root(a, power):
        w, v = np.linalg.eigh(a)
        return (v * np.maximum(w, 1e-300) ** power) @ v.T

    B = root(post, 0.5) @ root(s_hh, -0.5)
    m_new = mean[cols] + (values - mean[cols]) @ gain.T                              # (F, p)
    h_new = m_new[:, None, :] + h @ B.T                                              # (F, N, p)
    out = z[None] + (h_new - z[None][..., cols]) @ gain_all.T
    out[..., cols] = h_new
    if follow is not None and moves is not None:  # the rest follow what moved by their regression on it
        mv = np.asarray(moves, bool) & np.asarray(follow, bool)
        rest = ~np.asarray(moves, bool)
        if mv.any() and rest.any():
            a = dz[:, mv]
            g2 = np.linalg.solve(a.T @ a / (n - 1) + 1e-12 * np.eye(mv.sum()), a.T @ dz[:, rest] / (n - 1)).T
            out[..., rest] += (out[..., mv] - z[None][..., mv]) @ g2.T
    return out


def _random_walk(density, x, parts, coef, chol, step, rng, n_moves):
    """``n_moves`` random-walk Metropolis steps leaving log p = Σ coef_k · part_k invariant (−∞
    wherever a part is), Gaussian proposals step · chol · ε, the step adapted to the acceptance;
    ``density`` (n, d) → the parts (k, n). Returns the draws, their parts, the step and the number
    of moves accepted. F sets of draws at once: ``x`` (F, n, d), parts (k, F, n), ``chol``
    (F, d, d) and ``step`` (F,), each set's step adapted to its own acceptance."""
    batched = x.ndim == 3
    xs, ch = (x, chol) if batched else (x[None], chol[None])
    parts = parts if batched else parts[:, None]
    steps = np.broadcast_to(np.asarray(step, float), (len(xs),)).copy()
    call = density if batched else (lambda p: density(p[0])[:, None])
    accepted, cur = 0, _combine(parts, coef)
    for _ in range(n_moves):
        prop = xs + steps[:, None, None] * np.einsum("fnd,fed->fne", rng.standard_normal(xs.shape), ch)
        new = call(prop)
        log_p = _combine(new, coef)
        with np.errstate(invalid="ignore"):
            acc = np.log(rng.uniform(size=cur.shape)) < np.where(np.isfinite(log_p), log_p - cur, -np.inf)
        xs[acc], parts[:, acc], cur[acc] = prop[acc], new[:, acc], log_p[acc]
        rate = acc.mean(axis=1)
        accepted += int(acc.sum())
        steps *= np.where(rate < 0.15, 0.6, np.where(rate > 0.5, 1.4, 1.0))
    if batched:
        return xs, parts, steps, accepted
    return xs[0], parts[:, 0], float(steps[0]), accepted


def _combine(parts: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Σ coef_k · part_k over the rows of ``parts`` (k, n), −∞ wherever a part is (no 0 · ∞): for
    the tempered update log p_β = (1 − β) log p_old + β log p_new."""
    with np.errstate(invalid="ignore"):
        out = np.tensordot(coef, np.where(np.isfinite(parts), parts, 0.0), axes=1)
    return np.where(np.all(np.isfinite(parts), axis=0), out, -np.inf)


def _next_beta(delta: np.ndarray, beta: float, ess_goal: float) -> float:
    """The largest β' ≤ 1 whose incremental weights exp((β' − β) δ) keep ESS ≥ ``ess_goal``."""
    def ess(b):
        return normalise(((b - beta) * delta)[None])[1][0]

    if ess(1.0) >= ess_goal:
        return 1.0
    lo, hi = beta, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess(mid) >= ess_goal else (lo, mid)
    return max(lo, beta + 1e-6)
