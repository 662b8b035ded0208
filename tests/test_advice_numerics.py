"""The advice's numerics: pairwise IoU, weighted HDI, the importance weights of a simulated
observation (against the models' own posteriors), the tempered fallback, candidates and costs."""

import dataclasses

import arviz as az
import numpy as np
import pytest

from creference_bayes.bench.simulate import simulate_scene, true_state
from creference_bayes.evaluation.iou3d import box_iou_3d
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.contract import C_SCALE
from creference_bayes.models.metrology import ReferenceTerm, ground_lengths
from creference_bayes.pipeline import build_model
from creference_bayes.workflows.advice.answers import with_dimension_lines
from creference_bayes.workflows.advice.candidates import (PAPER_REFERENCE_SECONDS, PAPER_TARGET_SECONDS,
                                                          annotation_seconds, candidates, format_mix)
from creference_bayes.workflows.advice.iou import iou_3d_at_least, iou_3d_pairs
from creference_bayes.workflows.advice.observe import DimsObservation, ReferenceObservation, grown
from creference_bayes.workflows.advice.update import (gaussian_transport, informative, location_sd, normalise,
                                                      tempered_update, weighted_hdi)


def _box_pairs(seed: int, n: int, yaw_sd: float, size_sd: float):
    """n random boxes (x, y, z, yaw, l, w, h) and as many moved from them: 0.3 m, ``yaw_sd`` rad,
    ``size_sd`` m apart (sizes kept positive)."""
    rng = np.random.default_rng(seed)
    a = np.column_stack([rng.normal(0, 0.6, n), rng.normal(1.5, 0.2, n), rng.normal(6, 0.6, n),
                         rng.uniform(-np.pi, np.pi, n), rng.uniform(0.2, 3, (n, 3))])
    b = a + np.column_stack([rng.normal(0, 0.3, (n, 3)), rng.normal(0, yaw_sd, n), rng.normal(0, size_sd, (n, 3))])
    b[:, 4:] = np.abs(b[:, 4:]) + 0.05
    return a, b


def test_pairwise_iou_matches_shapely():
    n = 400
    a, b = _box_pairs(0, n, 0.5, 0.2)
    b[:50] = a[:50]  # identical boxes
    expected = np.array([box_iou_3d(a[i], b[i:i + 1])[0] for i in range(n)])
    np.testing.assert_allclose(iou_3d_pairs(a, b), expected, atol=1e-9)
    assert np.all(iou_3d_pairs(a[:50], b[:50]) > 1 - 1e-9)
    assert (expected == 0).any() and ((expected > 0) & (expected < 1)).sum() > 100


@pytest.mark.parametrize("threshold", [0.3, 0.5, 0.7, 0.9])
def test_iou_at_least_a_threshold_is_the_iou_compared_whatever_the_bound_leaves_out(threshold):
    """The advice's P(IoU ≥ t) counts pairs by :func:`iou_3d_at_least`, which computes the IoU only
    where a cheap upper bound leaves the answer open: the same verdict as the IoU compared, pair
    for pair (identical, touching, turned and far-apart boxes among them)."""
    n = 4000
    a, b = _box_pairs(2, n, 0.3, 0.1)
    b[:50] = a[:50]                                               # identical
    b[50:100] = a[50:100]
    b[50:100, 0] += a[50:100, 4] * np.cos(a[50:100, 3])          # touching end to end
    b[50:100, 2] -= a[50:100, 4] * np.sin(a[50:100, 3])
    b[100:150, 0] += 20.0                                         # far apart
    iou = iou_3d_pairs(a, b)
    np.testing.assert_array_equal(iou_3d_at_least(a, b, threshold), iou >= threshold)
    assert np.all(iou[:50] > 1 - 1e-9) and np.all(iou[50:150] < 1e-9)


def test_iou_at_least_a_threshold_computes_the_iou_of_few_pairs(monkeypatch):
    """Its two bounds decide most pairs of a posterior's boxes (a mean box against draws a few
    centimetres and degrees apart), those above the bar as well as those below."""
    from creference_bayes.workflows.advice import iou as iou_module

    a, b = _box_pairs(4, 4000, 0.05, 0.05)
    a[:, 4:] += 2.0  # cars' sizes, 0.15 m apart: most pairs above the bar, the upper bound leaves them open
    b[:, 4:] += 2.0
    b[:, :3] = a[:, :3] + (b[:, :3] - a[:, :3]) * 0.5
    exact = iou_3d_pairs(a, b) >= 0.7
    computed = []
    real = iou_module.iou_3d_pairs
    monkeypatch.setattr(iou_module, "iou_3d_pairs", lambda x, y: computed.append(len(x)) or real(x, y))
    np.testing.assert_array_equal(iou_3d_at_least(a, b, 0.7), exact)
    assert 0.5 < exact.mean() < 0.98
    assert sum(computed) < 0.35 * len(a)


