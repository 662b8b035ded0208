"""Single-view metrology (method.md §4): ground coordinates, pair solve, bounds, skip rules."""

import math
import warnings

import numpy as np
import pytest

from creference_bayes.core.cost import SoftConstraints
from creference_bayes.core.geometry import (Camera, box_points, dimension_corners,
                                            horizon_from_rotation, horizon_line, project,
                                            rotation_from_pitch_roll)
from creference_bayes.core.metrology import (GroundFrame, SkipRules, aggregate_references,
                                             pair_bounds, pixel_sensitivity,
                                             target_ground_point)

#: the skip rules without the pixel-sensitivity rule (tests of exactness keep every stable pair)
NO_SENSITIVITY = SkipRules(max_pixel_sensitivity=None)
from creference_bayes.io.scene import parse_scene

W, HT = 2880, 1800


def _camera(pitch_deg, roll_deg, f, pp):
    R = rotation_from_pitch_roll(math.radians(pitch_deg), math.radians(roll_deg))
    return R, horizon_from_rotation(R, f, pp, W)


def _ground(x, z, h):
    return np.array([x, h, z], float)


def make_scene(*, pitch=0.0, roll=0.0, f=1600.0, h=1.4, pp=(W / 2, HT / 2), target=(0.8, 6.0, 0.6),
               size=(1.2, 0.5, 2.0), segments=None, lengths=None, horizon=True, ranges=None):
    """A scene whose annotations are exact projections (no rounding anywhere).

    ``segments``: list of ((x0, z0), (x1, z1)) ground segments, metres; ``lengths`` overrides
    the stated lengths; ``ranges`` (list of (lo, hi) factors or None) states ranges instead.
    """
    pp = np.asarray(pp, float)
    R, hz = _camera(pitch, roll, f, pp)
    x, z, yaw = target
    params = np.array([x, h, z, yaw, f])
    corners, _ = project(box_points(params, dimension_corners(*size, 1)), R, f, pp)
    if segments is None:
        segments = [((-2.0, 4.0), (-0.5, 4.2)), ((1.5, 3.5), (1.9, 7.0)), ((-1.0, 9.0), (0.5, 11.0)),
                    ((2.5, 5.0), (3.5, 5.5)), ((-3.0, 6.0), (-2.6, 8.5))]
    refs = []
    for k, (a, b) in enumerate(segments):
        P = np.stack([_ground(*a, h), _ground(*b, h)])
        uv, depth = project(P, R, f, pp)
        true_len = float(np.linalg.norm(P[1] - P[0]))
        stated = true_len if lengths is None else lengths[k]
        ref = {"measure": "length", "mode": "direct", "unit": "m", "line": uv.tolist()}
        if ranges is not None and ranges[k] is not None:
            ref["range"] = [stated * ranges[k][0], stated * ranges[k][1]]
        else:
            ref["value"] = stated
        refs.append(ref)
    data = {"format": "creference-scene/1", "image": {"width": W, "height": HT},
            "camera": {"principal_point": pp.tolist()},
            "target": {"id": "t", "dimensions_m": dict(zip(("length", "width", "height"), size)),
                       "dimension_lines": [{"corners": corners.tolist()}]},
            "references": refs}
    if horizon:
        data["horizon"] = hz.tolist()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(data)


# -- the paper's cross-ratio and the ζ coordinate agree ------------------------------------------

def _aggregate(scene, camera=None, **kw):
    """The pairwise aggregation of a one-target scene's references (metres) for its target."""
    return aggregate_references(scene.targets[0].median_corners, scene.references,
                                camera or Camera.from_scene(scene), **kw)


