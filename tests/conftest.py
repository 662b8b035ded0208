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
    """assert_same_scene(a, b, atol=1e-9, drop=()): two scene dicts are the same scene (both
    normalised by parse_scene → scene_to_dict; numbers equal to ``atol`` absolute and 1e-12
    relative; keys named in ``drop`` — "seconds", "ground_truth", … — removed anywhere)."""
    from creference_bayes.io.scene import parse_scene, scene_to_dict

    def _norm(d, drop):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = scene_to_dict(parse_scene(d))

        def strip(x):
            if isinstance(x, dict):
                return {k: strip(v) for k, v in x.items() if k not in drop}
            if isinstance(x, list):
                return [strip(v) for v in x]
            return x
        return strip(d)

    def _cmp(x, y, path, atol):
        if isinstance(x, dict):
            assert isinstance(y, dict) and set(x) == set(y), f"{path}: keys {sorted(x)} != {sorted(y)}"
            for k in x:
                _cmp(x[k], y[k], f"{path}.{k}", atol)
        elif isinstance(x, list):
            assert isinstance(y, list) and len(x) == len(y), f"{path}: {x!r} != {y!r}"
            for i, (p, q) in enumerate(zip(x, y)):
                _cmp(p, q, f"{path}[{i}]", atol)
        elif isinstance(x, float) or isinstance(y, float):
            assert abs(x - y) <= atol + 1e-12 * abs(x), f"{path}: {x!r} != {y!r}"
        else:
            assert x == y, f"{path}: {x!r} != {y!r}"

    def check(a, b, atol=1e-9, drop=()):
        _cmp(_norm(a, set(drop)), _norm(b, set(drop)), "scene", atol)

    return check
