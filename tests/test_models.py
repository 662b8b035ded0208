"""The model contract and its two models (models/contract.py, metrology.py, paper.py): geometry
against OpenCV and the one-target geometry, likelihood terms against SciPy, the contract's pieces
adding up, the paper's cost against the one-target cost it restates."""

import numpy as np
import pytest
from scipy import stats

from conftest import truth_scene
from creference_bayes.core.cost import target_cost
from creference_bayes.core.geometry import Camera, dimension_corners, rotation_from_pitch_roll
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.contract import (C_SCALE, REF_SCALE_LOG_SD, REF_SCALE_MEDIAN, Bounds, Model, ObjectData,
                                              object_corners)
from creference_bayes.models.metrology import (MetrologyModel, ReferenceTerm, ground_lengths, segment_floor,
                                               t_interval, target_sigmas)
from creference_bayes.pipeline import build_model


def _model(seed=0, **kw):
    d, truth = truth_scene(seed, **kw)
    model, _ = build_model(parse_scene(d))
    model.handedness = truth["handedness"].astype(float)
    return model, truth


def test_object_corners_are_the_one_target_geometry():
    for hand in (1, -1):
        got = object_corners(np.array([[4.2, 1.7, 1.5]]), np.array([hand]))[0]
        np.testing.assert_allclose(got, dimension_corners(4.2, 1.7, 1.5, hand))


def test_projection_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    model, truth = _model(4, m=3, ground_sd_m=0.1)
    cam, objs = truth["camera"], truth["objects"]
    uv, _ = model.project(cam[None], objs[None])
    R = rotation_from_pitch_roll(cam[1], cam[2])
    K = np.array([[cam[0], 0, model.principal_point[0]], [0, cam[0], model.principal_point[1]], [0, 0, 1.0]])
    for i in range(3):
        c, s = np.cos(objs[i, 2]), np.sin(objs[i, 2])
        Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        loc = np.array([objs[i, 0], cam[3] - objs[i, 6], objs[i, 1]])
        pts = loc + dimension_corners(*objs[i, 3:6], int(model.handedness[i])) @ Ry.T
        ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], np.zeros(3), K, None)
        np.testing.assert_allclose(uv[0, i], ref[:, 0], atol=1e-6)


def test_the_terms_add_up_to_the_posterior_and_the_pointwise_likelihood_to_the_likelihood():
    model, truth = _model(1, m=3, n_annotations=2, noise_px=2.0, n_refs=3, sizes_known=False)
    rng = np.random.default_rng(0)
    cams = model.complete_camera(truth["camera"] + rng.normal(0, [5, 0.01, 0.01, 0.05, 0.1], (6, 5)))
    objs = truth["objects"] + rng.normal(0, 0.05, (6, 3, 7))
    c, o, p = model.terms(cams, objs, 2.0)
    np.testing.assert_allclose(c, model.camera_term(cams, 2.0))
    np.testing.assert_allclose(o, model.object_terms(cams, objs, 2.0))
    np.testing.assert_allclose(model.neg_log_posterior(cams, objs, 2.0), c + o.sum(1) + p.sum(1))
    ll = model.pointwise_log_likelihood(cams, objs)
    nll = model.camera_nll(cams) + model.object_nll(cams, objs).sum(1) + model.pair_nll(cams, objs).sum(1)
    behind = model.behind(model.project(cams, objs)[1]).sum(1)  # a penalty, not an observation
    np.testing.assert_allclose(-(ll["annotations"].sum((1, 2)) + ll["references"].sum(1) + ll["horizon"]),
                               nll - behind, rtol=1e-10)


