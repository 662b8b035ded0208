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
