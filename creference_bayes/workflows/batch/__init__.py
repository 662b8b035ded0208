"""Estimate every scene of a data set: discovery, seeds, resume, failure isolation (docs/batch.md).

A scene file is the unit (a scene of one or many targets, either format,
:func:`~creference_bayes.estimate`): one result, one seed, one copy, one error record.

The batch folder::

    DIR/results/KEY.json   the scene's creference-result/2, plus a ``batch`` block (key, source,
                           seed, settings): written atomically, the mark that the scene is done
    DIR/scenes/KEY.json    a copy of the scene (canonical creference-scene/2, same fingerprint as
                           the original): what ``creference labels`` needs (sizes, camera, truth)
    DIR/errors/KEY.json    why the scene failed (invalid input, an exception, the time limit)
    DIR/summary.csv        one row per target (summary.py)
    DIR/batch.json         the run's settings and every scene's status

KEY is the scene file's path relative to the folder given on the command line, without
``.json`` (a file given directly: its stem). A scene is skipped on a rerun when its result exists,
records the fingerprint of the scene as it is now (``scene_id.sha256``) and was made with the same
settings; everything else is (re)computed. Each scene's seed derives from the base seed and the
scene's fingerprint (:func:`derive_seed`), never from its position or the engine, so the numbers
are the same whatever the engine, the worker count or the order.
"""

from __future__ import annotations

import hashlib
import math
import time
import warnings
from collections import deque
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ... import __version__
from ...io.files import atomic_write_json
from ...io.scene import SceneError, SceneWarning, load_scene, scene_fingerprint, scene_to_dict, with_classes
from ...pipeline import EstimateSettings, option_record
from .files import ERROR_FORMAT, layout, record_error, up_to_date
from .dataset import shared_scale
from .runner import Runner, one_line, progress_bar, run_scene
from .engines import Engine

__all__ = ["BATCH_FORMAT", "ERROR_FORMAT", "BatchSettings", "SceneInput", "BatchReport",
           "discover_scenes", "derive_seed", "run_scene", "run_batch", "learn_priors", "layout", "corner_scales",
           "segment_floors", "hand_segments", "MIN_FLOOR_SEGMENTS"]

BATCH_FORMAT = "creference-batch/2"


