"""What the estimate knows about the camera: orientation modes, the horizon as a measurement,
the focal-length prior (scene, EXIF, default), the pose prior, and the sampling coordinates."""

import json
import warnings


import numpy as np
import pytest
from PIL import Image
from scipy import stats

import creference_bayes as cb
from conftest import truth_scene
from creference_bayes.camera_setup import GIVEN_HORIZON_SD_PX, setup_camera
from creference_bayes.core.geometry import horizon_from_rotation, rotation_from_pitch_roll
from creference_bayes.io.scene import SceneError, parse_scene, scene_to_dict
from creference_bayes.models.camera_terms import (FULL_FRAME_DIAGONAL_MM, FocalPrior, OrientationPrior,
                                                  horizon_offsets)
from creference_bayes.vision.exif import camera_id_from_exif, focal_from_exif


def _scene_dict(seed=3, **kw):
    return truth_scene(seed, **{"horizon": "exact", "n_annotations": 3, "noise_px": 2.0, "n_refs": 2, **kw})[0]


def _parse(d):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


# -- orientation and focal prior decisions ------------------------------------------------------

def test_orientation_modes():
    d = _scene_dict()
    exact = setup_camera(_parse(d))
    assert exact.orientation == "horizon" and exact.camera.horizon is not None
    assert exact.terms.orientation is None and exact.terms.horizon is None
    d_sd = {**d, "horizon_sd_px": 3.0}
    measured = setup_camera(_parse(d_sd))
    assert measured.orientation == "free" and measured.camera.horizon is None
    assert measured.terms.horizon.sd_px == 3.0 and measured.terms.horizon.source == "scene"
    forced = setup_camera(_parse(d), orientation="free")
    assert forced.terms.horizon.sd_px == GIVEN_HORIZON_SD_PX
    no = {k: v for k, v in d.items() if k != "horizon"}
    free = setup_camera(_parse(no))
    assert free.orientation == "free" and free.terms.orientation is not None and free.terms.horizon is None
    assert any("no horizon and no image" in n for n in free.notes)
    level = setup_camera(_parse(no), orientation="level")
    assert level.orientation == "level" and level.camera.horizon is None
    with pytest.raises(ValueError, match="orientation"):
        setup_camera(_parse(d), orientation="tilted")


def test_focal_prior_sources():
    d = _scene_dict()
    default = setup_camera(_parse(d)).terms.focal
    assert default.source == "default"
    assert default.median_px == pytest.approx(26.0 / FULL_FRAME_DIAGONAL_MM * np.hypot(2880, 1800))  # a 26 mm lens: 2041 px
    assert setup_camera(_parse(d), focal_prior="none").terms.focal is None
    stated = _parse({**d, "camera": {**d["camera"], "focal_length_prior": {"equivalent_35mm_mm": 26, "log_sd": 0.05}}})
    fp = setup_camera(stated).terms.focal
    assert fp.source == "scene" and fp.log_sd == 0.05 and np.isinf(fp.dof)
    assert fp.median_px == pytest.approx(26 / FULL_FRAME_DIAGONAL_MM * np.hypot(2880, 1800))
    assert setup_camera(stated, focal_prior="default").terms.focal.source == "default"
    known = _parse({**d, "camera": {**d["camera"], "focal_length_px": 1500.0}})
    assert setup_camera(known).terms.focal is None


def test_scene_keys_are_validated_and_round_trip():
    d = _scene_dict()
    d["horizon_sd_px"] = 2.5
    d["camera"]["focal_length_prior"] = {"median_px": 1800, "log_sd": 0.2, "dof": 4}
    d["camera"]["orientation_prior"] = {"pitch_sd_deg": 5, "height_median_m": 1.2}
    s = _parse(d)
    assert s.horizon_sd_px == 2.5 and s.focal_prior.median_px == 1800 and s.focal_prior.dof == 4
    assert s.orientation_prior.pitch_sd == pytest.approx(np.radians(5))
    assert s.orientation_prior.height_median_m == 1.2 and s.orientation_prior.roll_sd == pytest.approx(np.radians(10))
    back = _parse(json.loads(json.dumps(scene_to_dict(s))))
    assert back.horizon_sd_px == 2.5 and back.focal_prior == s.focal_prior
    assert back.orientation_prior == s.orientation_prior
    bad = [({"horizon_sd_px": -1}, "horizon_sd_px: expected a number >= 0"),
           ({"camera": {"focal_length_prior": {"median_px": 1, "equivalent_35mm_mm": 2}}},
            "camera.focal_length_prior: expected exactly one of"),
           ({"camera": {"focal_length_prior": {"median_px": 1800, "log_sd": 0}}},
            "camera.focal_length_prior.log_sd: expected a positive number"),
           ({"camera": {"orientation_prior": {"pitch_sd_deg": -2}}}, "camera.orientation_prior.pitch_sd_deg")]
    for change, message in bad:
        with pytest.raises(SceneError, match=message.replace("(", r"\(")):
            parse_scene({**_scene_dict(), **change})
    no_horizon = {k: v for k, v in _scene_dict().items() if k != "horizon"}
    with pytest.raises(SceneError, match="horizon_sd_px: an uncertainty 2 px without a horizon"):
        parse_scene({**no_horizon, "horizon_sd_px": 2})