def test_weighted_hdi_with_equal_weights_is_the_sample_hdi_and_columns_are_independent():
    rng = np.random.default_rng(1)
    x = rng.gamma(3.0, 1.0, 4000)
    width, median = weighted_hdi(x, np.full((1, x.size), 1 / x.size), 0.9)
    lo, hi = az.hdi(x, hdi_prob=0.9)
    assert width[0] == pytest.approx(hi - lo, rel=2e-3)
    assert median[0] == pytest.approx(np.median(x), abs=2e-3)
    # several quantities at once: each column as on its own, for uneven weights
    cols = np.column_stack([x[:600], rng.normal(size=600), x[:600] ** 2])
    w, _ = normalise(3.0 * rng.standard_normal((40, 600)))
    both = weighted_hdi(cols, w, 0.9)
    for j in range(3):
        np.testing.assert_array_equal(np.array(both)[:, :, j], np.array(weighted_hdi(cols[:, j], w, 0.9)))


def test_weighted_hdi_bounding_blocks_of_draws_finds_the_interval_every_draw_would(monkeypatch):
    """weighted_hdi computes the intervals of only those blocks of draws whose bound can beat an
    interval found: the widths and medians must be those of every draw's interval, to the bit,
    for even and very uneven weights (an effective draw or two) and both interval ends; and both
    those of a brute-force scan of every start and end by linear interpolation."""
    from creference_bayes.workflows.advice import update

    rng = np.random.default_rng(7)
    vals = np.column_stack([rng.gamma(3.0, 2.0, 300), rng.normal(size=300), rng.standard_t(2, 300)])
    w, ess = normalise(rng.standard_normal((60, 300)) * np.linspace(0.0, 6.0, 60)[:, None])
    assert ess.min() < 3 and ess.max() > 299
    for prob in (0.5, 0.9):
        fast = weighted_hdi(vals, w, prob)
        monkeypatch.setattr(update, "HDI_BLOCK", 10**9)  # one block a row: every draw's interval
        every = weighted_hdi(vals, w, prob)
        monkeypatch.undo()
        np.testing.assert_array_equal(fast[0], every[0])
        np.testing.assert_array_equal(fast[1], every[1])
        for j in range(vals.shape[1]):
            order = np.argsort(vals[:, j])
            v = vals[order, j]
            for i in (0, 30, 59):
                c = np.cumsum(w[i, order]) - 0.5 * w[i, order]
                up = c + prob <= c[-1]
                down = c - prob >= c[0]
                widths = np.concatenate([np.interp(c[up] + prob, c, v) - v[up], v[down] - np.interp(c[down] - prob, c, v)])
                assert fast[0][i, j] == pytest.approx(widths.min(), rel=1e-9, abs=1e-12)
                assert fast[1][i, j] == pytest.approx(np.interp(0.5, c, v), rel=1e-9)


def test_the_beta_of_a_labels_futures_is_the_likelihoods_maximum_within_the_cap():
    """good_chance's beta: per column the beta-binomial maximum likelihood with its concentration at
    most Σ n − 1, as a general optimiser finds it column by column (Nelder–Mead in logit mean and log
    concentration, from several starts); spread and underdispersed columns (a label whose futures
    hardly differ, held at the cap) among them, fitted together."""
    from scipy.optimize import minimize
    from scipy.special import betaln

    from creference_bayes.workflows.advice import _fit_futures

    rng = np.random.default_rng(3)
    n_fut = 60
    n_eff = 1.0 / (1.0 / 16 + 1.0 / rng.uniform(20, 300, n_fut))
    true = np.column_stack([rng.beta(2, 5, n_fut), rng.beta(30, 10, n_fut), np.full(n_fut, 0.45),
                            np.full(n_fut, 0.97), rng.beta(0.5, 0.5, n_fut)])
    p_hat = rng.binomial(16, true) / 16
    a, b = _fit_futures(p_hat, n_eff)
    k, cap = p_hat * n_eff[:, None], n_eff.sum() - 1.0

    def nll(x, j):  # the column's beta-binomial negative log-likelihood (the binomial coefficient left out)
        mu, conc = 1.0 / (1.0 + np.exp(-x[0])), np.exp(min(x[1], np.log(cap)))
        return -np.sum(betaln(k[:, j] + mu * conc, n_eff - k[:, j] + (1 - mu) * conc) - betaln(mu * conc, (1 - mu) * conc))

    assert np.all(a + b <= cap * (1 + 1e-9))
    assert a[2] + b[2] == pytest.approx(cap)  # the futures of a fixed P(IoU ≥ t) scatter as the binomial: at the cap
    for j in range(p_hat.shape[1]):
        best = min((minimize(nll, x0, args=(j,), method="Nelder-Mead", options={"xatol": 1e-9, "fatol": 1e-12,
                                                                                   "maxiter": 20000})
                    for x0 in ([0.0, 1.0], [0.0, 5.0], [1.0, np.log(cap)])), key=lambda r: r.fun)
        mine = np.array([np.log(a[j] / b[j]), np.log(a[j] + b[j])])
        assert nll(mine, j) <= best.fun + 1e-6
        assert a[j] / (a[j] + b[j]) == pytest.approx(1.0 / (1.0 + np.exp(-best.x[0])), abs=1e-4)