@dataclass(frozen=True)
class BatchSettings(EstimateSettings):
    """What decides a scene's numbers; a result made with other settings is recomputed: the
    estimate's settings (:class:`~creference_bayes.pipeline.EstimateSettings`, whose fields these
    extend; ``sampling`` e.g. ``{"min_ess": 400, "max_steps": 20000}``; ``confidence_map`` is
    compared by the map actually used, a file's by its content wherever it lies) and the batch's own.

    Attributes
    ----------
    seed : base seed; each scene's seed is :func:`derive_seed` (seed, scene fingerprint)
    dataset : ``auto``: learn what the frames share when there is something to learn (the camera's
        focal length and mounting, the crowd's reference scale, where targets stand), from a
        first pass, and hand it back to each frame (:mod:`.dataset`); ``none``: every frame alone
        (the crowd's corner scale excepted: ``pool_scale``)
    rig : what the frames of one camera (``camera.id``) share: ``auto`` (the focal length and the
        mounting), ``focal`` (the focal length only), ``mounting`` (the same as ``auto``) or
        ``none`` (nothing of the camera) (:mod:`.rig`)
    pool_scale : a frame whose objects are not all annotated twice takes the crowd's corner scale
        from the other frames too (:func:`corner_scales`), and every frame the crowd's segment floor
        (:func:`segment_floors`); False: from its own annotations only, and the default floor

    A stored result is also compared by the ground prior it records
    (:func:`~creference_bayes.pipeline.expected_ground`).
    """

    seed: int = 0
    dataset: str = "auto"
    rig: str = "auto"
    pool_scale: bool = True

    def __post_init__(self):
        from .dataset import DATASET_CHOICES
        from .rig import RIG_CHOICES

        super().__post_init__()  # the estimate's settings: a ValueError naming each bad one
        if self.dataset not in DATASET_CHOICES:
            raise ValueError(f"dataset: expected one of {list(DATASET_CHOICES)}, got {self.dataset!r}")
        if self.rig not in RIG_CHOICES:
            raise ValueError(f"rig: expected one of {list(RIG_CHOICES)}, got {self.rig!r}")

    def ground(self, n_objects: int) -> dict | None:
        """The ground prior a result of a scene of ``n_objects`` targets is made under (None: it
        plays no part), :func:`~creference_bayes.pipeline.expected_ground`."""
        from ...pipeline import expected_ground

        return expected_ground(self.model, self.options, n_objects)

    def to_dict(self) -> dict:
        """The settings as the results record them (``batch.settings``) and a rerun compares them."""
        from ...io.result import RESULT_DRAWS

        d = asdict(replace(self, confidence_map=None, classes={}))
        for key in ("restarts", "orientation_prior", "bounds"):  # the estimate's fields a batch leaves at None
            if d[key] is None:
                del d[key]
        d["sampling"] = dict(sorted(self.sampling.items()))
        d["confidence_map"] = self._map_identity()
        d["classes"] = {k: self.classes[k].to_dict() for k in sorted(self.classes)}
        d["keep_draws"] = RESULT_DRAWS
        del d["pool_scale"]  # what it changes, the scene's corner_scale, is in the scene's fingerprint
        d["options"] = {k: option_record(v) for k, v in sorted(self.options.items())}  # inf as "inf"
        if not self.options:  # results made before the option existed stay up to date
            del d["options"]
        for key in ("dataset", "rig"):  # the defaults: what a frame took is in its scene and its job's record
            if d[key] == "auto":
                del d[key]
        if self.distance_range is None:  # likewise for the distance range
            del d["distance_range"]
        else:
            d["distance_range"] = [float(v) for v in self.distance_range]
        return d

    def _map_identity(self) -> dict:
        """The map the estimates use, as compared on a rerun (a file's content, not its path)."""
        from ...models.confidence_map import describe_confidence_map, resolve_confidence_map
        from ...pipeline import model_class

        if "confidence_map" not in model_class(self.model).capabilities:  # the pipeline checks the map
            return {"name": "none"}
        d = describe_confidence_map(resolve_confidence_map(self.confidence_map))
        d.pop("source", None)
        return d

@dataclass(frozen=True)
class SceneInput:
    """One scene file and the KEY that names its files in the batch folder."""

    key: str
    path: Path


def discover_scenes(inputs, exclude: str | Path | None = None) -> list[SceneInput]:
    """Scene files from files and folders (every ``*.json`` below a folder, sorted, hidden ones left out).

    Parameters
    ----------
    inputs : paths of scene files or folders
    exclude : a folder whose files are never inputs (the batch folder itself)

    Raises
    ------
    FileNotFoundError : an input does not exist
    ValueError : no scene file at all, or two different files with the same KEY
    """
    exclude = None if exclude is None else Path(exclude).resolve()
    found: dict[str, SceneInput] = {}
    for item in inputs:
        root = Path(item)
        if root.is_dir():
            files = [(p.relative_to(root).with_suffix("").as_posix(), p) for p in sorted(root.rglob("*.json"))
                     if not any(part.startswith(".") for part in p.relative_to(root).parts)]
        elif root.exists():
            files = [(root.stem, root)]
        else:
            raise FileNotFoundError(2, "no such file or folder", str(root))
        for key, path in files:
            resolved = path.resolve()
            if exclude is not None and resolved.is_relative_to(exclude):
                continue
            if key in found and found[key].path.resolve() != resolved:
                raise ValueError(f"two scene files would share the name {key!r} in the batch folder: "
                                 f"{found[key].path} and {path} (run them as separate batches)")
            found.setdefault(key, SceneInput(key, path))
    if not found:
        raise ValueError(f"no scene files (*.json) in {', '.join(map(str, inputs)) or 'the inputs'}")
    return list(found.values())