@pytest.mark.parametrize("seed", range(5))
def test_cross_ratio_gives_the_same_depth_ratio_as_zeta(seed):
    rng = np.random.default_rng(seed)
    f, h = rng.uniform(1000, 2600), rng.uniform(1.0, 2.5)
    pp = np.array([W / 2, HT / 2]) * (1 + rng.uniform(-0.1, 0.1, 2))
    R = rotation_from_pitch_roll(math.radians(rng.uniform(0, 15)), math.radians(rng.uniform(-3, 3)))
    frame = GroundFrame(horizon_line(horizon_from_rotation(R, f, pp, W)), pp)
    # a ground line towards the depth direction (the paper's "vertical" line) or any other one
    start = np.array([rng.uniform(-2, 2), h, rng.uniform(2, 4)])
    angle = rng.uniform(-1.2, 1.2)
    d = np.array([math.sin(angle), 0.0, math.cos(angle)])
    s = np.sort(rng.uniform(0, 8, 3))
    A, B, C = (start + t * d for t in s)
    uv, _ = project(np.stack([A, B, C]), R, f, pp)
    vp_h = np.array([[f, 0, pp[0]], [0, f, pp[1]], [0, 0, 1.0]]) @ R @ d
    vp = vp_h[:2] / vp_h[2]
    a, b, c = uv
    # cross-ratio (A, B; C, Vp): |AC|·|BVp| / (|BC|·|AVp|) = real AC / real BC
    dist = lambda p, q: np.linalg.norm(p - q)  # noqa: E731
    cross = dist(a, c) * dist(b, vp) / (dist(b, c) * dist(a, vp))
    real = (s[2] - s[0]) / (s[2] - s[1])
    zeta = frame.coordinates(uv)[:, 1]
    assert cross == pytest.approx(real, rel=1e-9)
    assert (zeta[2] - zeta[0]) / (zeta[2] - zeta[1]) == pytest.approx(cross, rel=1e-9)


