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