def derive_seed(base_seed: int, fingerprint: str) -> int:
    """A scene's seed, an integer in [0, 2⁶⁰), from the base seed and the scene's fingerprint
    (:func:`~creference_bayes.io.scene.scene_fingerprint`): the same scene content gives the same
    seed wherever, whenever and in whatever order it runs."""
    digest = hashlib.sha256(f"creference-batch:{int(base_seed)}:{fingerprint}".encode()).hexdigest()
    return int(digest[:15], 16)


@dataclass
class BatchReport:
    """What a batch run did. ``status`` maps every KEY to ``done``, ``skipped``, ``failed`` or
    ``not run`` (interrupted); ``errors`` maps failed KEYs to their one-line error."""

    status: dict[str, str]
    errors: dict[str, str]
    seconds: float
    engine: str
    #: targets estimated in this run (every target of every scene estimated)
    n_targets: int = 0
    #: the KEYs, done or skipped, whose result says its posterior did not converge (summary.csv)
    not_converged: list[str] = field(default_factory=list)
    #: what the data set learnt: each quantity's pool of all the frames of each group, with its
    #: checks and warnings (:meth:`.dataset.DataSet.summary`); empty when nothing was learnt
    dataset: dict = field(default_factory=dict)
    #: what the batch set out to learn and could not, a line each (:meth:`.dataset.DataSet.not_learnt`)
    dataset_notes: list[str] = field(default_factory=list)

    def keys(self, status: str) -> list[str]:
        return [k for k, s in self.status.items() if s == status]

    @property
    def ok(self) -> bool:
        return all(s in ("done", "skipped") for s in self.status.values())

    @property
    def targets_per_minute(self) -> float | None:
        return 60.0 * self.n_targets / self.seconds if self.n_targets and self.seconds > 0 else None


def run_batch(inputs, out: str | Path, engine: Engine, settings: BatchSettings = BatchSettings(), *,
              time_limit: float | None = None, progress: bool | str = False,
              on_event: Callable[[str, str], None] | None = None) -> BatchReport:
    """Estimate every scene of ``inputs`` into the batch folder ``out`` with ``engine``.

    Parameters
    ----------
    inputs : scene files and folders (:func:`discover_scenes`)
    out : the batch folder (created)
    engine : :class:`~.engines.LocalEngine` or :class:`~.engines.DaskEngine`; closed on return
    settings : what decides the numbers
    time_limit : seconds a scene may take from the moment it starts, or None. A scene over it is
        recorded as failed and the batch goes on; its computation is abandoned (a local worker
        process is ended when the batch ends, a Dask worker thread runs on until it finishes)
    progress : show a tqdm bar on standard error (True), or print a line there per finished scene,
        with how it ended and its time (``"lines"``, for a log file)
    on_event : called with (KEY, status) as each scene ends (tests, logging)

    Returns
    -------
    BatchReport; the folder also holds ``summary.csv`` and ``batch.json``. When the data set has
    something to teach (:func:`.dataset.plan`), the frames are first estimated alone, a MAP each,
    into ``out/first_pass`` (a batch folder of its own, resumed like any), then each frame into
    ``out`` with the priors the other frames give it; its result then has a ``dataset`` block (and,
    with its camera's pool, a ``rig`` block). The report is the second pass's; its time counts
    both; its ``dataset`` holds each quantity's pool of all the frames, with the pools' warnings.
    """

    t_start = time.perf_counter()
    out = Path(out)
    try:
        if time_limit is not None and not time_limit > 0:
            raise ValueError(f"time_limit: expected a number of seconds > 0, got {time_limit!r}")
        scenes = discover_scenes(inputs, exclude=out)
        out.mkdir(parents=True, exist_ok=True)
    except BaseException:
        engine.close(abandon=True)
        raise
    run = dict(engine=engine, time_limit=time_limit, progress=progress, on_event=on_event, t_start=t_start)
    from .dataset import hand_back, plan

    try:
        loaded = _load_quietly(scenes, settings) if settings.dataset != "none" else []
        learn = plan([scene for _, scene in loaded], settings)
    except BaseException as exc:
        engine.close(abandon=True)
        if isinstance(exc, KeyboardInterrupt):  # stopped while the scenes are read: the folder still
            _write_folder(out, scenes, settings.to_dict(), {si.key: "not run" for si in scenes}, {}, engine,
                          t_start, time_limit)  # gets its summary, every scene not run
        raise
    if not learn:
        return _run_pass(scenes, out, settings, **run)
    try:  # every frame alone, a MAP each, into out/first_pass: a batch folder of its own, resumed like any
        ds = _first_pass(scenes, loaded, out / "first_pass", settings, learn, run)
    except BaseException:
        engine.close(abandon=True)
        raise
    report = _run_pass(scenes, out, settings, transform=lambda key, scene: hand_back(ds, key, scene, settings),
                       dataset=ds.summary(), **run)
    report.dataset_notes = ds.not_learnt()
    return report


