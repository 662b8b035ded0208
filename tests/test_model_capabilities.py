"""Models declare what they offer (issue 63): the optimiser, the sampler and the result read a
model's capabilities and options, never its name or the attributes it happens to have; a fit
keeps its state (handedness, pilot, σ continuation) in copies, so the model estimated is never
changed; equal results compare equal; the summary has the bottom's y's ESS and R-hat."""

import pickle
import warnings

import numpy as np
import pytest
from conftest import truth_scene

import creference_bayes as cb
from creference_bayes import pipeline
from creference_bayes.models.contract import Model

TINY = {"min_ess": 20, "max_steps": 200, "chunk": 50}


class CornerModel(Model):
    """A user's own model: each annotation's corners N(projection, 3 px²), nothing else (no
    ``sigma``, no references, no confidence map)."""

    name = "corners"
    noise_px = 3.0

    def _per_set(self, cams, objs):
        uv, depth = self.project(cams, objs)  # (n, m, 4, 2)
        out = np.zeros((len(cams), self.n_objects, max(len(o.annotations) for o in self.objects)))
        for i, o in enumerate(self.objects):
            r2 = np.sum((o.annotations[None] - uv[:, i, None]) ** 2, axis=(-1, -2))  # (n, K)
            out[:, i, :len(o.annotations)] = 0.5 * r2 / self.noise_px**2
        return out, depth

    def object_nll(self, cams, objs):
        per, depth = self._per_set(cams, objs)
        return per.sum(axis=-1) + self.behind(depth)

    def pointwise_log_likelihood(self, cams, objs):
        cams = self.complete_camera(cams)
        return {"annotations": -self._per_set(cams, objs)[0], "horizon": -self.horizon_nll(cams)}


def _use(monkeypatch, make):
    """Make ``estimate`` build its model with ``make(model, setup)`` from the metrology model and
    set-up it would build; returns the list the built models go to."""
    real, built = pipeline.build_model, []

    def build(scene, settings=None, **kw):
        model, setup = real(scene, settings, **kw)
        built.append(make(model))
        return built[-1], setup

    monkeypatch.setattr(pipeline, "build_model", build)
    return built


def _state(model) -> dict:
    """Every attribute of the model, as bytes."""
    return {k: pickle.dumps(v) for k, v in vars(model).items()}


def test_capabilities_are_named_and_documented():
    """Every model declares only documented capabilities and options it accepts."""
    from creference_bayes.models.contract import CAPABILITIES

    for name, cls in pipeline.MODEL_CLASSES.items():
        assert cls.name == name and cls.capabilities <= set(CAPABILITIES)
        assert set(cls.word_options) <= set(cls.options) and pipeline.MODEL_OPTIONS[name] == cls.options
    assert pipeline.model_class("paper").has_ground_offsets(3) is False
    assert pipeline.model_class("metrology").has_ground_offsets(3) and not Model.has_ground_offsets(3)


def test_a_users_model_without_capabilities_goes_through_estimate_and_its_result(monkeypatch):
    """A model that is neither ``metrology`` nor ``paper``, without a corner scale or references,
    is fitted, sampled and read back through the Result: its result reports no per-object σ, its
    InferenceData has exactly its annotations as observations."""
    d, truth = truth_scene(3, m=3, n_annotations=2, noise_px=1.0, sizes_known=False)
    built = _use(monkeypatch, lambda m: CornerModel(m.principal_point, m.image_size, m.objects,
                                                    camera_terms=m.camera_terms, orientation=m.orientation,
                                                    bounds=m.bounds))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = cb.estimate(d, seed=0, sampling=TINY)
    assert isinstance(built[0], CornerModel)
    data = result.to_dict()
    assert data["model"] == "corners" and all("sigma_px" not in o for o in data["objects"])
    assert data["references"]["n_references"] == 0
    got = np.array([o.location_m for o in result.objects])[:, [0, 2]]
    np.testing.assert_allclose(got, truth["objects"][:, :2], rtol=0.1)
    idata = result.to_inference_data()
    assert idata.log_likelihood["observations"].sizes["observation"] == 6  # 3 targets × 2 sets