def test_the_beta_fits_trigamma_is_scipys_from_tiny_to_huge_arguments():
    """The beta fits' ψ′ (recurrence, then the asymptotic series) against SciPy's Hurwitz zeta(2, x),
    across the arguments a fit meets (a concentration of 2e-3 split by a mean near 0, counts in the
    thousands) and in any array shape."""
    from scipy.special import polygamma

    from creference_bayes.workflows.advice import _trigamma

    x = np.concatenate([np.geomspace(1e-6, 1e6, 2001), [9.999999, 10.0, 10.000001, 0.5, 1.0, 2.0]])
    np.testing.assert_allclose(_trigamma(x), polygamma(1, x), rtol=1e-12)
    assert _trigamma(1.0) == pytest.approx(np.pi**2 / 6, rel=1e-13)
    grid = x[:2000].reshape(40, 50)
    np.testing.assert_allclose(_trigamma(grid), polygamma(1, grid), rtol=1e-12)
    np.testing.assert_allclose(_trigamma(grid.T), polygamma(1, grid.T), rtol=1e-12)  # Fortran order


def test_the_location_sd_of_uneven_weights_is_not_short():
    """Weights unrelated to the draws, a few dozen effective draws of 1000: the location's
    variance from them must be the draws' (3 m², unit normals in x, y, z) on average; the plain
    weighted variance is short by 1/ESS (here 3–4 %)."""
    rng = np.random.default_rng(0)
    loc = rng.standard_normal((1000, 3))
    w, ess = normalise(2.0 * rng.standard_normal((400, 1000)))
    assert 20 < np.median(ess) < 60
    var = location_sd(loc, w) ** 2
    truth = np.sum((loc - loc.mean(axis=0)) ** 2) / 999
    assert np.mean(var) == pytest.approx(truth, rel=0.015)
    assert location_sd(loc, np.full((1, 1000), 1e-3))[0] ** 2 == pytest.approx(truth, rel=1e-9)


@pytest.mark.parametrize("ess_scale", [0.5, 2.0])
def test_the_screen_of_weights_that_say_nothing_is_a_chi_square_of_the_rows(ess_scale):
    """Weights unrelated to 300 objects' draws (many or few effective draws of 400): at its mean
    (sd 0) about half the objects pass the screen (a chi-square of 50 degrees is above its mean
    47 % of the time; a variance off by a fifth would give 10 % or 90 %); at three of its sd
    almost none."""
    rng = np.random.default_rng(4)
    features = rng.standard_normal((400, 300, 1)) * rng.uniform(0.1, 10.0, 300)[None, :, None]
    w, ess = normalise(ess_scale * rng.standard_normal((50, 400)))
    assert (200 < np.median(ess) < 400) if ess_scale < 1 else (10 < np.median(ess) < 60)
    assert 0.35 < np.mean(informative(features, w, sd=0.0)) < 0.6
    assert np.mean(informative(features, w)) < 0.03


def test_the_screen_finds_the_objects_the_weights_learn_about_and_skips_a_constant():
    """Rows of weights from simulated observations of object 0's first feature (noise three times
    its sd: each row takes a tenth of its variance): object 0 is read, object 1 (its own draws) is
    not, nor is object 2 (the same first feature as object 0 but a known, constant size)."""
    rng = np.random.default_rng(5)
    f = rng.standard_normal((400, 3, 2))
    f[:, 2, 0] = f[:, 0, 0]
    f[:, 2, 1] = 1.7  # a constant feature adds nothing and no NaN
    y = f[rng.integers(400, size=50), 0, 0] + 3.0 * rng.standard_normal(50)
    w, _ = normalise(-0.5 * ((y[:, None] - f[None, :, 0, 0]) / 3.0) ** 2)
    assert informative(f, w).tolist() == [True, False, True]
    f[:, 2, 0] = 2.0
    assert informative(f, w).tolist() == [True, False, False]