def test_reference_terms_are_student_t_in_log_length():
    """A single value's term is the t density of log v around log ℓ (scale √(s² + line variance)),
    a range's the t probability of the interval; SciPy's densities, up to their constants."""
    model, truth = _model(2, n_refs=2)
    line = np.asarray(model.references[0].line)
    refs = [ReferenceTerm(0, "ground", 3.0, 3.0, False, line), ReferenceTerm(1, "ground", 2.0, 5.0, True, line)]
    m = MetrologyModel(model.principal_point, model.image_size, model.objects, refs, ref_line_sigma=0.0)
    cams = m.complete_camera(np.array([truth["camera"]] * 3))
    cams[:, C_SCALE] = [0.2, 0.5, 1.5]
    ell = ground_lengths(line[None], m.principal_point, cams)[:, 0]
    nll = m.reference_nll_matrix(cams, truth["objects"][None].repeat(3, 0))
    single = -stats.t.logpdf(np.log(3.0), 2.0, loc=np.log(ell), scale=cams[:, C_SCALE])
    rng_ = -np.log(stats.t.cdf(np.log(5.0), 2.0, np.log(ell), cams[:, C_SCALE])
                   - stats.t.cdf(np.log(2.0), 2.0, np.log(ell), cams[:, C_SCALE]))
    diff = nll[:, 0] - single  # the same constant for every scale
    np.testing.assert_allclose(diff, diff[0], atol=1e-9)
    np.testing.assert_allclose(nll[:, 1], rng_, rtol=1e-9)


def test_closed_form_t2_interval_matches_scipy_far_into_the_tails():
    rng = np.random.default_rng(0)
    lo = -np.exp(rng.uniform(-5, 14, 2000))
    hi = lo + np.exp(rng.uniform(-6, 15, 2000))
    t2, t3 = stats.t(2), stats.t(3)
    # scipy's lower-tail form where the interval sits in the lower half, its upper-tail form otherwise
    lower = lo + hi <= 0
    want2 = np.where(lower, t2.cdf(hi) - t2.cdf(lo), t2.sf(lo) - t2.sf(hi))
    want3 = np.where(lower, t3.cdf(hi) - t3.cdf(lo), t3.sf(lo) - t3.sf(hi))
    assert 0 < lower.sum() < len(lo)  # both halves are exercised
    np.testing.assert_allclose(t_interval(2.0, lo, hi), want2, rtol=1e-6)  # both lose digits to cancellation
    np.testing.assert_allclose(t_interval(3.0, lo, hi), want3, rtol=1e-8, atol=1e-15)
    np.testing.assert_allclose(t_interval(2.0, -hi, -lo), t_interval(2.0, lo, hi), rtol=1e-12)


def test_priors_are_densities_of_the_stated_distributions():
    model, truth = _model(3, m=2, sizes_known=False, n_refs=2)
    cams = model.complete_camera(np.array([truth["camera"], truth["camera"] * [1.1, 1, 1, 1.2, 2]]))
    p = model.height_prior
    want = (-stats.norm.logpdf(cams[:, 1], p.pitch_mean, p.pitch_sd) - stats.norm.logpdf(cams[:, 2], p.roll_mean, p.roll_sd)
            - stats.lognorm.logpdf(cams[:, 3], p.height_log_sd, scale=p.height_median_m)
            - stats.lognorm.logpdf(cams[:, 4], REF_SCALE_LOG_SD, scale=REF_SCALE_MEDIAN)
            + model.camera_terms.focal.neg_log(cams[:, 0]))
    got = model.camera_neg_log_prior(cams)
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-9)



def test_the_ground_offset_prior_is_a_student_t_whose_scale_grows_with_distance():
    model, truth = _model(3, m=2)
    assert model.object_free[:, 6].all()
    objs = np.repeat(truth["objects"][None], 4, axis=0)
    objs[:, :, 0], objs[:, :, 1] = 3.0, [[4.0], [4.0], [40.0], [40.0]]  # ground distance 5 m or √1609 m
    objs[:, :, 6] = [[0.0], [0.3], [0.0], [0.3]]
    d = np.hypot(3.0, [4.0, 4.0, 40.0, 40.0])
    # default: scale √(0.056² + (0.0017 d)²) m, 2 degrees of freedom; as SciPy's t density of g
    s = np.hypot(0.056, 0.0017 * d)
    want = -(stats.t.logpdf(objs[:, 0, 6] / s, 2.0) - np.log(s))
    got = model.ground_neg_log_prior(objs)[:, 0]
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-12)
    assert got[3] - got[2] < got[1] - got[0]  # the same offset costs less 40 m away than 5 m away
    normal = Model(model.principal_point, model.image_size, model.objects, ground_sd_m=0.08, ground_sd_per_m=0.0,
                   ground_dof=np.inf)  # the earlier prior: N(0, 0.08²) at every distance
    got = normal.ground_neg_log_prior(objs)[:, 0]
    want = -stats.norm.logpdf(objs[:, 0, 6], 0.0, 0.08)
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-12)
    assert not Model(model.principal_point, model.image_size, model.objects, ground_sd_m=0.0).object_free[:, 6].any()
    for key, bad in (("ground_sd_m", -0.1), ("ground_sd_per_m", np.nan), ("ground_dof", 0.0)):
        with pytest.raises(ValueError, match=f"{key}: expected .*got {bad}"):
            Model(model.principal_point, model.image_size, model.objects, **{key: bad})