# -- the terms against independent formulas ----------------------------------------------------

def test_focal_and_pose_priors_against_scipy():
    fp = FocalPrior(1500.0, 0.3, 3.0)
    mu = np.array([600.0, 1500.0, 4000.0])
    want = -stats.t(3, loc=np.log(1500), scale=0.3).logpdf(np.log(mu)) + np.log(mu)
    got = fp.neg_log(mu)
    np.testing.assert_allclose(got - got[1], want - want[1], rtol=1e-10)
    lo, hi = fp.interval(0.9)
    assert stats.t(3).cdf(np.log(hi / 1500) / 0.3) == pytest.approx(0.95)
    op = OrientationPrior()
    p, r, h = np.radians([3.0, 20.0]), np.radians([-2.0, 7.0]), np.array([1.6, 6.0])
    want = -(stats.norm(0, op.pitch_sd).logpdf(p) + stats.norm(0, op.roll_sd).logpdf(r)
             + stats.norm(np.log(1.6), 0.6).logpdf(np.log(h)) - np.log(h))
    got = op.neg_log(p, r, h)
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-10)


def test_points_on_the_true_horizon_have_zero_offset():
    rng = np.random.default_rng(0)
    pp = np.array([1500.0, 880.0])
    for _ in range(5):
        pitch, roll, mu = rng.uniform(-0.2, 0.4), rng.uniform(-0.1, 0.1), rng.uniform(900, 3000)
        pts = horizon_from_rotation(rotation_from_pitch_roll(pitch, roll), mu, pp, 2880)
        cam = np.array([[mu, pitch, roll, 1.5, 0.5]])
        np.testing.assert_allclose(horizon_offsets(pts, cam, pp), 0.0, atol=1e-7)
        below = pts + [[0.0, 10.0], [0.0, 10.0]]
        assert np.all(horizon_offsets(below, cam, pp) > 9.0)


def test_working_coordinates_round_trip_with_the_stated_jacobian():
    """The optimiser's and the sampler's coordinates (each object anchored to the image): a
    bijection whose log |∂natural/∂working| (the full determinant over the free parameters, by
    central differences) is what log_jacobian says."""
    from creference_bayes.inference.coords import WorkingCoords
    from creference_bayes.pipeline import build_model

    d, truth = truth_scene(5, m=2, sizes_known=False, n_refs=1)
    model, _ = build_model(_parse(d))
    model.handedness = truth["handedness"].astype(float)
    co = WorkingCoords(model)
    cams = model.complete_camera(truth["camera"][None] * [1.02, 1.1, 1.0, 0.97, 1.0])
    wc, wo = co.to_work(cams, truth["objects"][None])
    c2, o2 = co.from_work(wc, wo)
    np.testing.assert_allclose(c2, cams, rtol=1e-12)
    np.testing.assert_allclose(o2, truth["objects"][None], rtol=1e-10, atol=1e-12)
    free = np.concatenate([model.camera_free, model.object_free.ravel()])
    x0 = np.concatenate([wc[0], wo[0].ravel()])
    h = 1e-6

    def natural(x):
        c, o = co.from_work(x[None, :5], x[None, 5:].reshape(1, -1, 7))
        return np.concatenate([c[0], o[0].ravel()])[free]

    J = np.column_stack([(natural(x0 + h * e) - natural(x0 - h * e)) / (2 * h) for e in np.eye(len(x0))[free]])
    jc, jo = co.log_jacobian(wc, wo)
    assert jc[0] + jo[0].sum() == pytest.approx(np.log(abs(np.linalg.det(J))), abs=1e-5)