def test_reweighting_a_gaussian_gives_the_conjugate_posterior():
    x = np.random.default_rng(2).normal(0.0, 1.0, 200_000)
    # observation y = 1 with noise sd 1: posterior N(0.5, 0.5); sd 0.5: N(0.8, 0.2)
    w, ess = normalise(np.stack([-0.5 * (1.0 - x) ** 2, -0.5 * ((1.0 - x) / 0.5) ** 2]))
    width, median = weighted_hdi(x, w, 0.9)
    np.testing.assert_allclose(width, 2 * 1.6449 * np.sqrt([0.5, 0.2]), rtol=0.01)
    np.testing.assert_allclose(median, [0.5, 0.8], atol=0.01)
    assert ess[0] > ess[1] > 0


def test_tempered_update_recovers_a_posterior_plain_reweighting_cannot():
    rng = np.random.default_rng(3)
    prior = rng.normal(0.0, 1.0, (400, 2))
    mu, sd = np.array([1.2, -0.7]), 0.03   # the likelihood is 30 times narrower than the prior

    def log_old(p):
        return -0.5 * np.sum(p * p, axis=1)

    def log_new(p):
        return log_old(p) - 0.5 * np.sum(((p - mu) / sd) ** 2, axis=1)

    _, ess = normalise((log_new(prior) - log_old(prior))[None])
    assert ess[0] < 5  # collapsed
    moved, info = tempered_update(log_old, log_new, prior, rng)
    post_var = 1 / (1 + 1 / sd**2)
    np.testing.assert_allclose(moved.mean(axis=0), mu * post_var / sd**2, atol=0.01)
    np.testing.assert_allclose(moved.std(axis=0), np.sqrt(post_var), rtol=0.25)
    assert info["beta"] == 1.0 and info["stages"] >= 2


def test_the_gaussian_transport_gives_the_draws_the_conjugate_moments_of_their_own_normal():
    """Answers on two of four correlated quantities, each set of moved draws against the textbook
    conjugate update of the draws' own mean and covariance (not of the law they came from, so the
    check is to rounding): mean μ + C S⁻¹ (a − μ_h), covariance Σ − C S⁻¹ Cᵀ, C = Cov(z, h),
    S = Σ_hh + diag(sd²); every draw moved by the same affine map (each moved draw a draw of its own)."""
    rng = np.random.default_rng(8)
    a = rng.normal(size=(4, 4))
    z = rng.multivariate_normal([1.0, -2.0, 0.5, 3.0], a @ a.T + 0.5 * np.eye(4), 500)
    z[:, 3] = np.exp(0.3 * z[:, 3])  # not normal: the moments are the draws' own all the same
    cols, sd = np.array([2, 0]), np.array([0.05, 0.2])
    values = np.array([[0.4, 1.1], [1.5, -0.5]])
    moved = gaussian_transport(z, cols, values, sd)
    assert moved.shape == (2, 500, 4)
    mu, cov = z.mean(axis=0), np.cov(z.T)
    c = cov[:, cols]
    s_inv = np.linalg.inv(cov[np.ix_(cols, cols)] + np.diag(sd ** 2))
    for f in range(2):
        np.testing.assert_allclose(moved[f].mean(axis=0), mu + c @ s_inv @ (values[f] - mu[cols]), atol=1e-9)
        np.testing.assert_allclose(np.cov(moved[f].T), cov - c @ s_inv @ c.T, atol=1e-9)
        linear, *_ = np.linalg.lstsq(np.column_stack([z, np.ones(500)]), moved[f], rcond=None)
        np.testing.assert_allclose(np.column_stack([z, np.ones(500)]) @ linear, moved[f], atol=1e-9)
        assert len(np.unique(moved[f, :, 1].round(12))) == 500


def test_the_gaussian_transport_leaves_draws_it_cannot_map_where_they_are():
    """A quantity that does not vary over the draws, or a draw that is not finite: no map (the
    identity), never a NaN or a singular solve."""
    rng = np.random.default_rng(3)
    z = rng.normal(size=(50, 3))
    fixed = z.copy()
    fixed[:, 1] = 2.0
    np.testing.assert_array_equal(gaussian_transport(fixed, [1], np.array([[2.5], [1.0]]), np.array([0.1])),
                                  np.repeat(fixed[None], 2, axis=0))
    broken = z.copy()
    broken[7, 0] = np.nan
    np.testing.assert_array_equal(gaussian_transport(broken, [0], np.array([[0.5]]), np.array([0.1]))[0], broken)
    assert np.all(np.isfinite(gaussian_transport(z, [0, 2], np.array([[0.5, -0.5]]), np.array([0.1, 0.2]))))