def _first_pass(scenes, loaded, first: Path, settings: BatchSettings, learn: tuple, run: dict):
    """Estimate every frame alone (a MAP each) into ``first`` and read what the frames share
    (:meth:`.dataset.DataSet.from_first_pass`); the engine is left open."""
    from .dataset import DataSet
    from .rig import camera_id_of

    alone = replace(settings, posterior=False, dataset="none", rig="none")
    _run_pass(scenes, first, alone, close=False, desc="first pass", **run)
    frames = [(si.key, camera_id_of(scene)) for si, scene in loaded]
    ds = DataSet.from_first_pass(frames, first, learn,
                                 settings={si.key: scene.setting for si, scene in loaded if scene.setting is not None})
    if (at := ds.refit_at()) is not None:  # the crowd's corner scale read again from a fit at its own scale
        again = first / "at_crowd_scale"
        _run_pass([si for si in scenes if si.key in ds.residuals], again,
                  replace(alone, options={**settings.options, "target_sigma": at}), close=False,
                  desc="first pass at the crowd's scale", **run)
        ds = ds.with_residuals_from(frames, again, at)
    return ds


def learn_priors(inputs, out: str | Path, settings: BatchSettings = BatchSettings(), engine: Engine | None = None) -> dict:
    """What ``creference batch`` hands each frame, without estimating the frames with it: the
    batch's first pass into ``out`` (a MAP each, resumed like any batch folder; run only when the
    data set has something to teach, :func:`.dataset.plan`), the crowd's corner scale of the
    other frames (``settings.pool_scale``) and each frame's priors from the others
    (:func:`.dataset.hand_back`). Returns KEY → (scene with its handed-back priors, estimate
    keyword arguments, the ``dataset`` block its result would carry), for every scene that loads.
    For studies that estimate the frames themselves (examples/advice_study.py ``--dataset``)."""
    from .dataset import hand_back, plan
    from .engines import LocalEngine

    out = Path(out)
    scenes = discover_scenes(inputs, exclude=out)
    loaded = _load_quietly(scenes, settings)
    learn = plan([scene for _, scene in loaded], settings)
    ds = None
    if learn:
        engine = engine or LocalEngine(1)
        run = dict(engine=engine, time_limit=None, progress=False, on_event=None, t_start=time.perf_counter())
        try:
            ds = _first_pass(scenes, loaded, out, settings, learn, run)
        finally:
            engine.close()
    scales = corner_scales([scene for _, scene in loaded]) if settings.pool_scale else [None] * len(loaded)
    segments = hand_segments([scene for _, scene in loaded], settings)
    handed = {}
    for (si, scene), scale, (seg_kwargs, seg_block) in zip(loaded, scales, segments):
        own_scale, kwargs, block = scene.corner_scale, {}, {}
        scene = _with_scale(scene, scale)
        if ds is not None:
            scene, kwargs, block, _ = hand_back(ds, si.key, scene, settings)
        handed[si.key] = (scene, {**seg_kwargs, **kwargs}, {**_scale_block(block, scale, own_scale), **seg_block})
    return handed


