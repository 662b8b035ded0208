"""The log-posterior (method.md §7) and its Laplace start."""

from dataclasses import dataclass, field

import numpy as np
import pytest

from creference_bayes.core.geometry import Camera
from creference_bayes.core.metrology import aggregate_references
from creference_bayes.models.params import Bounds, wrap_angle
from creference_bayes.inference.optimize import optimize_map
from creference_bayes.camera_setup import setup_camera
from creference_bayes.pipeline import build_models, estimate
from creference_bayes.inference.posterior import LogPosterior, laplace_scales


@dataclass
class QuadraticModel:
    """cost = ½ (p − c)ᵀ H (p − c) over all seven parameters, with wide bounds."""

    H: np.ndarray
    c: np.ndarray
    bounds: Bounds = field(default_factory=lambda: Bounds(np.full(7, -100.0), np.full(7, 100.0)))
    name: str = "quadratic"

    def __post_init__(self):
        self.free = np.ones(7, bool)

    def expand(self, p):
        return np.atleast_2d(p)

    def cost(self, p):
        d = p - self.c
        return 0.5 * np.einsum("ni,ij,nj->n", d, self.H, d)


def _paper_model(scene):
    models = build_models(scene, setup_camera(scene, focal_prior="none"), model="paper")
    m = optimize_map(models, rng=0)
    return next(x for x in models if x.handedness == m.handedness), m


def test_log_posterior_is_minus_cost_over_temperature(make_scene):
    model, m = _paper_model(make_scene(1, tier="low"))
    p = m.params[model.free] + np.array([0.01, -0.02, 0.05, 0.01, 3.0])
    cost = model.cost(model.expand(p[None]))[0]
    for t in (1.0, 2.5):
        assert LogPosterior(model, t)(p)[0] == pytest.approx(-cost / t, rel=1e-12)


def test_support_is_the_bounds_but_yaw_is_circular(make_scene):
    model, m = _paper_model(make_scene(2, tier="low"))
    lp = LogPosterior(model)
    p = m.params[model.free].copy()
    turned = p.copy()
    turned[3] += 4 * np.pi  # outside [−π, π), same orientation
    np.testing.assert_allclose(lp(turned), lp(p), rtol=1e-9)
    assert wrap_angle(turned[3]) == pytest.approx(p[3])
    outside = p.copy()
    outside[2] = model.bounds.upper[2] * 1.01
    assert lp(outside)[0] == -np.inf
    outside = p.copy()
    outside[4] = model.bounds.lower[4] * 0.99
    assert lp(outside)[0] == -np.inf
    assert lp(np.where(np.arange(len(p)) == 0, np.nan, p))[0] == -np.inf


def test_non_finite_costs_become_minus_infinity():
    model = QuadraticModel(np.eye(7), np.zeros(7))
    bad = QuadraticModel(np.eye(7), np.zeros(7))
    bad.cost = lambda p: np.array([np.nan, np.inf, -np.inf, 1.0])[: len(p)]
    out = LogPosterior(bad)(np.zeros((4, 7)))
    assert out[:3].tolist() == [-np.inf, -np.inf, -np.inf] and out[3] == -1.0
    assert np.isfinite(LogPosterior(model)(np.zeros((1, 7))))[0]


@pytest.mark.parametrize("t", [0, -1, np.nan, np.inf, True])
def test_temperature_must_be_positive(t):
    with pytest.raises(ValueError, match="temperature"):
        LogPosterior(QuadraticModel(np.eye(7), np.zeros(7)), t)


def test_laplace_recovers_a_known_covariance():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((7, 7))
    cov = a @ a.T + 0.5 * np.eye(7)
    c = rng.standard_normal(7)
    lap = laplace_scales(LogPosterior(QuadraticModel(np.linalg.inv(cov), c), temperature=2.0), c)
    assert lap.positive_definite
    np.testing.assert_allclose(lap.cov, 2.0 * cov, rtol=1e-6, atol=1e-9)