def test_transported_draws_weighed_by_the_new_posterior_over_the_old_are_its_draws():
    """A posterior that is not normal (a banana: z1 | z0 ~ N(0.3 z0², 0.3²), z0 ~ N(0, 1)) and a
    sharp answer on z0 (sd 0.05, at 1.2: far in reweighting's terms): the draws carried by the
    transport and weighed by p_new(y) / p_old(z) (the map's Jacobian is one constant) give the
    answer's posterior mean of z1 (0.3 E z0² after it), where the transport alone does not (it
    moves z1 along its straight regression on z0, which is 0)."""
    rng = np.random.default_rng(9)
    n = 4000
    z0 = rng.normal(size=n)
    z = np.column_stack([z0, 0.3 * z0 ** 2 + 0.3 * rng.normal(size=n)])

    def log_old(x):
        return -0.5 * x[..., 0] ** 2 - 0.5 * ((x[..., 1] - 0.3 * x[..., 0] ** 2) / 0.3) ** 2

    value, sd = 1.2, 0.05
    y = gaussian_transport(z, [0], np.array([[value]]), np.array([sd]))[0]
    log_w = log_old(y) - 0.5 * ((y[:, 0] - value) / sd) ** 2 - log_old(z)
    w, ess = normalise(log_w)
    w = w[0]
    post_var = 1.0 / (1.0 + 1.0 / sd ** 2)           # z0 | answer: normal
    post_mean = post_var * value / sd ** 2
    truth = 0.3 * (post_mean ** 2 + post_var)         # E z1 = 0.3 E z0²
    assert ess[0] > 0.02 * n                          # weights that still count
    assert w @ y[:, 1] == pytest.approx(truth, abs=4 * 0.3 / np.sqrt(ess[0]))   # 4 se
    assert abs(y[:, 1].mean() - truth) > 0.1          # the transport alone is off


def _scene(seed, **kw):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(simulate_scene(np.random.default_rng(seed), **kw))


def _with_sets(scene, k):
    """The scene with its targets' first k sets of dimension lines."""
    return dataclasses.replace(scene, targets=tuple(dataclasses.replace(t, dimension_lines=t.dimension_lines[:k])
                                                    for t in scene.targets))


def _states(scene, model, n, rng):
    """States scattered around the scene's truth (the weights are defined pointwise, so any states
    will do); derived parameters are filled in by the model."""
    cam, objs = true_state(scene)
    cams = np.tile(cam, (n, 1)) * np.exp(rng.normal(0, [0.05, 0, 0, 0.03, 0.3], (n, 5)))
    cams[:, 1:3] += rng.normal(0, 0.01, (n, 2))
    o = np.tile(objs, (n, 1, 1))
    o[..., :2] += rng.normal(0, 0.1, o[..., :2].shape)
    o[..., 2] += rng.normal(0, 0.1, o[..., 2].shape)
    o[..., 6] = np.where(model.object_free[:, 6], o[..., 6], 0.0)
    return model.complete_camera(cams), o


def _frame_model(scene):
    """The scene's model with the truth's handedness and its pilot at the true camera."""
    model, _ = build_model(scene)
    model.handedness = np.array([t.ground_truth["handedness"] for t in scene.targets], float)
    model.set_pilot(true_state(scene)[0])
    return model


@pytest.fixture(scope="module")
def frame():
    """A 3-target outdoor scene (class size priors, three sets each, two references) and its model
    at the truth, with states around it."""
    scene = _with_sets(_scene(5, tier="medium", setting="outdoor", n_objects=3, sizes="prior", n_references=2), 3)
    model = _frame_model(scene)
    cams, o = _states(scene, model, 300, np.random.default_rng(6))
    return scene, model, cams, o


def test_a_grown_model_without_more_is_the_model(frame):
    scene, model, cams, objs = frame
    np.testing.assert_array_equal(grown(model, {}).neg_log_posterior(cams, objs), model.neg_log_posterior(cams, objs))