def _with_scale(scene, scale):
    return scene if scale is None else replace(scene, corner_scale=scale)


def _scale_block(block: dict, scale, own_scale) -> dict:
    """A frame's ``dataset`` block with its corner scale: the crowd's (``scale``) or its own."""
    if scale is not None:  # the crowd's corner scale: a quantity of the data set read from the annotations
        block["corner_scale_px"] = {"from": "data set", "shared_by": "crowd", "sd": scale[0], "dof": scale[1]}
    elif own_scale is not None and block:
        block["corner_scale_px"] = {"from": "override", "why": "the scene's own corner scale"}
    return block


def _load_quietly(scenes: list[SceneInput], settings: BatchSettings) -> list:
    """(scene input, scene) of every scene that loads (the others fail in the pass that reads them)."""
    loaded = []
    for si in scenes:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                loaded.append((si, load_scene(si.path, classes=settings.classes or None)))
        except (SceneError, OSError, ValueError):
            continue
    return loaded


def corner_scales(scenes: list) -> list[tuple[float, float] | None]:
    """The crowd's corner scale each scene gets from the others: (sd px, degrees of freedom) pooled
    over the other scenes' objects annotated more than once (a set's 8 coordinates around their
    per-corner mean, :func:`~creference_bayes.models.metrology.corner_spread`), for the scenes
    with an object annotated once and no ``corner_scale`` of their own; None for the others. The sd
    is rounded to two significant digits (steps of at most 5 %, about its own uncertainty from a few
    hundred degrees of freedom) and the degrees of freedom to one (they only weigh the pool against
    a frame's own sets), so that a few frames more or less leave the others up to date."""
    from ...models.metrology import MIN_TARGET_SIGMA_PX, corner_spread

    own = []
    for scene in scenes:
        ss, dof = corner_spread([t.corners for t in scene.targets])
        own.append((float(ss.sum()), float(dof.sum()), scene.corner_scale is None and bool((dof == 0).any())))
    total_ss, total_dof = sum(v[0] for v in own), sum(v[1] for v in own)
    return [(max(_sig2(math.sqrt(max(total_ss - ss, 0.0) / (total_dof - dof))), MIN_TARGET_SIGMA_PX),
             float(f"{total_dof - dof:.1g}")) if needs and total_dof - dof > 0 else None
            for ss, dof, needs in own]


def segment_floors(scenes: list) -> list[dict | None]:
    """The floor of the marginal reading's prior of a segment's length each scene gets from the
    others (the data set's segment floor, :data:`~.dataset.SEGMENT_FLOOR`): ``floor`` (px,
    :func:`~creference_bayes.models.metrology.segment_floor`) fitted to the other scenes' drawn
    lengths (``segments``, at least :data:`MIN_FLOOR_SEGMENTS`) with their end points' noise
    ``noise_px`` = :data:`~creference_bayes.models.metrology.REF_LINE_FACTOR` × the crowd's corner
    scale of the other scenes (the model's own σ_line). None without. Rounded to two significant
    digits, as the corner scale (:func:`corner_scales`)."""
    from ...models.metrology import REF_LINE_FACTOR, corner_spread, segment_floor

    own = []
    for scene in scenes:
        ss, dof = corner_spread([t.corners for t in scene.targets])
        lengths = [np.linalg.norm(np.subtract(*r.line)) for r in scene.references if r.line is not None]
        own.append((ss.sum(), dof.sum(), np.histogram(np.log(np.maximum(lengths, 1e-3)), _LENGTH_BINS)[0]))
    total = [sum(v[i] for v in own) for i in range(3)]
    out = []
    for ss, dof, counts in own:
        rest_ss, rest_dof, rest = total[0] - ss, total[1] - dof, total[2] - counts
        if rest_dof <= 0 or rest_ss <= 0 or rest.sum() < MIN_FLOOR_SEGMENTS:
            out.append(None)
            continue
        noise = _sig2(REF_LINE_FACTOR * math.sqrt(rest_ss / rest_dof))
        floor = segment_floor(_LENGTH_CENTRES[rest > 0], noise, counts=rest[rest > 0])
        out.append({"floor_px": _sig2(floor), "segments": int(rest.sum()), "noise_px": noise})
    return out