def test_a_far_target_seen_once_converges_along_its_viewing_ray():
    """A target at about 40 m seen through one set of lines and one reference: the posterior runs
    far along the viewing ray, and the sampler still converges and holds the truth."""
    d, truth = truth_scene(17, n_annotations=1, noise_px=3.0, n_refs=1, depth=(35.0, 45.0))
    r = cb.estimate(d, seed=1)
    assert r.converged, r.warnings
    lo, hi = r.to_dict()["objects"][0]["posterior"]["hdi"]["distance_m"]
    true = float(np.hypot(*truth["objects"][0, :2]))
    assert lo < true < hi and hi > 1.5 * lo  # wide, as one set of lines on a far target is


# -- EXIF ---------------------------------------------------------------------------------------

def _jpeg(path, size=(720, 450), **tags):
    img = Image.new("RGB", size, (120, 120, 120))
    exif = Image.Exif()
    ifd = exif.get_ifd(0x8769)
    for tag, value in tags.items():
        ifd[{"f35": 0xA405, "focal": 0x920A, "xres": 0xA20E, "unit": 0xA210, "width": 0xA002}[tag]] = value
    img.save(path, exif=exif)
    return path


def test_exif_focal_length_routes(tmp_path):
    a = focal_from_exif(_jpeg(tmp_path / "a.jpg", f35=26), (2880, 1800))
    assert a.route == "35mm" and a.focal_px == pytest.approx(26 / FULL_FRAME_DIAGONAL_MM * np.hypot(2880, 1800))
    # a 6 mm lens on a sensor of 400 pixels per mm, recorded 4000 px wide, the scene 2880 wide
    b = focal_from_exif(_jpeg(tmp_path / "b.jpg", focal=6.0, xres=400.0, unit=4, width=4000), (2880, 1800))
    assert b.route == "focal_plane" and b.focal_px == pytest.approx(6.0 * 400.0 * 2880 / 4000)
    assert focal_from_exif(_jpeg(tmp_path / "c.jpg"), (2880, 1800)) is None
    (tmp_path / "d.jpg").write_bytes(b"not an image")
    assert focal_from_exif(tmp_path / "d.jpg", (2880, 1800)) is None
    assert focal_from_exif(tmp_path / "missing.jpg", (2880, 1800)) is None


def _camera_jpeg(path, make=None, model=None, focal=None, serial=None):
    """A small JPEG with the EXIF tags that name a camera: Make, Model (IFD0), FocalLength and
    BodySerialNumber (the Exif IFD)."""
    img = Image.new("RGB", (64, 48), (120, 120, 120))
    exif = Image.Exif()
    for tag, value in ((0x010F, make), (0x0110, model)):
        if value is not None:
            exif[tag] = value
    ifd = exif.get_ifd(0x8769)
    for tag, value in ((0x920A, focal), (0xA431, serial)):
        if value is not None:
            ifd[tag] = value
    img.save(path, exif=exif)
    return path


def test_camera_id_from_exif_make_model_and_focal_length(tmp_path):
    def cid(name, **tags):
        return camera_id_from_exif(_camera_jpeg(tmp_path / f"{name}.jpg", **tags))

    assert cid("a", make="Canon", model="Canon EOS 80D", focal=35.0) == "exif:Canon EOS 80D 35mm"
    assert cid("b", make="Apple", model="iPhone 12", focal=4.2) == "exif:Apple iPhone 12 4.2mm"
    # NUL padding and blanks cleaned; the make dropped when the model starts with its first word
    assert cid("c", make="NIKON CORPORATION", model="NIKON  D750\0\0", focal=50.0) == "exif:NIKON D750 50mm"
    # two bodies of one model are two cameras; another focal length of a zoom is another camera
    assert cid("d", make="Canon", model="Canon EOS 80D", focal=35.0, serial="012345") == \
        "exif:Canon EOS 80D #012345 35mm"
    assert cid("e", make="Canon", model="Canon EOS 80D", focal=50.0) != cid("a2", make="Canon",
                                                                         model="Canon EOS 80D", focal=35.0)
    assert cid("f", make="SONY", model="ILCE-7M3") == "exif:SONY ILCE-7M3"  # no focal length tag
    # None: no model, no EXIF at all, not an image, no file
    assert cid("g", make="Apple", focal=4.2) is None
    assert cid("h") is None
    (tmp_path / "i.jpg").write_bytes(b"not an image")
    assert camera_id_from_exif(tmp_path / "i.jpg") is None
    assert camera_id_from_exif(tmp_path / "missing.jpg") is None
    # the id is one a scene file takes as its camera.id
    d = _scene_dict()
    d["camera"] = {**d.get("camera", {}), "id": cid("j", make="Canon", model="Canon EOS 80D", focal=35.0)}
    assert _parse(d).camera_id == "exif:Canon EOS 80D 35mm"