def test_a_grown_model_keeps_the_crowds_corner_scale_from_the_data_set():
    """A frame of one set of lines an object whose corner scale came from the data set (``creference
    batch``: 2.5 px over 300 degrees of freedom): the model with nothing more is the model, and with
    a set more on one target the other targets keep that scale (within what the new set's own few
    degrees of freedom add), as the frame estimated again with the set does. Without it they fell
    to the new set's spread alone (its 8 coordinates) and the references' line noise with them."""
    scene = dataclasses.replace(_with_sets(_scene(5, tier="medium", setting="outdoor", n_objects=3, sizes="prior",
                                                  n_references=2), 1), corner_scale=(2.5, 300.0))
    model = _frame_model(scene)
    cams, objs = _states(scene, model, 50, np.random.default_rng(2))
    same = grown(model, {})
    np.testing.assert_array_equal(same.sigma, model.sigma)
    np.testing.assert_array_equal(same.neg_log_posterior(cams, objs), model.neg_log_posterior(cams, objs))
    lines = np.asarray(scene.targets[0].corners[0]) + np.random.default_rng(3).normal(0, 2.5, (4, 2))
    more = grown(model, {}, annotations={0: lines})
    again, _ = build_model(with_dimension_lines(scene, scene.targets[0].id, lines))
    np.testing.assert_allclose(more.sigma, again.sigma, rtol=1e-9)
    assert more.ref_line_sigma == pytest.approx(again.ref_line_sigma, rel=1e-9)
    np.testing.assert_allclose(more.sigma[1:], model.sigma[1:], rtol=0.05)


@pytest.mark.parametrize("kind", ["ground", "ground-range", "size", "distance"])
def test_reference_weights_are_the_difference_of_the_models_posteriors(frame, kind):
    scene, model, cams, objs = frame
    line = np.asarray(scene.references[1].line, float)
    term = {"size": ReferenceTerm(0, "size", 1, 1, False, owner=1, size_index=0),
            "distance": ReferenceTerm(0, "distance", 1, 1, False, owner=0, other=2)}.get(
        kind, ReferenceTerm(0, "ground", 1, 1, False, line=line))
    obs = ReferenceObservation(model, term, {}, range_share=float(kind == "ground-range"), temperature=2.0)
    assert obs.usable and not obs.needs_scale
    obs.simulate(np.random.default_rng(7), cams[:6], objs[:6])
    fast = obs.log_ratio(cams, objs)
    base = model.neg_log_posterior(cams, objs, 2.0)
    for i in range(6):
        brute = base - obs.model_with(i).neg_log_posterior(cams, objs, 2.0)
        assert np.ptp(fast[i] - brute) < 1e-8, f"row {i}: not a constant offset ({np.ptp(fast[i] - brute):.2e})"
    assert obs.is_range.all() == (kind == "ground-range")


def test_a_first_reference_brings_its_crowd_scale_from_the_prior(frame):
    """A scene without references has no crowd scale: the draws get one from its prior, and the
    weights are then the new model's posterior over the old one's times that prior."""
    scene, model, cams, objs = frame
    bare = dataclasses.replace(scene, references=(), reference_targets=())
    m0, _ = build_model(bare)
    m0.handedness, m0.pilot = model.handedness, model.pilot
    obs = ReferenceObservation(m0, ReferenceTerm(0, "ground", 1, 1, False, line=scene.references[1].line), {})
    assert obs.needs_scale and not m0.camera_free[C_SCALE]
    c = obs.scale_draws(cams, np.random.default_rng(1))
    assert np.median(c[:, C_SCALE]) == pytest.approx(0.5, rel=0.2)
    obs.simulate(np.random.default_rng(2), c[:4], objs[:4])
    old = m0.neg_log_posterior(c, objs) + m0.ref_scale_neg_log(c[:, C_SCALE])
    for i, row in enumerate(obs.log_ratio(c, objs)):
        assert np.ptp(row - (old - obs.model_with(i).neg_log_posterior(c, objs))) < 1e-8


def test_dimension_line_weights_follow_the_new_corner_scales(frame):
    scene, model, cams, objs = frame
    obs = DimsObservation(model, 1, {})
    obs.simulate(np.random.default_rng(8), cams[:3], objs[:3])
    new = obs.model_with(0)
    assert new.sigma[1] != model.sigma[1] and np.all(new.sigma[[0, 2]] == model.sigma[[0, 2]])
    assert new.ref_line_sigma != model.ref_line_sigma  # … and so the references' line noise
    # the weights are the whole difference of the posteriors, not the new set's likelihood alone
    base = model.neg_log_posterior(cams, objs)
    with_sigma = obs.log_ratio(cams, objs, base)[0]
    fixed = grown(model, {"ref_line_sigma": model.ref_line_sigma}, annotations={1: obs.corners[0]})
    fixed.sigma = model.sigma.copy()  # the new set's likelihood at the old scales
    assert np.ptp(with_sigma - (base - fixed.neg_log_posterior(cams, objs))) > 1e-3


