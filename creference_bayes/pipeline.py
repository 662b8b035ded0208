"""The public entry point: :func:`estimate` any scene, from the scene to its :class:`Result`.

Data flow, one way: scene (one target or many: a scene is a frame) → camera set-up
(:mod:`.camera_setup`) → model (:mod:`.models`: ``metrology`` or ``paper``, both the same
contract) → MAP (:mod:`.inference.map`) → posterior (:mod:`.inference.sampler`, an emcee run) →
result (:class:`Result`, its file :mod:`.io.result`). This module only wires the stages. The result
records how it was made (``provenance``), and :func:`rebuild_model` makes the same model again from
a result and its scene (:meth:`Result.to_inference_data` of a result read with :func:`load_result`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from .camera_setup import setup_camera
from .io.scene import Scene, load_scene, parse_scene
from .models.contract import ObjectData
from .models.location_prior import LocationPrior
from .models.metrology import MetrologyModel, ReferenceTerm
from .models.paper import PaperModel

__all__ = ["EstimateSettings", "MODELS", "MODEL_CLASSES", "model_class", "DEFAULT_MODEL", "MODEL_OPTIONS", "Result", "estimate", "load_result", "build_model", "rebuild_model", "map_state",
           "result_draws", "reference_terms", "parse_model_options", "option_record", "expected_ground"]

#: The models by name: classes of the model contract (:mod:`.models.contract`), each declaring its
#: capabilities and the options a user may set.
MODEL_CLASSES = {"metrology": MetrologyModel, "paper": PaperModel}
MODELS = tuple(MODEL_CLASSES)
#: The default model. The benchmark (docs/studies/benchmark.md) found the metrology model as good
#: as the paper's cost or better in every noise tier and, unlike it, calibrated at T = 1.
DEFAULT_MODEL = "metrology"
#: Model options a user may set, by model (the result's provenance records them).
MODEL_OPTIONS = {name: cls.options for name, cls in MODEL_CLASSES.items()}
_SIZES = ("length", "width", "height")


def model_class(model: str):
    """The class of the model named ``model`` (:data:`MODEL_CLASSES`); ``ValueError`` naming it
    when there is none."""
    try:
        return MODEL_CLASSES[model]
    except (KeyError, TypeError):
        raise ValueError(f"model: unknown model {model!r} (expected one of {list(MODELS)})") from None


def parse_model_options(model: str, items) -> dict:
    """Model options from ``KEY=VALUE`` strings (the command line's ``--option``): numbers (``inf``
    allowed), except ``line_reading`` and the paper model's ``on``, which are words. The model
    checks the values' ranges when it is built.

    Raises
    ------
    ValueError : not ``KEY=VALUE``, a KEY the model does not have, a number that is not one, or a
        KEY given twice (each names the item)
    """
    cls = model_class(model)
    out: dict = {}
    for item in items:
        key, sep, value = str(item).partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise ValueError(f"--option {item!r}: expected KEY=VALUE")
        if key not in MODEL_OPTIONS[model]:
            raise ValueError(f"--option {key}: the {model} model has no such option "
                             f"(expected one of {', '.join(MODEL_OPTIONS[model])})")
        if key in out:
            raise ValueError(f"--option {key}: given twice ({out[key]!r} and {value!r})")
        if key in cls.word_options:
            out[key] = value
            continue
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"--option {key}: expected a number, got {value!r}") from None
        if np.isnan(number):
            raise ValueError(f"--option {key}: expected a number, got {value!r}")
        out[key] = number
    return out


def option_record(value):
    """A model option as a result records it: an infinite number as the word (``"inf"``), JSON
    having no infinity."""
    if isinstance(value, (float, np.floating)) and np.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def expected_ground(model: str, options: Mapping, n_objects: int) -> dict | None:
    """The ``provenance.ground`` a result of a scene of ``n_objects`` targets made with these
    options records (:func:`_ground_dict`), or None where the ground's prior plays no part: the
    paper model and a scene of one target fix every ground offset. A batch compares it with a
    stored result's: a result made under another ground prior, :data:`UNRECORDED_GROUND` for one
    that records none, is recomputed."""
    if not model_class(model).has_ground_offsets(n_objects):
        return None
    from .models.contract import (DEFAULT_GROUND_DOF, DEFAULT_GROUND_SD_M, DEFAULT_GROUND_SD_PER_M,
                                  DEFAULT_GROUND_TILT_SD_RAD)

    ground = dict(ground_sd_m=DEFAULT_GROUND_SD_M, ground_sd_per_m=DEFAULT_GROUND_SD_PER_M,
                  ground_dof=DEFAULT_GROUND_DOF, ground_tilt_sd_rad=DEFAULT_GROUND_TILT_SD_RAD)
    return _ground_record(**{k: float(options.get(k, v)) for k, v in ground.items()})

def reference_terms(scene: Scene) -> list[ReferenceTerm]:
    """The scene's references as the models read them (:class:`~.models.metrology.ReferenceTerm`):
    a relative reference to a target of known size is a plain ground length."""
    out = []
    for r, owner in zip(scene.references, scene.reference_targets):
        common = dict(is_range=r.is_range, confidence=r.confidence, measure=r.measure, mode=r.mode)
        if isinstance(owner, tuple):
            out.append(ReferenceTerm(r.index, "distance", r.low, r.high, owner=owner[0], other=owner[1], **common))
        elif r.line is None:
            out.append(ReferenceTerm(r.index, "size", r.low, r.high, owner=owner, size_index=_SIZES.index(r.measure),
                                     **common))
        elif r.mode == "relative":
            t, k = scene.targets[owner], _SIZES.index(r.measure)
            if t.dimensions is not None:
                out.append(ReferenceTerm(r.index, "ground", r.low * t.dimensions[k], r.high * t.dimensions[k],
                                         line=np.asarray(r.line, float), **common))
            else:
                out.append(ReferenceTerm(r.index, "relative", r.low, r.high, line=np.asarray(r.line, float),
                                         owner=owner, size_index=k, **common))
        else:
            out.append(ReferenceTerm(r.index, "ground", r.low, r.high, line=np.asarray(r.line, float), **common))
    return out


@dataclass(frozen=True)
class EstimateSettings:
    """What decides an estimate's numbers besides the scene and the seed: one object that
    :func:`estimate`, :func:`build_model`, a batch (:class:`~.workflows.batch.BatchSettings`
    extends it) and the command line share.

    Attributes
    ----------
    model : one of :data:`MODELS`
    preset : ``default`` (closed-form starts and Newton steps), ``paper`` or ``paper-controlled``
        (the paper's basin hopping with random restarts, its bounds and σ in px)
    posterior : sample the posterior after the MAP
    restarts : random restarts of the paper's presets (None: the paper's)
    temperature : T of log p = log-likelihood / T + log-prior (priors are never tempered); None:
        the model's own (1 for the metrology model and the paper presets, 3 for the paper model
        with the default preset)
    hdi_prob : probability of the reported highest-density intervals, in (0, 1)
    sampling : sampler settings (:class:`~.inference.sampler.SamplerSettings` fields, e.g.
        ``{"min_ess": 400, "max_steps": 20000}``)
    orientation, focal_prior, orientation_prior : how the camera is treated
        (:func:`~.camera_setup.setup_camera`)
    location_prior : ``"auto"`` (``"log-depth"`` with the default preset, ``"flat"`` with the paper
        presets, whose method has no prior), a name of
        :data:`~.models.location_prior.LOCATION_PRIORS` or a
        :class:`~.models.location_prior.LocationPrior`
    distance_range : (low, high) metres: the ground distances the data set's targets stand at
        (the location prior falls softly outside them), or None
    bounds : a :class:`~.models.contract.Bounds` box instead of the preset's (simulation-based
        calibration estimates within the box its scenes are drawn from)
    classes : size priors of the user's own classes (name → ``SizePrior``; a scene's own win)
    confidence_map : how ranges stated with a confidence are read (metrology model):
        ``"default"``, ``"none"``, ``"identity"``, a map file's path or a
        :class:`~.models.confidence_map.ConfidenceMap`
    use_references : use the workers' references
    keep_draws : posterior draws the result keeps (0: none); None:
        :data:`~.io.result.RESULT_DRAWS`
    options : the model's own settings (:data:`MODEL_OPTIONS`, e.g. ``{"ground_sd_m": 0.08}``)
    """

    model: str = DEFAULT_MODEL
    preset: str = "default"
    posterior: bool = True
    restarts: int | None = None
    temperature: float | None = None
    hdi_prob: float = 0.9
    sampling: Mapping = field(default_factory=dict)
    orientation: str = "auto"
    focal_prior: Any = "auto"
    orientation_prior: Any = None
    location_prior: Any = "auto"
    distance_range: tuple[float, float] | None = None
    bounds: Any = None
    classes: Mapping = field(default_factory=dict)
    confidence_map: Any = "default"
    use_references: bool = True
    keep_draws: int | None = None
    options: Mapping = field(default_factory=dict)

    def __post_init__(self):
        cls = model_class(self.model)  # a ValueError naming the model
        t = self.temperature
        if t is not None and not (isinstance(t, (int, float)) and not isinstance(t, bool) and np.isfinite(t) and t > 0):
            raise ValueError(f"temperature: expected a finite number > 0, got {t!r}")
        if not (isinstance(self.hdi_prob, (int, float)) and 0 < self.hdi_prob < 1):
            raise ValueError(f"hdi_prob: expected a probability in (0, 1), got {self.hdi_prob!r}")
        unknown = sorted(set(self.options) - set(cls.options))
        if unknown:
            raise ValueError(f"{self.model} model: unknown option(s) {unknown} (expected some of {list(cls.options)})")
        if self.sampling:  # (the sampler's module, and emcee, only where there is something to check)
            from .inference.sampler import SamplerSettings

            SamplerSettings.from_options(self.sampling)  # a ValueError naming the sampler setting
        if self.distance_range is not None:
            LocationPrior(distance_m=self.distance_range)  # a ValueError naming the range
        object.__setattr__(self, "sampling", dict(self.sampling or {}))
        object.__setattr__(self, "classes", dict(self.classes or {}))
        object.__setattr__(self, "options", dict(self.options or {}))

    def replace(self, **changes) -> "EstimateSettings":
        """These settings with ``changes``: a field by its name, any other name a model option
        (added to :attr:`options`)."""
        names = {f.name for f in fields(self)}
        options = {k: changes.pop(k) for k in list(changes) if k not in names}
        if options:
            changes["options"] = {**changes.get("options", self.options), **options}
        return replace(self, **changes) if changes else self

    @classmethod
    def of(cls, settings: "EstimateSettings | None", changes: Mapping) -> "EstimateSettings":
        """``settings`` (default: the defaults) with ``changes`` (:meth:`replace`)."""
        base = cls() if settings is None else settings
        if not isinstance(base, EstimateSettings):
            raise TypeError(f"settings: expected an EstimateSettings, got {type(base).__name__}")
        return base.replace(**changes)

    def estimate_settings(self) -> "EstimateSettings":
        """Only the estimate's part (a batch's settings extend these)."""
        if type(self) is EstimateSettings:
            return self
        return EstimateSettings(**{f.name: getattr(self, f.name) for f in fields(EstimateSettings)})


def build_model(scene: Scene, settings: EstimateSettings | None = None, *, image_horizon: dict | None = None,
                **changes):
    """The model of ``scene`` and its camera set-up.

    Parameters
    ----------
    scene : the scene
    settings : :class:`EstimateSettings` (default: the defaults); the model reads ``model``,
        ``preset``, ``orientation``, ``focal_prior``, ``orientation_prior``, ``location_prior``,
        ``distance_range``, ``classes``, ``use_references``, ``confidence_map``, ``bounds`` and
        ``options``
    image_horizon : what an earlier estimate from the scene's image found
        (:func:`~creference_bayes.camera_setup.setup_camera`; a result's record), or None
    changes : changes to ``settings`` (:meth:`EstimateSettings.replace`: a field by its name, any
        other name a model option)
    """
    from .inference.map import preset_bounds

    st = EstimateSettings.of(settings, changes)
    model, preset, location_prior, classes = st.model, st.preset, st.location_prior, st.classes or None
    check_confidence_map(model, st.confidence_map)
    if location_prior == "auto":
        location_prior = "log-depth" if preset == "default" else "flat"
    if st.distance_range is not None:
        kind = location_prior.kind if isinstance(location_prior, LocationPrior) else location_prior
        location_prior = LocationPrior(kind, st.distance_range)
    setup = setup_camera(scene, orientation=st.orientation, focal_prior=st.focal_prior, orientation_prior=st.orientation_prior,
                         location_prior=location_prior, image_horizon=image_horizon)
    bounds = st.bounds if st.bounds is not None else preset_bounds(preset, scene.image_size)
    if setup.terms.location is not None and setup.terms.location.distance_m is not None:
        try:
            check_distance_range(setup.terms.location.distance_m, bounds, scene.image_size)
        except ValueError as exc:
            raise ValueError(f"distance_range: {exc}") from None
    objects = [ObjectData(t.id, t.corners, 1, t.dimensions,
                          None if t.dimensions is not None else t.size_prior or scene.size_prior(t.cls, classes), t.cls)
               for t in scene.targets]
    refs = reference_terms(scene) if st.use_references else []
    common = dict(camera_terms=setup.terms, orientation=setup.orientation, focal_length_px=scene.focal_length_px,
                  horizon_line=setup.camera.horizon if setup.orientation == "horizon" else None, bounds=bounds)
    return _BUILDERS[model](scene, objects, refs, setup, common, preset, st.confidence_map, st.options), setup


def check_confidence_map(model: str, confidence_map, option: str = "confidence_map") -> None:
    """A confidence map other than ``"default"`` or ``"none"`` needs a model that reads stated
    confidences (capability ``confidence_map``); a ValueError naming ``option`` and the model
    otherwise."""
    if "confidence_map" in model_class(model).capabilities or confidence_map is None or \
            isinstance(confidence_map, str) and confidence_map in ("default", "none"):
        return
    readers = [name for name, c in MODEL_CLASSES.items() if "confidence_map" in c.capabilities]
    raise ValueError(f"{option}: the {model} model does not read stated confidences, got {confidence_map!r} "
                     f"(use {' or '.join(f'the {r} model' for r in readers)}, or 'none')")


def _metrology(scene, objects, refs, setup, common, preset, confidence_map, options):
    """The metrology model of a scene (:func:`build_model`)."""
    from .models.confidence_map import resolve_confidence_map

    return MetrologyModel(scene.principal_point, scene.image_size, objects, refs,
                          confidence_map=resolve_confidence_map(confidence_map), corner_scale=scene.corner_scale,
                          **common, **options)


def _paper(scene, objects, refs, setup, common, preset, confidence_map, options):
    """The paper model of a scene (:func:`build_model`): its references aggregated into each
    object's bounds; the default preset's calibrated σ and temperature."""
    from .core.metrology import aggregate_references
    from .models.paper import CALIBRATED_SIGMA_PX, CALIBRATED_TEMPERATURE

    options = dict(options)
    on = options.pop("on", "xz")
    lines = [r for r in refs if r.kind == "ground"]
    bounds = common["bounds"]
    focal_range = None if bounds is None else (bounds.camera_lower[0], bounds.camera_upper[0])
    reports = [aggregate_references(o.corner_median, lines, setup.aggregation_camera, on=on,
                                    focal_range_px=focal_range) for o in objects]
    calibrated = preset == "default"
    options = {"sigma": CALIBRATED_SIGMA_PX if calibrated else options.get("sigma", 100.0), **options}
    return PaperModel(scene.principal_point, scene.image_size, objects, [r.constraints for r in reports],
                      reference_reports=reports, default_temperature=CALIBRATED_TEMPERATURE if calibrated else 1.0,
                      **common, **options)


#: How each model of :data:`MODEL_CLASSES` is built from a scene.
_BUILDERS = {"metrology": _metrology, "paper": _paper}


def check_distance_range(distance_m, bounds, image_size=(1, 1)) -> None:
    """A distance range (low, high) m must meet the ground distances a model's bounds allow
    (``bounds`` None: the default preset's wide box); a ValueError naming both (without the
    option's name: the caller's words for it differ)."""
    from .models.contract import O_X, O_Z, Bounds

    bounds = bounds if bounds is not None else Bounds.wide(image_size)

    x_far = max(abs(bounds.object_lower[O_X]), abs(bounds.object_upper[O_X]))
    near, far = max(bounds.object_lower[O_Z], 0.0), float(np.hypot(x_far, bounds.object_upper[O_Z]))
    lo, hi = distance_m
    if lo > far or hi < near:
        raise ValueError(f"[{lo:g}, {hi:g}] m lies beyond the ground distances the bounds allow "
                         f"({near:.3g} to {far:.4g} m: z from {bounds.object_lower[O_Z]:g} to "
                         f"{bounds.object_upper[O_Z]:g} m, |x| up to {x_far:g} m)")


def _load(scene, classes) -> Scene:
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, Mapping):  # a decoded scene file
        return parse_scene(scene, classes=classes)
    return load_scene(scene, classes=classes)


def estimate(scene: Scene | str | Path | Mapping, settings: EstimateSettings | None = None, *, seed=None,
             progress: bool = False, **changes):
    """Estimate every target of a scene and its camera.

    Parameters
    ----------
    scene : a :class:`~.io.scene.Scene`, the path of a scene file (``creference-scene/1``: one
        target; ``creference-scene/2``: one or more) or such a file's content as a dict
    settings : :class:`EstimateSettings` (default: the defaults)
    seed : int or Generator; the same seed gives the same result
    progress : progress bars on standard error
    changes : changes to ``settings`` by keyword (:meth:`EstimateSettings.replace`: a field by its
        name, e.g. ``model="paper"``, ``hdi_prob=0.5``, ``sampling={"min_ess": 400}``; any other
        name a model option, e.g. ``ground_sd_m=0.1``)

    Returns
    -------
    :class:`Result`
    """
    from .inference.map import optimize
    from .inference.threads import single_threaded_blas
    from .io.result import RESULT_DRAWS, result_data

    st = EstimateSettings.of(settings, changes)
    scene = _load(scene, st.classes or None)
    rng = np.random.default_rng(seed)
    with single_threaded_blas():
        t0 = time.perf_counter()
        m, setup = build_model(scene, st)
        T = m.default_temperature if st.temperature is None else float(st.temperature)
        map_est = optimize(m, preset=st.preset, temperature=T, rng=rng, restarts=st.restarts, progress=progress)
        m = map_est.fitted(m)  # the model at the fit's handedness and pilot (a copy)
        draws = diag = None
        notes = []
        if st.posterior:
            from .inference.sampler import SamplerSettings, SamplingError, sample

            try:
                draws, diag = sample(m, map_est, settings=SamplerSettings.from_options(st.sampling), rng=rng,
                                     temperature=T, progress=progress)
            except SamplingError as exc:  # a MAP with zero posterior density: report, do not crash
                notes.append(f"posterior not sampled: {exc}")
            else:
                if "mode_starts" in diag.info:  # the search before sampling found other modes: the best optimum
                    from .inference.map import refine  # reached from any of them is the MAP

                    for start in diag.info.pop("mode_starts"):
                        map_est = refine(m, map_est, *start, temperature=T)
                    m = m.variant(handedness=map_est.handedness)
                if "pilot" in diag.info:  # the draws' pilot (the posterior's median camera) is the result's
                    m = m.variant(pilot=diag.info.pop("pilot"))
        provenance = {"model": st.model, "preset": st.preset,
                      "options": {k: option_record(st.options[k]) for k in sorted(st.options)},
                      "orientation": st.orientation,
                      "focal_prior": st.focal_prior if isinstance(st.focal_prior, str) else "given",
                      "location_prior": m.location.kind, "use_references": st.use_references, "temperature": T,
                      "hdi_prob": st.hdi_prob, "seed": seed if isinstance(seed, (int, type(None))) else "generator",
                      "sampling": dict(st.sampling), "confidence_map": _describe_map(m),
                      "classes": {k: v.to_dict() for k, v in st.classes.items()},
                      "bounds": None if st.bounds is None else _bounds_dict(st.bounds), "ground": _ground_dict(m)}
        if m.location.distance_m is not None:  # recorded only when given: a result without it had no range
            provenance["distance_range_m"] = list(m.location.distance_m)
        if m.location.population is not None:  # a data set's fitted population (workflows/batch/dataset.py)
            provenance["location_population"] = list(m.location.population)
        data = result_data(scene, m, setup, map_est, draws, diag, hdi_prob=st.hdi_prob, provenance=provenance,
                           seconds=time.perf_counter() - t0, notes=notes,
                           keep_draws=RESULT_DRAWS if st.keep_draws is None else int(st.keep_draws))
        return Result(data, draws, diag, tuple(data["warnings"]), m, scene_file=scene.source)


class ResultWarning(UserWarning):
    """What a :class:`Result` could not do in full (an InferenceData without the scene's part)."""


@dataclass(frozen=True, eq=False)
class Result:
    """The estimate of one scene: what :func:`estimate` returns and :func:`load_result` reads back.

    Read it with :attr:`objects` (each target's MAP, posterior and HDIs), :attr:`camera`,
    :attr:`converged` and :meth:`summary` (a table); :meth:`to_inference_data` gives the posterior
    as an ``arviz.InferenceData``; :meth:`save` writes the file (``creference-result/2``,
    docs/result_format.md), whose content :meth:`to_dict` returns.

    Attributes
    ----------
    data : the file's content (:meth:`to_dict`)
    draws : the posterior draws: ``cameras`` (chain, draw, 5), ``objects`` (chain, draw, m, 7) and
        ``log_prob``; every draw of an estimate, the kept ones (``draws`` of the file, by chain) of
        a result read back; None without a posterior
    diagnostics : the sampler's :class:`~.inference.sampler.Diagnostics` (None for a result read
        back: its file's ``diagnostics``)
    warnings : what the user should know
    model : the model estimated (None for a result read back: :meth:`to_inference_data` rebuilds
        it from the scene)
    scene_file : the scene's file, when known (:meth:`save` records where it is)
    source : the file the result was read from, or None
    """

    data: dict
    draws: Any = None
    diagnostics: Any = None
    warnings: tuple[str, ...] = ()
    model: Any = field(default=None, repr=False, compare=False)
    scene_file: Path | None = field(default=None, repr=False, compare=False)
    source: Path | None = field(default=None, repr=False, compare=False)

    def __eq__(self, other) -> bool:
        """Equal results have the same content (:meth:`to_dict`, numbers exactly, NaN equal to NaN),
        the same draws and the same warnings; how long it took (every ``seconds``), the model, the
        diagnostics object and where the files are do not count: the same scene estimated with the
        same seed gives an equal result. A result is unhashable (its content is a dict)."""
        if not isinstance(other, Result):
            return NotImplemented
        return _same(self.data, other.data) and _same(self.warnings, other.warnings) and \
            _same(None if self.draws is None else vars(self.draws), None if other.draws is None else vars(other.draws))

    __hash__ = None

    @property
    def objects(self) -> tuple:
        """Each target's :class:`~.io.result.ObjectEstimate`, in the scene's order."""
        from .io.result import ObjectEstimate

        return tuple(ObjectEstimate.from_dict(o) for o in self.data["objects"])

    @property
    def camera(self):
        """The camera's :class:`~.io.result.CameraEstimate`."""
        from .io.result import CameraEstimate

        return CameraEstimate.from_dict(self.data["camera"])

    @property
    def converged(self) -> bool | None:
        """Whether the posterior sampler converged (None without a posterior)."""
        diag = self.data.get("diagnostics")
        return None if not isinstance(diag, dict) or diag.get("converged") is None else bool(diag["converged"])

    @property
    def hdi_prob(self) -> float | None:
        """The probability of the result's highest-density intervals."""
        return self.data.get("hdi_prob")

    def to_dict(self) -> dict:
        """The file's content (``creference-result/2``; docs/result_format.md)."""
        return self.data

    def summary(self):
        """A pandas DataFrame, a row per quantity (``focal_length_px``, …, ``x[t0]``, …) and the
        columns ``map``, ``mean``, ``sd``, ``median``, the HDI's ends (``hdi_5%``, ``hdi_95%``),
        ``ess_bulk`` and ``r_hat``: the result's own numbers (from every draw), the same after
        :meth:`save` and :func:`load_result`."""
        from .inference.summary import summary_table

        return summary_table(self.data)

    def to_inference_data(self, scene: Scene | str | Path | None = None):
        """The posterior as an ``arviz.InferenceData`` (layout: :mod:`.inference.summary`):
        ``posterior``, ``sample_stats``, ``log_likelihood`` (every observation once, for
        ``arviz.loo``), ``observed_data``, ``constant_data``, the provenance in the attributes; None
        without a posterior.

        A result read back holds its kept draws and rebuilds its model from its scene (``scene``, else
        where :func:`~.io.result.find_scene` looks); when the scene cannot be found the
        InferenceData has the posterior and sample_stats only, says so in its attribute
        ``missing`` and warns (:class:`ResultWarning`).
        """
        from .inference.summary import to_inference_data

        if self.draws is None:
            return None
        model, note = self.model, None
        if model is None:
            try:
                model = rebuild_model(self.data, self._scene(scene))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                reason = " ".join(str(exc).split())
                note = f"log_likelihood, observed_data and constant_data need the result's scene ({reason})"
                warnings.warn(note, ResultWarning, stacklevel=2)
        return to_inference_data(self.data, self.draws, model, note)

    def _scene(self, scene):
        from .io.result import find_scene

        if scene is not None:
            return scene
        try:
            if self.source is None:
                raise FileNotFoundError(2, "the result was not read from a file: pass scene=", str(self.data.get("scene")))
            return find_scene(self.data, self.source)
        except (OSError, ValueError):
            if self.scene_file is None:
                raise
            return self.scene_file

    def save(self, path: str | Path) -> Path:
        """Write the result's file (JSON, atomically) to ``path``; it records where the scene's file is
        (``scene_path``, relative to ``path``) when known, so that :func:`load_result` and the
        commands ``plot`` and ``advise`` find it. Returns the path."""
        from .io.files import atomic_write_json
        from .io.result import scene_path_from

        d = dict(self.data)
        if self.scene_file is not None:
            d["scene_path"] = scene_path_from(path, self.scene_file)
        return atomic_write_json(path, d, inline_numbers=True)


def _same(a, b) -> bool:
    """Whether two values of a result (dicts, lists, arrays, numbers, strings) are the same, but
    for timings (``seconds``)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(k == "seconds" or _same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, (np.ndarray, float, np.floating)) or isinstance(b, (np.ndarray, float, np.floating)):
        try:
            return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
        except TypeError:  # not numbers
            return np.array_equal(np.asarray(a), np.asarray(b))
    return type(a) is type(b) and a == b


def load_result(path: str | Path, scene: Scene | str | Path | None = None) -> Result:
    """A result file (``creference estimate --out``, :meth:`Result.save`, a batch's
    ``results/KEY.json``) as a :class:`Result`, with its kept draws by chain. A
    ``creference-result/1`` file is read in the current format, which needs its scene (``scene``,
    else where :func:`~.io.result.find_scene` looks). ``ValueError`` naming the file when it is not
    a result."""
    from .io.result import chained_draws, find_scene, read_result, result_from_v1

    path = Path(path)
    d = read_result(path)
    if d.get("format") == "creference-result/1":
        found = scene if isinstance(scene, Scene) else find_scene(d, path, scene)
        d = result_from_v1(d, found)
    scene_file = None
    if isinstance(d.get("scene_path"), str) and d["scene_path"]:
        candidate = path.parent / d["scene_path"]
        scene_file = candidate if candidate.is_file() else None
    if isinstance(scene, (str, Path)):  # given for a creference-result/1
        scene_file = Path(scene)
    try:
        draws = chained_draws(d)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return Result(d, draws, None, tuple(d.get("warnings") or ()), None,
                  scene_file=scene_file, source=path)


def _describe_map(model) -> dict:
    """The map the model read stated ranges with (a fitted map with its content, so that
    :func:`rebuild_model` reads them the same way)."""
    from .models.confidence_map import describe_confidence_map

    cmap = model.confidence_map if "confidence_map" in model.capabilities else None
    out = describe_confidence_map(cmap)
    return {**out, "map": cmap.to_dict()} if out["name"] == "file" else out


def _bounds_dict(b) -> dict:
    return {k: [float(v) if np.isfinite(v) else None for v in getattr(b, k)]
            for k in ("camera_lower", "camera_upper", "object_lower", "object_upper")}


def _bounds_from(d):
    """The bounds a result records, its unbounded ends (written as null) infinite."""
    from .models.contract import Bounds

    if not d:
        return None
    keys = ("camera_lower", "camera_upper", "object_lower", "object_upper")
    return Bounds(*(np.array([(-np.inf if k == "object_lower" else np.inf) if v is None else v for v in d[k]],
                             float) for k in keys))


def rebuild_model(result, scene: Scene | str | Path):
    """The model a result was made with, from the result (or its dict) and its scene, in one call:
    the same model, camera set-up, classes, options, bounds, each target's handedness and pilot. A
    horizon the estimate found in the scene's image is read from the result's record, not found
    again."""
    from .models.confidence_map import ConfidenceMap
    from .models.size_priors import size_priors_from_dict

    d = result if isinstance(result, dict) else result.to_dict()
    prov = d.get("provenance")
    missing = [k for k in ("options", "orientation", "focal_prior", "use_references")
               if not isinstance(prov, dict) or k not in prov]
    if missing:
        raise ValueError(f"provenance.{missing[0]}: missing (the settings the result was made with)")
    classes = size_priors_from_dict(prov["classes"], "provenance.classes", "file") if prov.get("classes") else None
    scene = _load(scene, classes)
    cmap = prov.get("confidence_map") or {"name": "none"}
    confidence_map = ConfidenceMap.from_dict(cmap["map"]) if cmap["name"] == "file" else \
        ConfidenceMap.identity(cmap.get("dof")) if cmap["name"] == "identity" else "none"
    kind = prov.get("model", DEFAULT_MODEL)
    cls = model_class(kind)
    options = {k: float(v) if isinstance(v, str) and k not in cls.word_options else v  # "inf" (JSON has no infinity)
               for k, v in prov["options"].items()}
    if "ground_sd_m" in cls.options:  # the ground's prior it was made with (a result without it: UNRECORDED_GROUND)
        options = {**_ground_options(prov.get("ground") or UNRECORDED_GROUND), **options}
    model, _ = build_model(scene, EstimateSettings(model=kind, preset=prov.get("preset", "default"),
                           orientation=prov["orientation"],
                           focal_prior=prov["focal_prior"] if prov["focal_prior"] != "given" else "auto",
                           location_prior=LocationPrior(prov.get("location_prior", "flat"),
                                                        population=prov.get("location_population")),
                           distance_range=prov.get("distance_range_m"), classes=classes,
                           use_references=prov["use_references"], confidence_map=confidence_map,
                           bounds=_bounds_from(prov.get("bounds")), options=options),
                           image_horizon=_recorded_image_horizon(d))
    hands = [o.get("handedness") for o in d["objects"]]
    if not all(h in (-1, 1) and not isinstance(h, bool) for h in hands):
        raise ValueError(f"objects[].handedness: expected -1 or 1 for every object, got {hands[:5]!r}")
    pilot = d.get("pilot_camera")
    if pilot is not None:
        if not (isinstance(pilot, list) and len(pilot) == 5 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in pilot)):
            raise ValueError(f"pilot_camera: expected null or 5 finite numbers, got {str(pilot)[:60]}")
        pilot = np.array(pilot, float)
    return model.variant(handedness=np.array(hands, float), pilot=pilot)


def _recorded_image_horizon(d: dict):
    """A result's ``camera.setup.horizon_estimate`` (what its estimate found in the scene's image),
    or None; :func:`~creference_bayes.camera_setup.setup_camera` checks what is in it."""
    setup = d["camera"].get("setup") if isinstance(d.get("camera"), dict) else None
    return setup.get("horizon_estimate") if isinstance(setup, dict) else None


#: The ground-offset prior a result that records no ``provenance.ground`` is read with: a normal of
#: 8 cm at every distance, as :func:`_ground_dict` writes it.
UNRECORDED_GROUND = {"sd_m": 0.08, "sd_per_m": 0.0, "dof": None, "tilt_sd_rad": float(np.radians(1.0))}


def _ground_dict(model) -> dict:
    """``provenance.ground``: the model's ground-offset prior (metres, metres per metre, degrees of
    freedom, null for a normal) and the ground's tilt (radians)."""
    return _ground_record(**model.ground_options)