def test_laplace_falls_back_on_a_kink():
    """|p| has no curvature at its minimum: the fallback gives positive, finite scales."""
    model = QuadraticModel(np.eye(7), np.zeros(7))
    w = np.arange(1, 8)
    model.cost = lambda p: np.sum(np.abs(p) * w, axis=1)
    lap = laplace_scales(LogPosterior(model), np.zeros(7))
    assert np.all(np.isfinite(lap.scale)) and np.all(lap.scale > 0)
    # along each axis the log-density falls by ~0.5 within about one scale
    assert np.all(np.abs(lap.scale * w - 0.5) < 0.5)


def test_laplace_on_the_bound_measures_the_inner_side():
    """A MAP on the box's upper bound of z, the density rising towards it (log p = z + const,
    no curvature there): the step is the inner side's, where log p has fallen by about ½ (0.5 m),
    not the 1e-6 of the box by which the MAP is moved inside (the outer side has zero density and
    says nothing about the width). The sampler's starting cloud is this wide along z."""
    model = QuadraticModel(np.eye(7), np.zeros(7), Bounds(np.full(7, -10.0), np.full(7, 10.0)))
    model.cost = lambda p: 0.5 * np.sum(np.delete(p, 2, axis=1) ** 2, axis=1) + (10.0 - p[:, 2])
    x0 = np.zeros(7)
    x0[2] = 10.0 - 1e-6 * 20.0
    lap = laplace_scales(LogPosterior(model), x0)
    assert not lap.positive_definite  # no curvature along z: the conditional widths
    # a fall of ½ at 0.5 m; the bracket accepts a fall of ⅛ to 2, so 0.125–2 m
    assert 0.12 < lap.scale[2] < 2.01, lap.scale
    assert np.all((np.delete(lap.scale, 2) > 0.49) & (np.delete(lap.scale, 2) < 2.01)), lap.scale


def test_laplace_near_a_bound_keeps_its_full_hessian():
    """A MAP 0.3 inside a bound, the posterior's scale several times that: the width is measured
    on the inner side, but the Hessian's central differences are taken with steps short enough
    to stay inside, so a Gaussian's covariance is still recovered exactly."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((7, 7))
    cov = a @ a.T + 0.5 * np.eye(7)
    c = np.zeros(7)
    c[2] = 9.7
    model = QuadraticModel(np.linalg.inv(cov), c, Bounds(np.full(7, -10.0), np.full(7, 10.0)))
    lap = laplace_scales(LogPosterior(model), c)
    assert lap.positive_definite
    np.testing.assert_allclose(lap.cov, cov, rtol=1e-6, atol=1e-9)


def test_laplace_in_a_corner_of_the_support_keeps_the_nominal_scale():
    """Where every step along an axis long enough to measure a width leaves the support (a corner
    that only a combination of parameters can leave inwards), that axis keeps its nominal start
    scale instead of shrinking to the corner's size."""
    model = QuadraticModel(np.eye(7), np.zeros(7))
    lp = LogPosterior(model)

    class Wedge:  # the support cut to −(1e-6 + |p5|) ≤ p6 ≤ 0
        free = lp.free

        def __call__(self, p):
            p = np.atleast_2d(p)
            out = lp(p)
            return np.where((p[:, 6] <= 0) & (p[:, 6] >= -(1e-6 + np.abs(p[:, 5]))), out, -np.inf)

    lap = laplace_scales(Wedge(), np.zeros(7))
    assert lap.scale[6] >= 0.01, lap.scale  # the nominal roll scale (rad)
    assert np.all((lap.scale[:5] > 0.49) & (lap.scale[:5] < 2.01)), lap.scale