@pytest.mark.parametrize("case", ["references move", "references stay", "no references", "one set each"])
def test_dimension_line_weights_are_the_difference_of_the_whole_posteriors(frame, case):
    """However the weights of a simulated set are computed (on the terms it changes, or on the whole
    posterior where the references' line noise moves), they are base − the new model's negative
    log-posterior at every draw, each draw at its own handedness, at a temperature."""
    scene, model, cams, objs = frame
    options = {}
    if case == "references stay":  # the references' line noise given: only the annotations change
        options = {"ref_line_sigma": model.ref_line_sigma}
        model = grown(model, options)
    elif case == "no references":
        model = _frame_model(dataclasses.replace(scene, references=()))
    elif case == "one set each":  # σ pooled over the objects with several sets: a new set moves them all
        model = _frame_model(dataclasses.replace(scene, targets=tuple(
            dataclasses.replace(t, dimension_lines=t.dimension_lines[:k]) for t, k in zip(scene.targets, (1, 3, 1)))))
    hands = np.where(np.random.default_rng(2).uniform(size=(len(cams), 3)) < 0.2, -1.0, 1.0) * model.handedness
    temperature = 1.7
    obs = DimsObservation(model, 1, options, temperature)
    obs.simulate(np.random.default_rng(8), cams[:4], objs[:4], hands[:4])
    at = model.at_handedness(hands)
    base = at.neg_log_posterior(cams, objs, temperature)
    got = obs.log_ratio(cams, objs, base, hands=hands)
    new = obs.model_with(0)
    if case == "references move":
        assert new.ref_line_sigma != model.ref_line_sigma
    elif case == "references stay":
        assert new.ref_line_sigma == model.ref_line_sigma and len(model.all_references)
    elif case == "one set each":
        assert np.all(new.sigma != model.sigma)  # the pooled scale of the one-set objects moved too
    for k in range(4):
        want = base - obs.model_with(k).at_handedness(hands).neg_log_posterior(cams, objs, temperature)
        np.testing.assert_allclose(got[k], want, rtol=1e-9, atol=1e-7)
        assert np.ptp(want) > 1e-3


def test_simulated_dimension_lines_scatter_as_the_scenes_sets_do(frame):
    """Three sets: the target's corner scale is their sd, and a simulated set must scatter by
    that sd (a t₄ of that scale would scatter √2 more than any set seen). One set in every target:
    the model's stated t₄ scale (5 px), whose sd is √2 · 5 px; with the data set's corner scale,
    read from other frames' sets, the sd that scale is."""
    scene, model, cams, objs = frame
    rows, orows = np.repeat(cams[:1], 4000, axis=0), np.repeat(objs[:1], 4000, axis=0)
    proj = model.project(cams[:1], objs[:1])[0][0, 2]
    obs = DimsObservation(model, 2, {})
    obs.simulate(np.random.default_rng(9), rows, orows)
    err = (obs.corners - proj).reshape(-1)
    assert np.std(err) == pytest.approx(model.sigma[2], rel=0.1)
    assert abs(np.median(err)) < 0.05 * model.sigma[2]
    m1, _ = build_model(_with_sets(scene, 1))
    m1.handedness = model.handedness
    assert np.all(m1.sigma == 5.0)
    one = DimsObservation(m1, 2, {})
    one.simulate(np.random.default_rng(9), rows, orows)
    # bivariate t with ν = 4 and scale σ: each coordinate has variance σ² ν / (ν − 2) = 2σ²
    assert np.std((one.corners - proj).reshape(-1)) == pytest.approx(np.sqrt(2) * 5.0, rel=0.1)
    # one set each, the crowd's corner scale from the data set (other frames' sets: an sd, 3 px over
    # 400 degrees of freedom): a simulated set scatters by that sd, as the crowd's sets do
    m2, _ = build_model(dataclasses.replace(_with_sets(scene, 1), corner_scale=(3.0, 400.0)))
    m2.handedness = model.handedness
    assert np.allclose(m2.sigma, 3.0)
    pooled = DimsObservation(m2, 2, {})
    pooled.simulate(np.random.default_rng(9), rows, orows)
    assert np.std((pooled.corners - proj).reshape(-1)) == pytest.approx(3.0, rel=0.1)


# ------------------------------------------------------------------------------------------------
# candidates