def test_target_scales_pool_over_objects_with_one_annotation():
    rng = np.random.default_rng(0)
    a = rng.normal(0, 2.0, (5, 4, 2))
    one = rng.normal(0, 2.0, (1, 4, 2))
    s = target_sigmas([a, one])
    assert s[0] == s[1] == pytest.approx(np.sqrt(np.sum((a - a.mean(0)) ** 2) / 32))
    assert target_sigmas([one])[0] == 5.0


def test_the_data_sets_corner_scale_joins_the_pool_of_objects_annotated_once():
    rng = np.random.default_rng(1)
    a = rng.normal(0, 2.0, (3, 4, 2))
    one = rng.normal(0, 2.0, (1, 4, 2))
    assert target_sigmas([one], corner_scale=(3.0, 40.0))[0] == pytest.approx(3.0)
    s = target_sigmas([a, one], corner_scale=(3.0, 40.0))
    ss = np.sum((a - a.mean(0)) ** 2)
    assert s[0] == pytest.approx(np.sqrt(ss / 16))  # its own annotations: the data set does not enter
    assert s[1] == pytest.approx(np.sqrt((ss + 40.0 * 9.0) / (16 + 40)))


def test_a_reference_above_an_exact_horizon_is_left_out():
    d, truth = truth_scene(5, horizon="exact", n_refs=1)
    d["references"].append({"measure": "length", "mode": "direct", "value": 2.0, "unit": "m",
                            "line": [[100.0, 10.0], [300.0, 12.0]]})
    model, _ = build_model(parse_scene(d))
    assert model.reference_status == {0: "used", 1: "endpoint_above_horizon"}
    assert model.n_references_used == 1


def test_the_paper_model_is_the_paper_cost_for_one_target():
    """Eq. 5 on the per-corner median plus the penalties: for one target, the one-target cost the
    package had before (core.cost.target_cost), state for state."""
    d, truth = truth_scene(6, n_annotations=3, noise_px=3.0)
    model, _ = build_model(parse_scene(d), model="paper", preset="paper")
    model.handedness = truth["handedness"].astype(float)
    rng = np.random.default_rng(1)
    cams = model.complete_camera(truth["camera"] + rng.normal(0, [20, 0.0, 0.0, 0.1, 0], (5, 5)))
    objs = truth["objects"] + rng.normal(0, 0.2, (5, 1, 7)) * [1, 1, 1, 0, 0, 0, 0]
    params = np.column_stack([objs[:, 0, 0], cams[:, 3], objs[:, 0, 1], objs[:, 0, 2], cams[:, 0], cams[:, 1], cams[:, 2]])
    o = model.objects[0]
    want = target_cost(params, np.median(o.annotations, axis=0), dimension_corners(*o.sizes, int(model.handedness[0])),
                       Camera(model.principal_point, None, None), model.sigma)
    np.testing.assert_allclose(model.object_nll(cams, objs)[:, 0], want, rtol=1e-10)