#: the fewest drawn segments of the other scenes a segment floor is fitted to (:func:`segment_floors`)
MIN_FLOOR_SEGMENTS = 20
#: bins of log drawn length (px) the other scenes' segments are pooled in, 1 % wide
_LENGTH_BINS = np.arange(math.log(1e-3), math.log(1e5) + 0.01, 0.01)
_LENGTH_CENTRES = np.exp(0.5 * (_LENGTH_BINS[1:] + _LENGTH_BINS[:-1]))


def _sig2(x: float) -> float:
    return float(f"{x:.2g}")


def hand_segments(scenes: list, settings) -> list[tuple[dict, dict]]:
    """Per scene, what the crowd's segments hand its estimate (:func:`segment_floors`): the
    keyword argument ``read_floor_px`` and the ``dataset`` block's entry; nothing without
    ``settings.pool_scale`` or for a model without the option; the user's option wins (an override)."""
    from ...pipeline import MODEL_OPTIONS
    from .dataset import SEGMENT_FLOOR

    if not settings.pool_scale or "read_floor_px" not in MODEL_OPTIONS[settings.model]:
        return [({}, {}) for _ in scenes]
    if "read_floor_px" in settings.options:
        why = {"from": "override", "why": f"--option read_floor_px={settings.options['read_floor_px']:g}"}
        return [({}, {SEGMENT_FLOOR.label: why}) for _ in scenes]
    return [({}, {}) if seg is None else ({"read_floor_px": seg["floor_px"]},
                                          {SEGMENT_FLOOR.label: {"from": "data set", "shared_by": "crowd", **seg}})
            for seg in segment_floors(scenes)]


def _run_pass(scenes, out: Path, settings: BatchSettings, *, engine: Engine, time_limit, progress, on_event,
              t_start: float, transform=None, close: bool = True, dataset: dict | None = None,
              desc: str = "batch") -> BatchReport:
    """Estimate ``scenes`` into ``out`` (with the crowd's corner scale from the other scenes, then
    ``transform(KEY, scene)`` → (scene, estimate keyword arguments, dataset block, rig block), if
    given: :func:`.dataset.hand_back`); writes summary.csv and batch.json (with ``dataset``, the
    pools of all frames, :meth:`.dataset.DataSet.summary`) whatever ends the run; closes the engine
    if ``close``."""

    out.mkdir(parents=True, exist_ok=True)
    ident = settings.to_dict()
    # From here on, whatever ends the run (an interrupt while the scenes are read, while they
    # run, a bug), the folder gets its summary.csv and batch.json.
    status = {si.key: "not run" for si in scenes}
    errors: dict[str, str] = {}
    bar = runner = None
    try:
        todo = _prepare(scenes, out, settings, ident, status, errors, transform)
        if on_event:
            for key in (k for k, s in status.items() if s in ("failed", "skipped")):
                on_event(key, status[key])
        n_invalid = sum(s == "failed" for s in status.values())
        bar = progress_bar(len(todo) + n_invalid, n_invalid, progress, desc)
        runner = Runner(out, engine, ident, time_limit, status, errors, bar, on_event)
        runner.run(todo)
    finally:
        if bar is not None:
            bar.close()
        interrupted = any(s == "not run" for s in status.values())
        if close or interrupted:
            engine.close(abandon=interrupted or (runner is not None and bool(runner.abandoned)))
        report = _write_folder(out, scenes, ident, status, errors, engine, t_start, time_limit,
                               runner.n_targets if runner is not None else 0, dataset)
    return report