def test_a_map_on_the_box_bound_needs_no_long_warm_up():
    """SBC's thin scene 12 (seed 0): the MAP sits on the box's 60 m bound and the posterior runs
    down the depth–focal ridge to about 35 m. Started from a cloud 1e-6 of the box thin along
    the ridge, the warm-up crawled down it to its 5000-step cap; started from the inner side's
    width it settles in the first stages."""
    import warnings

    from creference_bayes.bench.sbc import DESIGNS, SBC_BOX, draw_truth, simulate_sbc_scene
    from creference_bayes.io.scene import parse_scene

    n_target, refs = DESIGNS["thin"]
    rng = np.random.default_rng([0, list(DESIGNS).index("thin"), 12])
    data = None
    while data is None:
        data = simulate_sbc_scene(rng, draw_truth(rng, SBC_BOX), n_target, refs[12 % len(refs)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = parse_scene(data)
    r = estimate(scene, seed=[0, 12], bounds=SBC_BOX.bounds(), location_prior="log-depth",
                 focal_prior="default")
    assert r.map.params[2] > 59.9  # the MAP on the bound: the case this test is about
    assert r.diagnostics.converged
    assert r.diagnostics.warmup_steps <= 1000, r.diagnostics.warmup_steps
    lo, hi = r.posterior.hdi["z"]
    assert lo < 45.0 and hi > 58.0  # the ridge, found


def test_noise_free_posterior_concentrates_on_the_truth(make_scene):
    """Exact annotations and exact references: every true value inside its 90 % HDI, and the
    posterior mean within 3 % (Eq. 3) of the true location, with a tight posterior."""
    scene = make_scene(11, tier="none", principal_offset=0.05)
    camera = Camera.from_scene(scene)
    report = aggregate_references(scene, camera)
    assert report.pairs_used >= 3
    models = build_models(scene, setup_camera(scene, focal_prior="none"), model="paper",
                          constraints=report.constraints)
    m = optimize_map(models, rng=0)
    model = next(x for x in models if x.handedness == m.handedness)
    from creference_bayes.inference.sampling import sample
    from creference_bayes.inference.summary import evaluate_posterior, summarise

    lp = LogPosterior(model)
    lap = laplace_scales(lp, m.params[model.free])
    chains = sample(lp, m.params[model.free], lap.cov, rng=1, log_mask=model.bounds.lower[model.free] > 0)
    post, diag = summarise(chains, model.expand)
    err, inside = evaluate_posterior(post, scene.ground_truth, list(diag.r_hat))
    assert diag.converged, diag.warnings
    assert all(inside.values()), (inside, post.hdi)
    assert err < 3.0
    assert post.sd["distance_m"] < 0.1 * post.mean["distance_m"]


def test_known_focal_length_is_not_sampled(make_scene):
    scene = make_scene(12, tier="low")
    from dataclasses import replace

    scene = replace(scene, focal_length_px=scene.ground_truth.focal_length_px)
    r = estimate(scene, seed=0, sampling={"min_ess": 300, "tau_multiple": 20})
    assert r.posterior.sd["focal_length_px"] == 0.0
    assert r.posterior.mean["focal_length_px"] == pytest.approx(scene.focal_length_px)
    assert "focal_length_px" not in r.diagnostics.r_hat



def test_yaw_center_confines_yaw_to_one_turn(make_scene):
    """With ``yaw_center`` the density lives on (c − π, c + π], the circle cut open opposite c:
    the same values inside, zero a turn away; without it yaw is periodic and unbounded."""
    model, m = _paper_model(make_scene(2, tier="low"))
    p = m.params[model.free].copy()
    c = float(p[3])
    lp, cut = LogPosterior(model), LogPosterior(model, yaw_center=c)
    near = np.array([p + np.eye(len(p))[3] * d for d in (-3.0, -0.5, 0.0, 0.5, 3.0)])
    np.testing.assert_allclose(cut(near), lp(near), rtol=1e-12)
    turned = np.array([p + np.eye(len(p))[3] * d for d in (-2 * np.pi, 2 * np.pi, np.pi + 1e-6)])
    assert np.all(np.isfinite(lp(turned)))
    assert np.all(cut(turned) == -np.inf)
    with pytest.raises(ValueError, match="yaw_center"):
        LogPosterior(model, yaw_center=float("nan"))