def test_bounds_and_free_parameters():
    model, truth = _model(7, m=2, sizes_known=False, focal_known=True, horizon="exact")
    assert not model.camera_free[0] and not model.camera_free[1:3].any()  # µ known; pitch, roll derived
    assert model.object_free[:, 3:6].all()  # sizes from the class prior
    b = Bounds.box(model.image_size, x=(-3, 3), z=(5, 60))
    assert b.object_lower[0] == -3 and b.object_upper[1] == 60
    with pytest.raises(ValueError, match="lower bound above"):
        Bounds(b.camera_upper, b.camera_lower, b.object_lower, b.object_upper)
    cams = model.complete_camera(np.array([truth["camera"]]))
    assert model.in_bounds(cams, truth["objects"][None])[0]
    assert not model.in_bounds(cams * [1, 1, 1, 100, 1], truth["objects"][None])[0]


def test_an_object_needs_a_size_or_a_prior():
    with pytest.raises(ValueError, match="needs known sizes or a size prior"):
        ObjectData("a", np.zeros((1, 4, 2)))
    with pytest.raises(ValueError, match="shape"):
        ObjectData("a", np.zeros((4, 2)), sizes=(1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="at least one target"):
        Model([0, 0], (10, 10), [])


def test_line_noise_widens_far_references_and_is_fixed_at_the_pilot():
    """s_j² = s² + σ_line² |∇ log ℓ_j|² at the pilot: against an independent central difference of
    the log-length over the endpoints, larger for the segment nearest the horizon; the corrected
    reading (an option) shifts short segments and never narrows them."""
    d, truth = truth_scene(4, horizon="exact", n_refs=4)
    scene = parse_scene(d)
    m, _ = build_model(scene, ref_line_sigma=10.0, line_reading="linear")
    assert np.all(m.ref_line_var == 0)  # before the pilot
    m.set_pilot(truth["camera"])
    lines = np.array([r.line for r in m.references])
    cam = m.complete_camera(truth["camera"][None])
    g2 = np.zeros(len(lines))
    for k in range(4):
        step = np.eye(4)[k].reshape(2, 2) * 1e-3
        g2 += ((np.log(ground_lengths(lines + step, m.principal_point, cam)) -
                np.log(ground_lengths(lines - step, m.principal_point, cam)))[0] / 2e-3) ** 2
    np.testing.assert_allclose(m.ref_line_var, 100.0 * g2, rtol=0.05)
    from creference_bayes.models.metrology import linear_line_variances

    up = lines[:1] - [0.0, 300.0]  # the same segment drawn nearer the horizon: farther away
    near_far = linear_line_variances(np.concatenate([lines[:1], up]), m.principal_point, cam[0], 10.0)
    assert near_far[1] > 1.3 * near_far[0]
    c, _ = build_model(scene, ref_line_sigma=10.0, line_reading="corrected")
    c.set_pilot(truth["camera"])
    assert np.all(c.ref_line_var >= m.ref_line_var * (1 - 1e-9)) and np.all(c.ref_shift >= -1e-9)
    with pytest.raises(ValueError, match="line_reading"):
        build_model(scene, line_reading="exact")


def test_exact_references_never_hurt_and_recover_far_targets():
    """Noise-free annotations stored to 0.01 px and exact references of far targets: the MAP is
    within 0.2 % of the truth with them, and they never make it worse (beyond 0.05 %)."""
    import creference_bayes as cb

    for seed in range(3):
        d, truth = truth_scene(100 + seed, n_annotations=2, n_refs=10, depth=(25.0, 45.0))
        true = np.array([truth["objects"][0, 0], truth["camera"][3], truth["objects"][0, 1]])
        errs = {}
        for refs in (False, True):
            loc = cb.estimate(d, posterior=False, use_references=refs).to_dict()["objects"][0]["map"]
            errs[refs] = 100 * np.linalg.norm([loc["x"] - true[0], loc["y"] - true[1], loc["z"] - true[2]]) / np.linalg.norm(true)
        assert errs[True] < 0.2 and errs[True] <= errs[False] + 0.05, (seed, errs)


def test_heavy_tails_resist_an_outlier_annotation():
    """One of five annotations shifted by 150 px: the Student-t likelihood barely moves; a
    Gaussian one (ν → ∞) is dragged."""
    from creference_bayes.inference.map import optimize

    d, truth = truth_scene(1, n_annotations=5, noise_px=2.0, horizon="exact")
    d["targets"][0]["dimension_lines"][0]["corners"] = (np.array(d["targets"][0]["dimension_lines"][0]["corners"])
                                                        + 150.0).tolist()
    scene = parse_scene(d)
    true = np.hypot(*truth["objects"][0, :2])

    def err(**kw):
        m, _ = build_model(scene, target_sigma=2.0, **kw)
        est = optimize(m)
        return abs(np.hypot(*est.objects[0, :2]) / true - 1) * 100

    robust, gaussian = err(), err(target_dof=1e6)
    assert robust < 3.0 and gaussian > 3 * robust


def test_the_crowd_scale_follows_the_references():
    """Exact references put the crowd's error scale at its smallest; wild ones (a factor of e or
    more) at large values."""
    import creference_bayes as cb

    d, truth = truth_scene(7, n_annotations=3, noise_px=1.0, n_refs=8)
    exact = cb.estimate(d, seed=0, sampling={"min_ess": 100}).to_dict()["camera"]["posterior"]["median"]["ref_scale"]
    rng = np.random.default_rng(0)
    for r in d["references"]:
        r["value"] *= float(np.exp(rng.choice([-1.5, 1.5])))
    wild = cb.estimate(d, seed=0, sampling={"min_ess": 100}).to_dict()["camera"]["posterior"]["median"]["ref_scale"]
    assert exact < 0.05 < 0.5 < wild


def _ground_segments(rng, n, depth, cam, pp):
    """n true ground segments (n, 2, 2 px) and their lengths (m): midpoints at ``depth`` (m, uniform)
    within the view, any direction, lengths log-uniform in 0.3–10 m (the reading's own prior's
    shape), projected by a camera (5,) independent of the model's ray code."""
    from creference_bayes.core.geometry import project

    z = rng.uniform(*depth, n)
    x = rng.uniform(-0.3, 0.3, n) * z
    ang, length = rng.uniform(0, 2 * np.pi, n), np.exp(rng.uniform(np.log(0.3), np.log(10.0), n))
    half = 0.5 * length[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    ends = np.stack([np.column_stack([x, z]) - half, np.column_stack([x, z]) + half], axis=1)  # (n, 2, (x, z))
    pts = np.stack([ends[..., 0], np.full((n, 2), cam[3]), ends[..., 1]], axis=-1).reshape(-1, 3)
    uv, d = project(pts, rotation_from_pitch_roll(cam[1], cam[2]), cam[0], pp)
    return uv.reshape(n, 2, 2), length, d.reshape(n, 2)


@pytest.mark.parametrize("depth", [(3.0, 8.0), (30.0, 60.0)], ids=["far from the horizon", "near the horizon"])
def test_the_default_reading_of_a_drawn_segment_matches_a_monte_carlo_of_its_end_points(depth):
    """Segments drawn with 5 px of end-point noise, read at the true camera by the default reading
    (with the default floor of its prior, and with the floor the drawn lengths teach, segment_floor):
    against the Monte Carlo of that noise (the true lengths), the reading is centred (median error
    of the mean reading within 0.05 in log-length) and its stated spread matches the spread of its
    errors (within 25 %), and its bins put 80 % ± 8 of the truths in their central 80 %. Near the
    horizon the raw reading is far off (a median lengthening of about 0.7 in log) and is not
    symmetric; far from it the reading is the raw one."""
    from scipy.special import ndtr

    model, _ = _model(2, n_refs=1, horizon="exact")
    pp, sigma = model.principal_point, 5.0
    cam = np.array([1800.0, 0.05, 0.0, 1.6, 0.3])
    rng = np.random.default_rng(11)
    true, length, d = _ground_segments(rng, 500, depth, cam, pp)
    drawn = true + sigma * rng.standard_normal(true.shape)
    horizon_row = pp[1] - cam[0] * np.tan(cam[1])
    keep = np.all(d > 0.5, axis=1) & np.all(drawn[..., 1] > horizon_row + 2.0, axis=1)
    refs = [ReferenceTerm(j, "ground", 1.0, 1.0, False, line) for j, line in enumerate(drawn[keep])]
    truth = np.log(length[keep])
    raw = np.log(ground_lengths(drawn[keep], pp, cam[None])[0])
    learned = segment_floor(np.linalg.norm(drawn[keep, 1] - drawn[keep, 0], axis=1), sigma)
    with pytest.raises(ValueError, match="read_floor_px: expected a finite number > 0, got 0.0"):
        MetrologyModel(pp, model.image_size, model.objects, refs, read_floor_px=0.0)
    for floor in (None, learned):  # the default floor, and the floor these drawn lengths teach
        m = MetrologyModel(pp, model.image_size, model.objects, refs, ref_line_sigma=sigma, read_floor_px=floor)
        m.set_pilot(cam)
        read = m.predicted_log_lengths(cam[None], np.ones((1, 1, 7)))[0]
        error = read - truth
        assert abs(np.median(error)) < 0.05
        assert np.sqrt(np.mean(m.ref_line_var)) == pytest.approx(np.std(error), rel=0.25)
        bins = m.ref_shift[:, None] + m.ref_node_shift
        pit = np.mean(ndtr((truth[:, None] - (raw[:, None] - bins)) / np.sqrt(np.maximum(m.ref_node_var, 1e-12))),
                      axis=1)
        assert np.mean((pit > 0.1) & (pit < 0.9)) == pytest.approx(0.8, abs=0.08)
        if depth[0] > 10:
            assert np.median(raw - truth) > 0.3  # the raw reading lengthens near the horizon
        else:
            assert np.median(np.abs(read - raw)) < 0.01  # far from it, most segments read as drawn


def test_every_reference_format_is_read_through_the_bins_of_its_segment():
    """The ten formats of the bench's light crowd (direct and relative, values and ranges,
    lengths, widths, distances): each line reference's term is the mean over its bins b of the
    Student-t density of the stated log-value around log ℓ − e_b (scale √(s² + v_b); up to its
    constant), or of its probability of the stated range, SciPy's; every line has bins of its own."""
    from creference_bayes.bench.simulate import simulate_scene, true_state

    d = simulate_scene(np.random.default_rng([66, 3]), tier="light", setting="outdoor", n_references=10,
                       format_offset=0)
    scene = parse_scene(d)
    m, _ = build_model(scene)
    cam, objs = true_state(scene)
    m.handedness = np.array([t.ground_truth["handedness"] for t in scene.targets], float)
    m.set_pilot(cam)
    assert {(r.measure, r.mode, r.is_range) for r in scene.references} == {
        (a, b, c) for a in ("length", "width", "distance") for b in ("direct", "relative") for c in (False, True)
        if not (a == "distance" and b == "relative")}
    cams = m.complete_camera(np.repeat(cam[None], 3, axis=0) * [[1.0, 1, 1, 1, 0.2], [1.05, 1, 1, 0.97, 0.5],
                                                                  [0.9, 1, 1, 1.1, 1.0]])
    o = np.repeat(objs[None], 3, axis=0)
    got = m.pointwise_log_likelihood(cams, o)["references"]
    assert m.ref_node_shift.shape == (10, 8) and np.all(np.ptp(m.ref_node_shift, axis=1) > 0)
    pred = np.log(ground_lengths(np.array([r.line for r in m.references]), m.principal_point, cams))
    rel = np.array([r.kind == "relative" for r in m.references])
    pred[:, rel] -= np.log(o[:, 0, 3 + m.ref_size[rel]])
    loc = pred[..., None] - (m.ref_shift[:, None] + m.ref_node_shift)[None]             # (3, 10, 8)
    S = np.sqrt(cams[:, C_SCALE, None, None] ** 2 + m.ref_node_var[None])
    lo, hi = m.ref_log_low[None, :, None], m.ref_log_high[None, :, None]
    single = stats.t.pdf(lo, 2.0, loc, S)
    ranged = stats.t.cdf(hi, 2.0, loc, S) - stats.t.cdf(lo, 2.0, loc, S)
    want = np.log(np.mean(np.where(m.ref_is_range[None, :, None], ranged, single), axis=-1))
    want -= np.where(m.ref_is_range, 0.0, stats.t.logpdf(0.0, 2.0))  # a value's density, up to its constant
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-8)