@pytest.mark.parametrize("kind", ["metrology", "paper"])
def test_estimate_leaves_the_model_it_estimates_unchanged(monkeypatch, kind):
    """Handedness, pilot, σ, softness and the free masks are the fit's state, not the model's:
    every attribute of the model ``estimate`` builds is the same after the MAP, the sampler and the
    result (a scene with references, so the metrology model's pilot fixes their line noise)."""
    d, _ = truth_scene(5, m=3, n_annotations=2, noise_px=1.0, n_refs=2)
    before = []
    built = _use(monkeypatch, lambda m: before.append(_state(m)) or m)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = cb.estimate(d, model=kind, seed=1, sampling=TINY, posterior=kind == "metrology")
    after = _state(built[0])
    assert result.model is not built[0] and built[0].pilot is None
    assert after.keys() == before[0].keys()
    changed = [k for k in before[0] if before[0][k] != after[k]]
    assert not changed, changed
    # the fit's state is the result's: the model it carries is at the MAP's handedness and pilot
    assert list(result.model.handedness) == [o["handedness"] for o in result.to_dict()["objects"]]
    assert np.allclose(result.model.pilot, result.to_dict()["pilot_camera"])


def test_equal_results_compare_equal_and_are_not_hashable(tmp_path):
    """``==`` compares content, draws and warnings (no error on the arrays inside)."""
    d, _ = truth_scene(2, m=1, n_annotations=3, noise_px=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = cb.estimate(d, seed=0, sampling=TINY)
        b = cb.estimate(d, seed=0, sampling=TINY)
        c = cb.estimate(d, seed=0, posterior=False)
    assert a == b and not a != b
    assert a != c and a != a.to_dict()
    saved = cb.load_result(a.save(tmp_path / "r.json"))
    assert saved == cb.load_result(tmp_path / "r.json")
    with pytest.raises(TypeError):
        hash(a)


@pytest.fixture(scope="module")
def estimates():
    """A scene of one target and one of three, estimated with a tiny budget."""
    out = {}
    for m in (1, 3):
        d, _ = truth_scene(4, m=m, n_annotations=2, noise_px=1.0, sizes_known=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out[m] = cb.estimate(d, seed=0, sampling=TINY)
    return out


@pytest.mark.parametrize("m", [1, 3])
def test_the_summary_has_ess_and_rhat_of_every_sampled_quantity(estimates, m):
    """Every row of a free quantity has ESS and R-hat, the bottom's y too (a derived quantity):
    with one object it is the camera height's; with several, its own."""
    result = estimates[m]
    table = result.summary()
    ids = [o.id for o in result.objects]
    for i in ids:
        for name in ("x", "y", "z", "yaw", "distance_m"):
            assert np.isfinite(table.loc[f"{name}[{i}]", "ess_bulk"]), (name, i)
            assert np.isfinite(table.loc[f"{name}[{i}]", "r_hat"]), (name, i)
    if m == 1:
        assert table.loc[f"y[{ids[0]}]", "ess_bulk"] == table.loc["camera_height_m", "ess_bulk"]
    diag = result.to_dict()["diagnostics"]
    assert {f"{i}.y" for i in ids} <= set(diag["ess_bulk"]) and {f"{i}.y" for i in ids} <= set(diag["r_hat"])


def test_the_diagnostics_have_one_shape_for_one_object_and_several(estimates):
    """The same keys, the same acceptance rates, the same quantities checked per object (by name)
    whether the scene has one object or three."""
    one, three = (estimates[m].to_dict()["diagnostics"] for m in (1, 3))
    assert one.keys() == three.keys() and "modes" in one
    assert one["acceptance"].keys() == three["acceptance"].keys() == {"all", "camera", "objects"}
    assert all(0 <= v <= 1 for d in (one, three) for v in d["acceptance"].values())

    def per_object(d):
        return {k.split(".", 1)[1] for k in d["ess_bulk"] if not k.startswith("camera.")}

    assert per_object(one) <= per_object(three) and {"x", "z", "yaw", "y", "distance_m"} <= per_object(one)
    assert one["ess_bulk"].keys() == one["r_hat"].keys() and three["ess_bulk"].keys() == three["r_hat"].keys()