def _write_folder(out: Path, scenes, ident: dict, status: dict, errors: dict, engine: Engine, t_start: float,
                  time_limit, n_targets: int = 0, dataset: dict | None = None) -> BatchReport:
    """The folder's summary.csv and batch.json for the scenes' ``status`` (whatever ended the run)."""
    from .summary import summary_rows, write_summary

    report = BatchReport(status=status, errors=errors, seconds=time.perf_counter() - t_start,
                         engine=engine.describe(), n_targets=n_targets, dataset=dataset or {})
    rows = summary_rows(out, scenes, report)
    report.not_converged = list(dict.fromkeys(r["scene"] for r in rows if r["converged"] == "false"))
    write_summary(out, scenes, report, rows)
    atomic_write_json(out / "batch.json", {
        "format": BATCH_FORMAT, "creference_version": __version__, "settings": ident,
        "engine": report.engine, "time_limit_s": time_limit, "seconds": round(report.seconds, 3),
        **({"dataset": dataset} if dataset else {}),
        "scenes": [{"key": si.key, "source": str(si.path.resolve()), "status": status[si.key],
                    **({"error": errors[si.key]} if si.key in errors else {})} for si in scenes]})
    return report


def _prepare(scenes, out: Path, settings: BatchSettings, ident: dict, status: dict, errors: dict,
             transform=None) -> deque:
    """Read every scene: record the invalid ones, give the others the crowd's corner scale of the
    rest (``settings.pool_scale``, :func:`corner_scales`), skip the up-to-date ones, queue the others."""
    loaded = []
    for si in scenes:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)  # the result reports them
                scene = load_scene(si.path, classes=settings.classes or None)
            # the copy carries the classes file's priors its targets use: plot, advise, labels read it alone
            loaded.append((si, with_classes(scene, settings.classes)))
        except (SceneError, OSError, ValueError) as exc:
            errors[si.key] = one_line(exc)
            status[si.key] = "failed"
            record_error(layout(out, si.key), si, "load", errors[si.key])
    scales = corner_scales([scene for _, scene in loaded]) if settings.pool_scale else [None] * len(loaded)
    segments = hand_segments([scene for _, scene in loaded], settings)
    todo = deque()
    for (si, scene), scale, (seg_kwargs, seg_block) in zip(loaded, scales, segments):
        paths = layout(out, si.key)
        own_scale = scene.corner_scale
        scene = _with_scale(scene, scale)
        kwargs, block, rig = {}, {}, None
        if transform is not None:
            scene, kwargs, block, rig = transform(si.key, scene)
        kwargs, block = {**seg_kwargs, **kwargs}, {**_scale_block(block, scale, own_scale), **seg_block}
        job_ident = ident if not kwargs else {**ident, "from_dataset": _kwargs_record(kwargs)}
        scale = shared_scale(block, settings.seed)
        if scale is not None:  # the held values' uncertainty the result carries: another scale, another result
            job_ident = {**job_ident, "shared_scale": scale}
        fingerprint = scene_fingerprint(scene)
        if up_to_date(paths, fingerprint, job_ident, settings.ground(len(scene.targets))):
            status[si.key] = "skipped"
            if not paths["scene"].exists():
                atomic_write_json(paths["scene"], scene_to_dict(scene))
            continue
        todo.append((si, {"scene": scene, "seed": derive_seed(settings.seed, fingerprint),
                          "estimate": settings.estimate_settings().replace(**kwargs), "rig": rig,
                          "dataset": block or None, "ident": job_ident, "shared_scale": scale}))
    return todo


def _kwargs_record(kwargs: dict) -> dict:
    """What a frame's estimate took from the data set beyond its scene, as its result's settings
    record it (a rerun compares them: another pool, another estimate)."""
    return {k: v.to_dict() if hasattr(v, "to_dict") else v for k, v in sorted(kwargs.items())}