def test_pipeline_uses_exif_and_warns_when_the_annotations_disagree(tmp_path):
    d = _scene_dict(4, n_annotations=5)
    truth_35 = d["ground_truth"]["focal_length_px"] / np.hypot(2880, 1800) * FULL_FRAME_DIAGONAL_MM
    for name, f35 in (("right", truth_35), ("wrong", 4 * truth_35)):
        _jpeg(tmp_path / f"{name}.jpg", size=(2880, 1800), f35=int(round(f35)))
        scene = {**d, "image": {**d["image"], "path": f"{name}.jpg"}}
        (tmp_path / f"{name}.json").write_text(json.dumps(scene))
        r = cb.estimate(tmp_path / f"{name}.json", posterior=False)
        assert r.to_dict()["camera"]["setup"]["focal_prior"]["source"] == "exif"
        assert any("EXIF" in w for w in r.warnings)
        disagree = any("disagree with the exif focal length prior" in w for w in r.warnings)
        assert disagree == (name == "wrong"), r.warnings


# -- estimates ------------------------------------------------------------------------------------

def test_free_orientation_recovers_noise_free_scenes():
    """No horizon, noise-free annotations: pitch, roll and the location come back (the priors'
    pull on exact data is small)."""
    for seed in range(4):
        d, truth = truth_scene(seed, n_annotations=2, roll_deg=5.0, n_refs=2)
        doc = cb.estimate(d, posterior=False).to_dict()
        cam, obj = doc["camera"]["map"], doc["objects"][0]
        assert obj["evaluation"]["location_pct_error"] < 0.3, (seed, obj["evaluation"])
        assert abs(cam["pitch"] - truth["camera"][1]) < np.radians(0.2)
        assert abs(cam["roll"] - truth["camera"][2]) < np.radians(0.2)


def test_without_a_horizon_the_posterior_widens_and_still_holds_the_truth():
    d = _scene_dict(11, n_annotations=5, roll_deg=4.0)
    kw = dict(seed=0, sampling={"min_ess": 300})
    with_h = cb.estimate(d, **kw).to_dict()
    without = cb.estimate({k: v for k, v in d.items() if k != "horizon"}, **kw).to_dict()
    assert "pitch" not in with_h["camera"]["free"] and "pitch" in without["camera"]["free"]
    width = lambda r: np.diff(r["objects"][0]["posterior"]["hdi"]["distance_m"])[0]  # noqa: E731
    assert width(without) > width(with_h)
    assert without["objects"][0]["evaluation"]["distance_in_hdi"] and without["camera"]["evaluation"]["in_hdi"]["pitch"]
    assert without["diagnostics"]["converged"], without["diagnostics"]["warnings"]


def test_the_default_focal_prior_is_centred_on_the_population_of_real_cameras():
    """The default's median and scale are those of the photos of REAL_CAMERAS (its sources are in
    bench/simulate.py): 35 mm-equivalent focal lengths drawn as the bench draws them."""
    import math

    from creference_bayes.bench.simulate import draw_camera
    from creference_bayes.models.camera_terms import DEFAULT_FOCAL_35MM, DEFAULT_FOCAL_LOG_SD

    rng = np.random.default_rng(7)
    for setting in ("indoor", "outdoor"):
        cams = [draw_camera(rng, setting, "real") for _ in range(3000)]
        log_mm = np.log([c["focal_px"] / math.hypot(*c["image"]) * FULL_FRAME_DIAGONAL_MM for c in cams])
        assert abs(np.median(log_mm) - np.log(DEFAULT_FOCAL_35MM)) < 0.04, (setting, np.exp(np.median(log_mm)))
        assert abs(log_mm.std() - DEFAULT_FOCAL_LOG_SD) < 0.08, (setting, log_mm.std())
