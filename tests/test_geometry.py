"""Camera, horizon, box and projection (method.md §1) against independent references."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from creference_bayes.core.geometry import (Camera, box_points, box_vertices, dimension_corners,
                                            horizon_from_rotation, horizon_line,
                                            pitch_roll_from_horizon, project,
                                            rotation_from_pitch_roll, yaw_matrix)

W_IMG, H_IMG = 2880, 1800


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _K(f, pp):
    return np.array([[f, 0, pp[0]], [0, f, pp[1]], [0, 0, 1.0]])


def _cv2_project(points, R, f, pp):
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(points.astype(np.float64), rvec, np.zeros(3), _K(f, pp), None)
    return uv.reshape(-1, 2)


def _random_cases(seed, n):
    """n random cameras (off-centre principal point, pitch, roll, focal) and boxes in front of them."""
    rng = np.random.default_rng(seed)
    cases = []
    while len(cases) < n:
        pitch, roll = np.radians(rng.uniform(-40, 40)), np.radians(rng.uniform(-25, 25))
        f = rng.uniform(300, 6000)
        pp = np.array([rng.uniform(0.2, 0.8) * W_IMG, rng.uniform(0.2, 0.8) * H_IMG])
        size = rng.uniform(0.2, 5.0, 3)
        params = np.array([rng.uniform(-10, 10), rng.uniform(0.5, 3), rng.uniform(3, 60),
                           rng.uniform(-np.pi, np.pi), f])
        pts = box_points(params, box_vertices(*size))
        if np.all((pts @ (_rz(roll) @ _rx(pitch)).T)[:, 2] > 0.5):  # all in front of the camera
            cases.append((pitch, roll, f, pp, params, pts))
    return cases


def test_rotation_is_rz_roll_times_rx_pitch():
    rng = np.random.default_rng(1)
    p, r = rng.uniform(-1, 1, 20), rng.uniform(-1, 1, 20)
    R = rotation_from_pitch_roll(p, r)
    assert R.shape == (20, 3, 3)
    for i in range(20):
        np.testing.assert_allclose(R[i], _rz(r[i]) @ _rx(p[i]), atol=1e-15)


def test_projection_matches_opencv():
    cases = _random_cases(7, 150)
    for pitch, roll, f, pp, params, pts in cases:
        R = _rz(roll) @ _rx(pitch)
        expected = _cv2_project(pts, R, f, pp)
        uv, depth = project(pts, rotation_from_pitch_roll(pitch, roll), f, pp)
        np.testing.assert_allclose(uv, expected, rtol=0, atol=1e-6)
        np.testing.assert_allclose(depth, (pts @ R.T)[:, 2], rtol=1e-12)


def test_batched_projection_matches_opencv():
    cases = _random_cases(8, 60)
    pts = np.stack([c[5] for c in cases])  # (n, 8, 3)
    R = rotation_from_pitch_roll([c[0] for c in cases], [c[1] for c in cases])  # (n, 3, 3)
    f = np.array([c[2] for c in cases])
    for pp in (cases[0][3], np.array([W_IMG / 2, H_IMG / 2])):  # one principal point per batch
        uv, _ = project(pts, R, f, pp)
        assert uv.shape == (60, 8, 2)
        for i, (pitch, roll, *_rest) in enumerate(cases):
            np.testing.assert_allclose(uv[i], _cv2_project(pts[i], _rz(roll) @ _rx(pitch), f[i], pp), atol=1e-6)


def test_camera_with_horizon_projects_like_opencv():
    """A Camera knows its pitch and roll only through the horizon line; it still matches OpenCV."""
    for pitch, roll, f, pp, params, pts in _random_cases(9, 80):
        R = _rz(roll) @ _rx(pitch)
        camera = Camera(pp, horizon_line(horizon_from_rotation(R, f, pp, W_IMG)), None)
        uv, _ = camera.project(pts, f)
        np.testing.assert_allclose(uv, _cv2_project(pts, R, f, pp), atol=1e-6)


def test_level_camera_projects_like_opencv_with_identity():
    pitch, roll, f, pp, params, pts = _random_cases(10, 1)[0]
    pts = box_points(params, box_vertices(1, 1, 1))
    uv, _ = Camera(pp).project(pts, f)
    np.testing.assert_allclose(uv, _cv2_project(pts, np.eye(3), f, pp), atol=1e-6)
    uv2, _ = project(pts, None, f, pp)
    np.testing.assert_array_equal(uv, uv2)


def test_points_behind_the_camera_have_negative_depth_and_finite_pixels():
    uv, depth = project(np.array([[0.5, 1.0, -3.0], [0.0, 1.0, 0.0]]), None, 1000.0, [1440, 900])
    assert depth[0] == -3.0 and depth[1] == 0.0
    assert np.all(np.isfinite(uv))


def test_sign_conventions():
    f, pp = 1500.0, np.array([1400.0, 950.0])
    # pitch > 0 looks down: the horizon (a far point straight ahead) appears above the principal point
    uv, _ = project(np.array([[0.0, 0.0, 1e6]]), rotation_from_pitch_roll(0.2, 0.0), f, pp)
    assert uv[0, 1] < pp[1]
    # roll > 0 turns the horizon clockwise: v grows to the right of the principal point
    hz = horizon_from_rotation(rotation_from_pitch_roll(0.0, 0.1), f, pp, W_IMG)
    assert hz[1, 1] > hz[0, 1]
    # the horizon line's signed distance is positive below it, on the ground side
    line = horizon_line(hz)
    assert line @ [pp[0], pp[1] + 100, 1] > 0 > line @ [pp[0], pp[1] - 100, 1]
    np.testing.assert_allclose(np.hypot(line[0], line[1]), 1.0)


def test_horizon_pitch_roll_round_trip():
    rng = np.random.default_rng(11)
    for _ in range(300):
        pitch, roll = np.radians(rng.uniform(-60, 60)), np.radians(rng.uniform(-40, 40))
        f = rng.uniform(300, 6000)
        pp = np.array([rng.uniform(0, W_IMG), rng.uniform(0, H_IMG)])
        hz = horizon_from_rotation(rotation_from_pitch_roll(pitch, roll), f, pp, W_IMG)
        p, r = pitch_roll_from_horizon(horizon_line(hz), f, pp)
        assert p == pytest.approx(pitch, abs=1e-9) and r == pytest.approx(roll, abs=1e-9)


def test_pitch_roll_from_horizon_is_vectorised_over_focal_lengths():
    pp = np.array([1500.0, 800.0])
    line = horizon_line(np.array([[0.0, 700.0], [W_IMG, 760.0]]))
    focal = np.array([500.0, 1500.0, 4000.0])
    p, r = pitch_roll_from_horizon(line, focal, pp)
    assert p.shape == r.shape == (3,)
    for i, fi in enumerate(focal):
        pi, ri = pitch_roll_from_horizon(line, fi, pp)
        assert (p[i], r[i]) == pytest.approx((pi, ri), abs=1e-14)
        # the horizon is the image of the ground's points at infinity (independent of the formula)
        far = np.array([[x, 1.0, 1e9] for x in (-3e8, 0.0, 3e8)])
        uv, _ = project(far, rotation_from_pitch_roll(pi, ri), fi, pp)
        dist = np.c_[uv, np.ones(3)] @ line
        np.testing.assert_allclose(dist, 0.0, atol=1e-5)


def test_backprojection_onto_the_ground_inverts_projection():
    rng = np.random.default_rng(12)
    for pitch, roll, f, pp, params, _ in _random_cases(13, 40):
        h = params[1]
        R = rotation_from_pitch_roll(pitch, roll)
        camera = Camera(pp, horizon_line(horizon_from_rotation(R, f, pp, W_IMG)), None)
        ground = np.column_stack([rng.uniform(-20, 20, 30), np.full(30, h), rng.uniform(1, 80, 30)])
        keep = (ground @ R.T)[:, 2] > 0.1  # in front of the camera
        uv, _ = camera.project(ground[keep], f)
        assert np.all(camera.is_below_horizon(uv, f))
        np.testing.assert_allclose(camera.backproject_to_ground(uv, f, h), ground[keep], rtol=1e-8, atol=1e-8)
        # a point above the camera is above the horizon: flagged, and its "ground point" has Z <= 0
        sky, _ = camera.project(np.array([[1.0, -2.0, 30.0]]), f)
        assert not camera.is_below_horizon(sky, f)[0]
        assert camera.backproject_to_ground(sky, f, h)[0, 2] <= 0


@pytest.mark.parametrize("handedness", [1, -1])
def test_dimension_corners_geometry(handedness):
    rng = np.random.default_rng(14)
    for _ in range(20):
        L, W, H = rng.uniform(0.05, 6.0, 3)
        c = dimension_corners(L, W, H, handedness)
        e_len, e_wid, e_hgt = c[1] - c[0], c[2] - c[0], c[3] - c[0]
        np.testing.assert_allclose([np.linalg.norm(e_len), np.linalg.norm(e_wid), np.linalg.norm(e_hgt)],
                                   [L, W, H], rtol=1e-12)
        np.testing.assert_allclose(e_len / L, [1, 0, 0], atol=1e-15)  # length along the object's x
        np.testing.assert_allclose(np.abs(e_wid) / W, [0, 0, 1], atol=1e-15)  # width along its z
        np.testing.assert_allclose(e_hgt / H, [0, -1, 0], atol=1e-15)  # height up (−Y)
        np.testing.assert_array_equal(c[:3, 1], 0.0)  # c1..c3 on the ground
        # the parallelogram centre of the two ground lines is the bottom-centre (the origin)
        np.testing.assert_allclose(c[0] + e_len / 2 + e_wid / 2, 0.0, atol=1e-15)
        # c1 is a bottom vertex of the box and c2, c3, c4 are its three neighbours
        verts = box_vertices(L, W, H)
        for p in c:
            assert np.min(np.linalg.norm(verts - p, axis=1)) < 1e-12
        # seen from above (X right, Z up on the map) the width line turns counter-clockwise
        # from the length line for handedness +1, clockwise for −1
        assert np.sign(e_len[0] * e_wid[2] - e_len[2] * e_wid[0]) == handedness


def test_no_rotation_turns_one_handedness_into_the_other():
    L, W, H = 1.3, 0.6, 0.9
    a, b = dimension_corners(L, W, H, 1), dimension_corners(L, W, H, -1)

    def chirality(c):
        return np.linalg.det(np.stack([c[1] - c[0], c[2] - c[0], c[3] - c[0]]))

    assert chirality(a) == pytest.approx(L * W * H) and chirality(b) == pytest.approx(-L * W * H)
    # a mirror z -> -z maps one to the other ...
    np.testing.assert_allclose(a * [1, 1, -1], b, atol=1e-15)
    # ... but no proper rotation does: the best one (Kabsch, any axis, yaw included) leaves a gap
    for yaw in np.linspace(-np.pi, np.pi, 721):
        gap = np.max(np.linalg.norm(a @ yaw_matrix(yaw).T - b, axis=1))
        assert gap > 0.25 * min(L, W)
    _, rssd = Rotation.align_vectors(b - b.mean(0), a - a.mean(0))
    assert rssd > 0.1


def test_yaw_and_box_points_follow_the_documented_rotation():
    rng = np.random.default_rng(15)
    obj = rng.normal(size=(5, 3))
    for theta in rng.uniform(-np.pi, np.pi, 10):
        Ry = Rotation.from_euler("y", theta).as_matrix()  # right-handed rotation about +Y
        np.testing.assert_allclose(yaw_matrix(theta), Ry, atol=1e-15)
        loc = rng.normal(size=3)
        np.testing.assert_allclose(box_points(np.r_[loc, theta, 1000.0], obj), loc + obj @ Ry.T, atol=1e-14)
    batch = np.column_stack([rng.normal(size=(7, 3)), rng.uniform(-3, 3, 7), np.full(7, 900.0)])
    out = box_points(batch, obj)
    assert out.shape == (7, 5, 3)
    for i in range(7):
        np.testing.assert_allclose(out[i], box_points(batch[i], obj), atol=1e-15)


def test_dimension_corners_rejects_other_handedness():
    with pytest.raises(ValueError, match="handedness"):
        dimension_corners(1, 1, 1, 0)