def _ground_record(ground_sd_m, ground_sd_per_m, ground_dof, ground_tilt_sd_rad) -> dict:
    """The ground options as ``provenance.ground`` writes them (the inverse of :func:`_ground_options`)."""
    return {"sd_m": ground_sd_m, "sd_per_m": ground_sd_per_m, "dof": None if np.isinf(ground_dof) else ground_dof,
            "tilt_sd_rad": ground_tilt_sd_rad}


def _ground_options(ground: dict) -> dict:
    """The model options of a ``provenance.ground``."""
    return {"ground_sd_m": ground["sd_m"], "ground_sd_per_m": ground["sd_per_m"],
            "ground_dof": np.inf if ground["dof"] is None else ground["dof"],
            "ground_tilt_sd_rad": ground["tilt_sd_rad"]}


def map_state(result) -> tuple[np.ndarray, np.ndarray]:
    """The MAP of a result (or its dict) as model arrays: camera (5,) and objects (m, 7)."""
    from .models.contract import CAMERA_NAMES, OBJECT_NAMES

    d = result if isinstance(result, dict) else result.to_dict()
    camera = np.array([d["camera"]["map"][k] for k in CAMERA_NAMES], float)
    objects = np.array([[o["map"][k] for k in OBJECT_NAMES] for o in d["objects"]], float)
    return camera, objects


def result_draws(result, model, *, n: int = 2000, seed=0) -> tuple[np.ndarray, np.ndarray, str]:
    """Posterior draws of a result: those it keeps (``draws``) when it has them, else ``n`` draws of
    the Laplace approximation at its MAP (:mod:`.inference.laplace`) of the rebuilt ``model``.

    Returns cameras (k, 5), objects (k, m, 7) and where they came from (``"posterior"`` or
    ``"laplace"``).
    """
    from .inference.laplace import laplace
    from .io.result import stored_draws

    d = result if isinstance(result, dict) else result.to_dict()
    kept = stored_draws(d)  # a malformed ``draws`` raises ValueError naming the key
    if kept is not None and kept.objects.shape[2] == model.n_objects:
        return kept.cameras.reshape(-1, 5), kept.objects.reshape(-1, model.n_objects, 7), "posterior"
    camera, objects = map_state(d)
    lap = laplace(model, camera, objects, temperature=float(d["provenance"].get("temperature", 1.0)))
    cams, objs = lap.draws(n, seed)
    return cams, objs, "laplace"
