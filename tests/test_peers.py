"""The PoseLib P4Pf peer: exact on noise-free scenes, both handednesses, with and without a
horizon, the fallback when P4Pf has no real solution, and the install hint without PoseLib."""

import sys
import warnings

import numpy as np
import pytest

from creference_bayes.bench.runner import variant
from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.core.geometry import Camera, dimension_corners
from creference_bayes.io.scene import parse_scene

pytest.importorskip("poselib")
from creference_bayes.bench.peers import INSTALL_HINT, estimate_p4pf


def _scene(seed, n=5, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = parse_scene(simulate_scene(np.random.default_rng(seed), **{"decimals": None, **kw}))
    return variant(s, n, ())


def _truth(s):
    return s.targets[0].ground_truth


def test_noise_free_scenes_are_recovered_exactly():
    hands = set()
    for seed in range(12):
        s = _scene(seed, tier="none", principal_offset=0.05)
        g = _truth(s)
        p = estimate_p4pf(s)
        assert p.location_error(g["location_m"]) < 1e-3
        assert abs((p.params[3] - g["yaw_rad"] + np.pi) % (2 * np.pi) - np.pi) < 1e-4
        assert p.params[4] == pytest.approx(s.ground_truth["focal_length_px"], rel=1e-5)
        assert p.handedness == g["handedness"]
        assert p.rms_px < 1e-3
        hands.add(p.handedness)
    assert hands == {1, -1}


def test_without_horizon_gravity_comes_from_the_box():
    s = _scene(4, tier="none")
    level = Camera(s.principal_point, None, None)  # the peer may not use the horizon at all
    p = estimate_p4pf(s, camera=level)
    assert p.info["gravity"] == "box"
    assert p.location_error(_truth(s)["location_m"]) < 1e-3


def test_rms_is_the_reprojection_error_of_the_returned_pose():
    """Independent check: project the corners with the peer's pose and the pinhole model."""
    s = _scene(2, tier="medium")
    p = estimate_p4pf(s)
    t = s.targets[0]
    X = dimension_corners(*t.dimensions, p.handedness)
    pc = X @ p.rotation.T + p.translation
    uv = p.params[4] * pc[:, :2] / pc[:, 2:] + s.principal_point
    rms = np.sqrt(np.mean(np.sum((t.corners - uv) ** 2, axis=-1)))
    assert rms == pytest.approx(p.rms_px, rel=1e-6)
    assert rms < 2 * np.sqrt(2) * 5.0  # σ_t = 5 px per coordinate
    # the location is the box's origin, re-expressed in the horizon's gravity-aligned frame
    R = Camera.from_scene(s).rotation(p.params[4])
    np.testing.assert_allclose(R @ p.params[:3], p.translation, atol=1e-9)


def test_fallback_when_p4pf_has_no_real_solution():
    s = _scene(13, tier="high")  # noisy corners: P4Pf returns no real solution here
    p = estimate_p4pf(s)
    assert p.info["fallback"] and p.info["p4pf_solutions"] == 0
    assert p.rms_px < 2 * np.sqrt(2) * 10.0
    assert p.location_error(_truth(s)["location_m"]) < 100


def test_missing_poselib_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "poselib", None)  # import poselib now raises ImportError
    from creference_bayes.bench import peers

    assert not peers.poselib_available()
    with pytest.raises(ImportError, match=r"pip install creference-bayes\[peer\]"):
        peers.estimate_p4pf(_scene(0, tier="none"))
    assert "creference-bayes[peer]" in INSTALL_HINT


def test_only_one_target_of_known_size():
    s = parse_scene(simulate_scene(1, n_objects=2, sizes="prior", setting="street", n_references=0))
    with pytest.raises(ValueError, match="one target of known size"):
        estimate_p4pf(s)