def test_ground_frame_is_affine_with_the_documented_scales():
    # X = H ξ, Z = V (ζ − ζ_f), H = h / cos p, V = µ h / cos² p, ζ_f = sin p cos p / µ
    f, h, p = 1700.0, 1.3, math.radians(11.0)
    pp = np.array([1500.0, 850.0])
    R = rotation_from_pitch_roll(p, math.radians(-2.5))
    frame = GroundFrame(horizon_line(horizon_from_rotation(R, f, pp, W)), pp)
    rng = np.random.default_rng(3)
    P = np.column_stack([rng.uniform(-4, 4, 20), np.full(20, h), rng.uniform(2, 30, 20)])
    xi, zeta = frame.coordinates(project(P, R, f, pp)[0]).T
    np.testing.assert_allclose(xi * h / math.cos(p), P[:, 0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(f * h / math.cos(p) ** 2 * (zeta - math.sin(p) * math.cos(p) / f), P[:, 2],
                               rtol=1e-9)
    assert frame.d_c == pytest.approx(f * math.tan(p), rel=1e-9)


# -- noise-free references recover the target exactly ---------------------------------------------

def _check_exact(scene, x_true, z_true, h, f, rel=1e-6):
    report = _aggregate(scene, rules=NO_SENSITIVITY)
    assert report.pairs_used == 10 and report.pairs_skipped == 0
    for p in report.pairs:
        assert p.x == pytest.approx(x_true, rel=rel)
        assert p.z == pytest.approx(z_true, rel=rel)
        np.testing.assert_allclose(p.x_bounds, [x_true, x_true], rtol=rel)
        np.testing.assert_allclose(p.z_bounds, [z_true, z_true], rtol=rel)
        assert p.focal_length_px == pytest.approx(f, rel=rel)
        assert p.camera_height_m == pytest.approx(h, rel=rel)
    return report


def test_level_camera_recovers_x_and_z_exactly():
    scene = make_scene(target=(-1.3, 7.5, 2.0))
    report = _check_exact(scene, -1.3, 7.5, h=1.4, f=1600.0)
    c = report.constraints
    assert c.x_bounds.shape == (10, 2) and c.z_bounds.shape == (10, 2) and c.on == "xz"


def test_level_camera_without_horizon_uses_the_principal_point_row():
    scene = make_scene(target=(0.4, 5.0, -0.7), horizon=False)
    _check_exact(scene, 0.4, 5.0, h=1.4, f=1600.0)


@pytest.mark.parametrize("pitch, roll, pp", [(12.0, 0.0, (W / 2, HT / 2)), (15.0, 3.0, (1600.0, 800.0)),
                                             (-4.0, -2.0, (1300.0, 1000.0))])
def test_pitched_rolled_camera_is_exact_with_the_foot_point_correction(pitch, roll, pp):
    f, h = 1400.0, 1.6
    scene = make_scene(pitch=pitch, roll=roll, pp=pp, f=f, h=h, target=(0.9, 6.5, 0.3))
    _check_exact(scene, 0.9, 6.5, h=h, f=f)
    # the paper's z = ζ_t V (no correction) is off by h tan(pitch), as the docstring says
    frame = GroundFrame.from_camera(Camera.from_scene(scene))
    xi_t, zeta_t = target_ground_point(scene.targets[0].median_corners, frame)
    V = f * h / math.cos(math.radians(pitch)) ** 2
    assert zeta_t * V - 6.5 == pytest.approx(h * math.tan(math.radians(pitch)), rel=1e-6)


# -- ranges -----------------------------------------------------------------------------------------

def _sweep_bounds(d1, d2, r1, r2, target, d_c, focal_range=None, n=200_001):
    """Independent reference: sweep the implied focal length µ (V² = (d_c² + µ²) H²).

    At fixed µ the stated-length constraints bound H² to an interval, and x = ξ_t H and
    z = H (√ρ ζ_t − d_c/√ρ), ρ = V²/H², are monotone in H, so the interval's ends hold the
    extremes; a fine sweep over µ then gives the extremes over the whole feasible set.
    """
    mu = np.geomspace(*(focal_range or (1e-4, 1e7)), n)
    rho = d_c**2 + mu**2
    A = np.array([[d1[0] ** 2, d1[1] ** 2], [d2[0] ** 2, d2[1] ** 2]])
    per_h2 = A[:, :1] + A[:, 1:] * rho  # (2, n): ℓ² = H² (b² + β² ρ)
    lo = np.max(np.square([r1[0], r2[0]])[:, None] / per_h2, axis=0)
    hi = np.min(np.square([r1[1], r2[1]])[:, None] / per_h2, axis=0)
    ok = (lo <= hi) & (per_h2 > 0).all(axis=0)
    H = np.sqrt(np.concatenate([lo[ok], hi[ok]]))
    r = np.sqrt(np.concatenate([rho[ok], rho[ok]]))
    x, z = target[0] * H, H * (r * target[1] - d_c / r)
    return np.array([x.min(), x.max()]), np.array([z.min(), z.max()]), ok.mean()


@pytest.mark.parametrize("pitch, lo, hi, focal_range", [(0.0, 0.8, 1.25, None), (10.0, 0.7, 1.4, None),
                                                       (10.0, 0.3, 3.0, None), (10.0, 0.3, 3.0, (900.0, 2500.0))])
def test_range_bounds_contain_the_single_value_solution_and_match_a_sweep(pitch, lo, hi, focal_range):
    f, h = 1500.0, 1.5
    exact = make_scene(pitch=pitch, roll=2.0, f=f, h=h, target=(1.1, 5.5, 0.2))
    ranged = make_scene(pitch=pitch, roll=2.0, f=f, h=h, target=(1.1, 5.5, 0.2), ranges=[(lo, hi)] * 5)
    single = _aggregate(exact, rules=NO_SENSITIVITY)
    report = _aggregate(ranged, rules=NO_SENSITIVITY, focal_range_px=focal_range)
    frame = GroundFrame.from_camera(Camera.from_scene(ranged))
    target = target_ground_point(ranged.targets[0].median_corners, frame)
    refs = {r.index: r for r in ranged.references}
    checked = 0
    for p, s in zip(report.pairs, single.pairs):
        if not p.used:
            assert p.reason in ("no_positive_solution", "near_parallel")
            continue
        assert p.x_bounds[0] <= s.x <= p.x_bounds[1]
        assert p.z_bounds[0] <= s.z <= p.z_bounds[1]
        assert p.distance_bounds[0] <= math.hypot(s.x, s.z) <= p.distance_bounds[1]
        g = frame.coordinates(np.concatenate([refs[p.i].line, refs[p.j].line]))
        xb, zb, share = _sweep_bounds(g[1] - g[0], g[3] - g[2], (refs[p.i].low, refs[p.i].high),
                                      (refs[p.j].low, refs[p.j].high), target, frame.d_c,
                                      focal_range)
        assert 0.0 < share
        # (without a focal range the x bound approaches 0 as µ → ∞, beyond the sweep: atol)
        np.testing.assert_allclose(p.x_bounds, xb, rtol=1e-4, atol=1e-3 * np.ptp(xb))
        np.testing.assert_allclose(p.z_bounds, zb, rtol=1e-4, atol=1e-3 * np.ptp(zb))
        checked += 1
    assert checked >= 6


# -- skip rules -------------------------------------------------------------------------------------

def test_parallel_and_mirror_image_pairs_are_skipped_as_near_parallel():
    segs = [((-2.0, 4.0), (-1.0, 6.0)), ((1.0, 5.0), (2.0, 7.0)),  # parallel
            ((3.0, 4.0), (2.0, 6.0))]  # mirror image of both: the same |Δx|, |Δz|
    report = _aggregate(make_scene(pitch=6.0, segments=segs))
    assert report.pairs_used == 0
    assert report.skipped_reasons == {"near_parallel": 3}
    assert all(p.conditioning < 1e-6 for p in report.pairs)


def test_inconsistent_lengths_have_no_positive_solution():
    segs = [((-2.0, 4.0), (-0.5, 4.1)), ((1.5, 3.5), (1.6, 7.0))]  # lateral, then depth
    true = [math.hypot(1.5, 0.1), math.hypot(0.1, 3.5)]
    # the depth segment stated shorter than its own lateral offset (0.1 m) forces V² < 0
    report = _aggregate(make_scene(segments=segs, lengths=[true[0], 0.05]))
    assert report.skipped_reasons == {"no_positive_solution": 1}
    assert report.constraints is None


def test_huge_lengths_are_an_implausible_distance():
    segs = [((-2.0, 4.0), (-0.5, 4.1)), ((1.5, 3.5), (1.6, 7.0))]
    true = np.array([math.hypot(1.5, 0.1), math.hypot(0.1, 3.5)])
    report = _aggregate(make_scene(segments=segs, lengths=true * 5000))
    assert report.skipped_reasons == {"implausible_distance": 1}
    ok = _aggregate(make_scene(segments=segs, lengths=true * 100))
    assert ok.pairs_used == 1  # 600 m is far but plausible


def test_endpoint_above_the_horizon_is_skipped():
    scene = make_scene(pitch=5.0)
    data_line = scene.references[0].line.copy()
    data_line[1, 1] = 10.0  # far above the horizon (which is near row 760)
    ref = scene.references[0].__class__(**{**scene.references[0].__dict__, "line": data_line})
    scene = scene.__class__(**{**scene.__dict__, "references": (ref,) + scene.references[1:]})
    report = _aggregate(scene, rules=NO_SENSITIVITY)
    assert report.skipped_reasons == {"endpoint_above_horizon": 4}
    assert report.pairs_used == 6


def test_target_above_the_horizon_skips_every_pair():
    scene = make_scene()
    t = scene.targets[0]
    dl = t.dimension_lines[0].__class__(corners=t.dimension_lines[0].corners - [0.0, 700.0])
    target = t.__class__(**{**t.__dict__, "dimension_lines": (dl,)})
    report = _aggregate(scene.__class__(**{**scene.__dict__, "targets": (target,)}))
    assert report.skipped_reasons == {"target_above_horizon": 10}


def test_target_beyond_the_foot_point_is_behind_the_camera():
    # camera pitched 45° down: the nadir images 400 px below the principal point; a target
    # annotated below it has z ≤ 0 for every solution.
    f, h = 400.0, 1.5
    scene = make_scene(pitch=45.0, f=f, h=h, pp=(W / 2, 300.0),
                       segments=[((-1.0, 1.0), (0.0, 1.2)), ((0.5, 1.0), (0.6, 2.5))])
    t = scene.targets[0]
    corners = np.array([[1400.0, 750.0], [1500.0, 760.0], [1380.0, 780.0], [1400.0, 650.0]])
    target = t.__class__(**{**t.__dict__, "dimension_lines": (t.dimension_lines[0].__class__(corners),)})
    report = _aggregate(scene.__class__(**{**scene.__dict__, "targets": (target,)}))
    assert report.skipped_reasons == {"behind_camera": 1}


def test_pairs_that_amplify_pixel_noise_are_skipped_as_unstable():
    scene = make_scene(target=(-1.3, 7.5, 2.0))
    report = _aggregate(scene)
    unstable = {(p.i, p.j) for p in report.pairs if p.reason == "unstable"}
    assert (0, 3) in unstable and report.skipped_reasons.get("unstable") == len(unstable)
    # independent check of the sensitivity: move each endpoint of references 0 and 3 by a pixel,
    # re-run the whole aggregation (rule off) and watch the target distance
    def distance(sc):
        p = next(q for q in _aggregate(sc, rules=NO_SENSITIVITY).pairs if (q.i, q.j) == (0, 3))
        return math.hypot(p.x, p.z)

    d0, changes = distance(scene), []
    for k in (0, 3):
        for e in range(2):
            for c in range(2):
                line = scene.references[k].line.copy()
                line[e, c] += 1.0
                ref = scene.references[k].__class__(**{**scene.references[k].__dict__, "line": line})
                refs = tuple(ref if r.index == k else r for r in scene.references)
                changes.append(abs(distance(scene.__class__(**{**scene.__dict__, "references": refs})) - d0) / d0)
    frame = GroundFrame.from_camera(Camera.from_scene(scene))
    r0, r3 = scene.references[0], scene.references[3]
    sens = pixel_sensitivity(np.stack([r0.line, r3.line]), (r0.low, r3.low), frame,
                             target_ground_point(scene.targets[0].median_corners, frame))
    assert sens == pytest.approx(max(changes), rel=1e-6)
    assert sens > 0.02
    stable = {(p.i, p.j) for p in report.pairs if p.used}
    assert len(stable) >= 5 and not stable & unstable


def test_fewer_than_two_references_use_no_pair():
    scene = make_scene(segments=[((-2.0, 4.0), (-0.5, 4.1))])
    report = _aggregate(scene)
    assert (report.pairs_used, report.pairs_skipped, report.constraints) == (0, 0, None)
    assert report.to_dict()["pairs_used"] == 0


def test_distance_constraints_and_report_dict():
    scene = make_scene(pitch=8.0, target=(0.8, 6.0, 0.6), ranges=[(0.9, 1.1)] * 5)
    report = _aggregate(scene, on="distance")
    assert isinstance(report.constraints, SoftConstraints) and report.constraints.on == "distance"
    d_true = math.hypot(0.8, 6.0)
    assert np.all(report.constraints.distance_bounds[:, 0] <= d_true)
    assert np.all(report.constraints.distance_bounds[:, 1] >= d_true)
    d = report.to_dict()
    assert d["pairs_used"] + d["pairs_skipped"] == 10 and d["on"] == "distance"
    with pytest.raises(ValueError, match="on: expected"):
        _aggregate(scene, on="xyz")


def test_pair_bounds_of_a_single_value_is_a_point():
    d1, d2 = np.array([1.0, 1e-4]), np.array([0.1, 2e-3])
    hv = np.array([2.0, 3e6])
    l1, l2 = np.sqrt(d1**2 @ hv), np.sqrt(d2**2 @ hv)
    xb, zb, db = pair_bounds(d1, d2, (l1, l1), (l2, l2), np.array([0.5, 4e-3]), 0.0)
    np.testing.assert_allclose(xb, [0.5 * math.sqrt(2.0)] * 2, rtol=1e-9)
    np.testing.assert_allclose(zb, [4e-3 * math.sqrt(3e6)] * 2, rtol=1e-9)


# -- the pipeline ----------------------------------------------------------------------------------

def test_the_paper_model_reads_the_pairs_as_bounds_on_each_object():
    """Every pair of references is assessed for the target; the used pairs' bounds enter the paper
    model's cost (a pose far outside them pays for it), and the result counts used and skipped pairs."""
    import creference_bayes as cb
    from creference_bayes.pipeline import build_model

    scene = make_scene(target=(-1.3, 7.5, 2.0))
    result = cb.estimate(scene, model="paper", posterior=False, seed=0)
    rep = result.to_dict()["references"]["objects"][0]
    assert rep["pairs_used"] + rep["pairs_skipped"] == 10 and rep["pairs_used"] > 0
    model, _ = build_model(scene, model="paper")
    model.handedness = result.model.handedness
    cam = np.array([[result.to_dict()["camera"]["map"][k] for k in ("focal_length_px", "pitch", "roll", "height_m", "ref_scale")]])
    objs = np.array([[[result.to_dict()["objects"][0]["map"][k] for k in
                       ("x", "z", "yaw", "length_m", "width_m", "height_m", "ground_m")]]])
    far = objs.copy()
    far[0, 0, 1] *= 3.0
    bare, _ = build_model(scene, model="paper", use_references=False)
    bare.handedness = model.handedness
    penalty = lambda o: (model.object_nll(cam, o) - bare.object_nll(cam, o))[0, 0]
    assert penalty(far) - penalty(objs) > 10.0
    assert cb.estimate(scene, model="paper", posterior=False, use_references=False).to_dict()[
        "references"]["objects"][0]["pairs_used"] == 0


@pytest.mark.parametrize("nu", [2.0, 3.5, 30.0])
def test_a_references_reading_is_the_mean_of_its_bins_student_t(nu):
    """Each reference's likelihood is the mean over its reading's bins of a Student-t (ν) in
    log-length: a value's density (without its constant), a range's probability, a range stated
    with its own scale a normal density at its centre; checked against scipy.stats on random
    states, bins of one reference all alike or not, and far outliers (finite, and ordered)."""
    from scipy import stats

    from creference_bayes.models.metrology import reading_log_likelihood

    rng = np.random.default_rng(int(nu * 10))
    n, k, K = 7, 9, 8
    pred = rng.normal(0.0, 0.5, (n, k))
    pred[0, 0] = 40.0  # far out: finite, and less likely than near
    scale = np.exp(rng.normal(-2.0, 0.3, (n, 1)))
    low = rng.normal(0.0, 0.5, k)
    high = np.where(np.arange(k) % 3 == 1, low + np.abs(rng.normal(0.3, 0.1, k)), low)
    shift, var = rng.normal(0.0, 0.1, (k, K)), rng.uniform(0.0, 0.02, (k, K))
    shift[2], var[2] = 0.0, 0.0  # a reference of one bin, repeated
    own = np.full(k, np.nan)
    own[4] = 0.2
    high[4] = low[4] + 0.4
    got = reading_log_likelihood(pred, scale, low, high, high > low, nu, shift, var, own, None)
    const = stats.t.logpdf(0.0, nu)
    for j in range(k):
        s = np.sqrt(scale**2 + var[j])  # (n, K)
        loc = pred[:, j, None] - shift[j]
        if j == 4:
            sj = np.sqrt(0.2**2 + var[j])
            want = stats.norm.pdf(0.5 * (low[j] + high[j]), loc, sj) * np.sqrt(2 * np.pi)  # without its constant
        elif high[j] > low[j]:
            want = stats.t.cdf((high[j] - loc) / s, nu) - stats.t.cdf((low[j] - loc) / s, nu)
        else:
            want = np.exp(stats.t.logpdf((low[j] - loc) / s, nu) - const) / s
        np.testing.assert_allclose(got[:, j], np.log(np.maximum(want.mean(axis=1), 1e-300)), rtol=1e-7, atol=1e-9,
                                   err_msg=f"reference {j}")
    assert np.isfinite(got).all() and got[0, 0] < got[1:, 0].min()