def test_candidates_group_repeated_segments_and_cover_every_target(frame):
    scene, model, cams, objs = frame
    refs = list(scene.references)
    # a second worker on reference 0's object and measure, drawn a few pixels off and reversed
    twin = dataclasses.replace(refs[0], index=2, line=refs[0].line[::-1] + 2.0, worker="w-twin")
    # the same object name but a segment far away: another object of that name
    other = dataclasses.replace(refs[0], index=3, line=refs[0].line + np.array([400.0, 0.0]), worker="w-far")
    # a worker's distance between the first two targets
    pair = dataclasses.replace(refs[0], index=4, measure="distance", mode="direct", line=None, object=None)
    scene = dataclasses.replace(scene, references=tuple(refs) + (twin, other, pair),
                                reference_targets=scene.reference_targets + (None, None, (0, 1)))
    cands, notes = candidates(scene, model, *true_state(scene))
    keys = [c.key for c in cands]
    assert len(set(keys)) == len(keys)
    repeats = [c for c in cands if c.based_on and not c.new_segment]
    assert repeats[0].based_on == (0, 2) and any(c.based_on == (3,) for c in repeats)
    for c in cands:
        if c.new_segment:
            assert c.measure == "distance" and c.line[0, 1] == scene.image_height - 1
    ids = [t.id for t in scene.targets]
    between = [c for c in cands if c.term is not None and c.term.kind == "distance"]
    assert sum({c.term.owner, c.term.other} == {0, 1} for c in between) == 1  # the scene's own, repeated
    assert next(c for c in between if {c.term.owner, c.term.other} == {0, 1}).based_on == (4,)
    for i, tid in enumerate(ids):  # dimension lines, a length (class priors) and a pair distance each
        assert f"{tid}:dims" in keys and f"{tid}:length" in keys
        assert f"{tid}:distance" in keys or any(n.startswith(f"{tid}:distance") for n in notes)
        assert any(c.term is not None and c.term.kind == "distance" and i in (c.term.owner, c.term.other)
                   for c in cands)


def test_seconds_are_the_scenes_medians_else_the_papers():
    scene = _with_sets(_scene(12, n_references=2), 3)
    t = scene.targets[0]
    lines = tuple(dataclasses.replace(d, seconds=s) for d, s in zip(t.dimension_lines, (100.0, None, 300.0)))
    scene = dataclasses.replace(scene, targets=(dataclasses.replace(t, dimension_lines=lines),),
                                references=tuple(dataclasses.replace(r, seconds=None) for r in scene.references))
    assert annotation_seconds(scene) == {"dims": 200.0, "reference": PAPER_REFERENCE_SECONDS}
    bare = _with_sets(scene, 1)
    bare = dataclasses.replace(bare, targets=(dataclasses.replace(bare.targets[0], dimension_lines=(
        dataclasses.replace(bare.targets[0].dimension_lines[0], seconds=None),)),))
    assert annotation_seconds(bare)["dims"] == PAPER_TARGET_SECONDS


def test_format_mix_counts_ranges_and_their_precision():
    scene = _scene(13, n_references=10, format_offset=0)
    mix = format_mix(scene)
    assert mix.range_share == pytest.approx(sum(r.is_range for r in scene.references) / 10)
    assert 0.0 < mix.range_precision < 2.0


def test_a_simulated_reference_on_a_segment_near_the_horizon_is_read_as_the_model_reads_it(frame):
    """A new reference on a short segment 60 px below the horizon, simulated at the true camera by
    a crowd of almost no error: its values scatter as the model's reading of the drawn segment
    says (a mixture of its bins, each a Student-t, skewed and moved from the drawn segment's length:
    at 86 m, 8 px of row noise hide metres of depth), not around the drawn segment's length."""
    scene, model, cams, objs = frame
    a, b, c = model.horizon_line
    row = (60.0 - c - a * 1440.0) / b
    line = np.array([[1400.0, row], [1440.0, row]])
    obs = ReferenceObservation(model, ReferenceTerm(0, "ground", 1, 1, False, line=line), {})
    cam, o = true_state(scene)
    at = model.complete_camera(np.repeat(cam[None], 20000, axis=0))
    at[:, C_SCALE] = 1e-3
    obs.simulate(np.random.default_rng(3), at, np.repeat(o[None], 20000, axis=0))
    error = obs.log_low - np.log(ground_lengths(line[None], model.principal_point, at[:1]))[0, 0]
    p = obs.probe
    rng = np.random.default_rng(4)
    k = rng.integers(p.ref_node_shift.shape[1], size=200_000)
    bins = -(p.ref_shift[-1] + p.ref_node_shift[-1, k]) + np.sqrt(p.ref_node_var[-1, k]) * rng.standard_t(p.ref_dof, len(k))
    want = np.percentile(bins, [10, 50, 90])
    assert abs(want[1]) > 0.05 and want[2] - want[1] > 1.2 * (want[1] - want[0])  # moved and skewed
    np.testing.assert_allclose(np.percentile(error, [10, 50, 90]), want, atol=0.06)
