import os
import warnings

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy: tiny matrices, threads only cost

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")


@pytest.fixture
def make_scene():
    """Factory for validated synthetic scenes: make_scene(seed, **simulate_scene kwargs)."""
    from creference_bayes.io.scene import parse_scene
    from creference_bayes.bench.simulate import simulate_scene

    def _make(seed=0, **kwargs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return parse_scene(simulate_scene(np.random.default_rng(seed), **kwargs))

    return _make


@pytest.fixture
def assert_same_scene():
    """assert_same_scene(a, b, atol=1e-9, drop=()): two scene dicts are the same scene
    (``creference_bayes.io.scene.scene_differences`` finds nothing)."""
    from creference_bayes.io.scene import scene_differences

    def check(a, b, atol=1e-9, drop=()):
        diff = scene_differences(a, b, atol=atol, drop=drop)
        assert not diff, "\n".join(diff)

    return check


SIZES = {"Car": (4.2, 1.7, 1.5), "Pedestrian": (0.8, 0.6, 1.75), "Van": (5.1, 1.9, 2.2)}


def truth_scene(seed=0, *, m=1, sizes_known=True, noise_px=0.0, n_annotations=1, focal_known=False,
                horizon=None, n_refs=0, image=(2880, 1800), pitch_deg=6.0, roll_deg=1.0, height_m=1.6,
                focal_px=1500.0, ground_sd_m=0.0, depth=(6.0, 30.0)):
    """A scene made from a known state with the package's own projection, independent of the
    bench's simulator: returns (the scene's dict, the truth: ``camera`` (5,), ``objects`` (m, 7),
    ``handedness`` (m,)). Annotations are the projected corners plus N(0, noise_px²), rounded to
    0.01 px; references are ground segments in the lower image whose stated value is the true
    length (exact); ``horizon`` None, ``"exact"`` or ``"sd"`` (stated with 1 px)."""
    from creference_bayes.core.geometry import horizon_from_rotation, rotation_from_pitch_roll
    from creference_bayes.models.contract import Model, ObjectData
    from creference_bayes.models.metrology import ground_lengths

    rng = np.random.default_rng(seed)
    w, h = image
    pp = np.array([w / 2 + 0.03 * w, h / 2 - 0.02 * h])
    cam = np.array([focal_px, np.radians(pitch_deg), np.radians(roll_deg), height_m, 0.5])
    classes = list(SIZES)
    for _ in range(1000):
        cls = [classes[rng.integers(len(classes))] for _ in range(m)]
        sizes = np.array([SIZES[c] for c in cls]) * rng.uniform(0.9, 1.1, (m, 3))
        objs = np.zeros((m, 7))
        objs[:, 1] = np.exp(rng.uniform(np.log(depth[0]), np.log(depth[1]), m))
        objs[:, 0] = rng.uniform(-0.35, 0.35, m) * objs[:, 1]
        objs[:, 2] = rng.uniform(-np.pi, np.pi, m)
        objs[:, 3:6] = sizes
        objs[:, 6] = rng.normal(0.0, ground_sd_m, m) if m > 1 else 0.0
        hand = rng.choice([1, -1], m)
        proj = Model(pp, image, [ObjectData(str(i), np.zeros((1, 4, 2)), int(hand[i]), tuple(sizes[i])) for i in range(m)])
        uv, depth_ = proj.project(cam[None], objs[None])
        ann = np.round(uv[0][:, None] + rng.normal(0.0, noise_px, (m, n_annotations, 4, 2)), 2)
        inside = np.all((ann[..., 0] > 0) & (ann[..., 0] < w) & (ann[..., 1] > 0) & (ann[..., 1] < h))
        if inside and np.all(depth_ > 1.0):
            break
    targets = []
    for i in range(m):
        t = {"id": f"t{i}", "class": cls[i],
             "dimension_lines": [{"worker": f"w{k}", "corners": ann[i, k].tolist()} for k in range(n_annotations)],
             "ground_truth": {"location_m": [objs[i, 0], cam[3] - objs[i, 6], objs[i, 1]], "yaw_rad": objs[i, 2],
                              "handedness": int(hand[i]), "ground_m": objs[i, 6],
                              "dimensions_m": dict(zip(("length", "width", "height"), sizes[i].tolist()))}}
        if sizes_known:
            t["dimensions_m"] = dict(zip(("length", "width", "height"), sizes[i].tolist()))
        targets.append(t)
    scene = {"format": "creference-scene/2", "image": {"width": w, "height": h},
             "camera": {"principal_point": pp.tolist()}, "targets": targets,
             "ground_truth": {"focal_length_px": cam[0], "pitch_rad": cam[1], "roll_rad": cam[2],
                              "camera_height_m": cam[3]}}
    if focal_known:
        scene["camera"]["focal_length_px"] = cam[0]
    if horizon is not None:
        scene["horizon"] = horizon_from_rotation(rotation_from_pitch_roll(cam[1], cam[2]), cam[0], pp, w).tolist()
        if horizon == "sd":
            scene["horizon_sd_px"] = 1.0
    refs = []
    while len(refs) < n_refs:
        a = np.array([rng.uniform(0.1 * w, 0.9 * w), rng.uniform(0.75 * h, 0.98 * h)])
        ang = rng.uniform(-np.pi, np.pi)
        line = np.array([a, a + rng.uniform(80, 400) * np.array([np.cos(ang), np.sin(ang)])])
        if np.all((line[:, 0] > 0) & (line[:, 0] < w) & (line[:, 1] > 0.6 * h) & (line[:, 1] < h)):
            length = float(ground_lengths(line[None], pp, cam[None])[0, 0])
            refs.append({"worker": f"r{len(refs)}", "measure": "length", "mode": "direct", "value": length,
                         "unit": "m", "line": np.round(line, 2).tolist()})
    if refs:
        scene["references"] = refs
    truth = {"camera": cam, "objects": objs, "handedness": hand}
    return scene, truth


@pytest.fixture
def make_truth_scene():
    """:func:`truth_scene` as a fixture."""
    return truth_scene
