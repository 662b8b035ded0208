"""A Label Studio task → its frame's scene → the estimate drawn as a Label Studio prediction
(docs/serve.md). No web framework here: :mod:`.app` wires these into the ML backend's routes.

A task is one frame: its scene is made by the importer of ``creference import label-studio``
(:func:`~creference_bayes.io.labelstudio.scenes_from_label_studio`) from the task's ``data`` and
its annotations. The photo is read (horizon, EXIF focal length) only from inside the configured
image root: a task that names a file outside it is refused (:class:`RequestError`, 403), and
without a root no image is read at all.

The prediction (:func:`prediction`) draws in the task's image coordinates (percent of the image
size, as Label Studio stores regions), with the controls of :func:`serve_config`: each target's
projected 3D box as one polygon tracing its twelve edges, a per-box text (the distance, its
interval, the label quality P(IoU ≥ T)) and a summary text of the frame (how it was estimated, the
next request). Its ``score`` is the frame's label quality: the lowest P(IoU ≥ T) of its targets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from ..io.annotation_tools import ConversionError
from ..io.labelstudio import label_studio_config, scenes_from_label_studio, url_path
from ..io.result import hdi
from ..io.scene import Scene, SceneError, parse_quietly, scene_fingerprint
from ..models.contract import O_X, O_Z

__all__ = ["RequestError", "ESTIMATE_BOX", "ESTIMATE_TEXT", "ESTIMATE_SUMMARY", "ESTIMATE_LABEL", "WIREFRAME",
           "serve_config", "Controls", "Frame", "task_id", "task_scene", "tasks_scene", "EstimateView", "estimate_view",
           "object_text", "dataset_lines", "summary_lines", "prediction", "empty_prediction"]

#: The controls :func:`serve_config` adds to a shipped config: the boxes (polygons), the per-box
#: text, the frame's summary text, and the boxes' label.
ESTIMATE_BOX, ESTIMATE_TEXT, ESTIMATE_SUMMARY, ESTIMATE_LABEL = "estimate_box", "estimate_text", "estimate_summary", \
    "estimate"
#: A projected box as one closed polygon through its 8 vertices (bottom face 0–3, then the top 4–7,
#: :func:`~creference_bayes.core.geometry.box_vertices`) that runs along all 12 edges.
WIREFRAME = (0, 1, 2, 3, 0, 4, 5, 1, 5, 6, 2, 6, 7, 3, 7, 4)


class RequestError(ValueError):
    """A request the service refuses: ``status`` (4xx) and the message said to the client."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def serve_config(lines: str = "keypoints") -> str:
    """A shipped labelling config (:func:`~creference_bayes.io.labelstudio.label_studio_config`)
    with the controls the service draws its estimate with (the importer ignores them)."""
    base = label_studio_config(lines)
    block = (resources.files("creference_bayes") / "data" / "label_studio_estimates.xml").read_text("utf-8")
    head, sep, tail = base.rpartition("</View>")
    return head + block + sep + tail


@dataclass(frozen=True)
class Controls:
    """Where a project's labelling config lets the service draw: the image's name and the names of
    the estimate controls it has (None: the config lacks it, and that part is not drawn)."""

    image: str = "image"
    box: str | None = None
    text: str | None = None
    summary: str | None = None

    @classmethod
    def from_config(cls, config: Any) -> "Controls":
        """The controls of a labelling config (XML text; read as untrusted input: no DTD, no
        entities). :class:`RequestError` (400) for text that is not such a config."""
        import defusedxml
        import defusedxml.ElementTree as DET
        from xml.etree.ElementTree import ParseError

        if not isinstance(config, str) or not config.strip():
            raise RequestError(f"label_config: expected the project's labelling config (XML text), got "
                               f"{_short(config)}")
        try:
            root = DET.fromstring(config, forbid_dtd=True)
        except (ParseError, defusedxml.DefusedXmlException, ValueError) as exc:
            raise RequestError(f"label_config: not a labelling config ({exc})") from None
        images = [el.get("name") for el in root.iter("Image") if el.get("name")]
        if not images:
            raise RequestError("label_config: no <Image name=…> tag (the shipped configs show the photo as 'image')")
        found = {(el.tag, el.get("name")) for el in root.iter()}
        return cls(image=images[0], box=ESTIMATE_BOX if ("PolygonLabels", ESTIMATE_BOX) in found else None,
                   text=ESTIMATE_TEXT if ("TextArea", ESTIMATE_TEXT) in found else None,
                   summary=ESTIMATE_SUMMARY if ("TextArea", ESTIMATE_SUMMARY) in found else None)


def _short(value: Any, n: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= n else text[:n] + "…"


@dataclass(frozen=True)
class Frame:
    """A task's frame: its scene, the scene's fingerprint (what a stored result is checked
    against) and the importer's notes; with a data set's priors (:mod:`.priors`), the scene as
    the data set hands it, the estimate's keyword arguments (``kwargs``), the result's ``dataset``
    and ``rig`` blocks, and a fingerprint that covers them."""

    scene: Scene
    fingerprint: str
    notes: tuple[str, ...] = ()
    kwargs: dict = field(default_factory=dict)
    dataset: dict | None = None
    rig: dict | None = None
    #: the frame's key in the service's folder (its first task's) and the keys of all its tasks
    key: str | None = None
    members: tuple[str, ...] = ()


def task_id(task: Any) -> int:
    """A task's Label Studio id (:class:`RequestError` when it has none)."""
    if not isinstance(task, dict):
        raise RequestError(f"a task must be an object, got {type(task).__name__}")
    tid = task.get("id")
    if isinstance(tid, bool) or not isinstance(tid, int) or tid < 0:
        raise RequestError(f"task id: expected a whole number >= 0, got {_short(tid)}")
    if not isinstance(task.get("data"), dict):
        raise RequestError(f"task {tid}: 'data' is missing or not an object")
    return tid


def task_scene(task: dict, image_root: str | Path | None = None) -> Frame | None:
    """The frame of a Label Studio task (with its annotations) alone, or None when no annotation
    draws anything yet. :class:`RequestError`: 422 for a task the importer refuses (its message
    names the task, annotation and region), 403 for an image outside ``image_root``."""
    return tasks_scene([task], image_root)


def tasks_scene(tasks: list[dict], image_root: str | Path | None = None) -> Frame | None:
    """The frame of the tasks of one photo (each with its annotations), joined into one scene as
    ``creference import label-studio`` joins them; the photo is the first task's. None when no
    annotation draws anything yet; :class:`RequestError` as :func:`task_scene` (422 also for tasks
    that cannot be joined: their image sizes disagree, a target drawn in two of them)."""
    tid = task_id(tasks[0])
    data = tasks[0]["data"]
    try:
        report = scenes_from_label_studio([{**t, "data": {k: v for k, v in t["data"].items() if k != "image_path"}}
                                           for t in tasks])
    except ConversionError as exc:
        raise RequestError(str(exc), 422) from None
    if report.errors:
        raise RequestError(str(report.errors[0]), 422)
    if not report.scenes:
        return None
    d = dict(report.scenes[0].scene)
    path = _image_file(data, image_root, f"task {tid}")
    d["image"] = {k: v for k, v in d["image"].items() if k != "path"}  # the photo only from inside the root
    if path is not None:
        d["image"]["path"] = str(path)
    try:
        scene = parse_quietly(d)
    except SceneError as exc:
        raise RequestError(f"task {tid}: {exc}", 422) from None
    return Frame(scene, scene_fingerprint(scene), tuple(report.notes))


def _image_file(data: dict, image_root, where: str) -> Path | None:
    """The photo a task names (``data.image_path``, else the local file of ``data.image``) inside
    ``image_root``, or None (no root, no such name, no such file). 403 for a name that leads
    outside the root (``..``, an absolute path elsewhere, a link out of it)."""
    if image_root is None:
        return None
    names = []
    if isinstance(data.get("image_path"), str) and data["image_path"]:
        names.append(data["image_path"])
    if isinstance(data.get("image"), str) and data["image"]:
        try:
            names.append(url_path(data["image"], where))
        except ConversionError:
            pass
    try:
        return _inside(Path(image_root).resolve(), names, where)
    except OSError as exc:  # a name no file system takes (too long, …)
        raise RequestError(f"{where}: image {_short(names[0])}: {exc.strerror or exc}", 422) from None


def _inside(root: Path, names: list[str], where: str) -> Path | None:
    for name in names:
        if "\0" in name:
            raise RequestError(f"{where}: image name {_short(name)} holds a NUL character", 422)
        candidate = (root / name).resolve()  # an absolute name replaces the root: checked below
        if candidate != root and root not in candidate.parents:
            raise RequestError(f"{where}: image {_short(name)} is outside the image root; refused", 403)
        if candidate.is_file():
            return candidate
    for name in names:  # as the importer looks: the file name alone in the root
        candidate = root / PurePosixPath(name).name
        if PurePosixPath(name).name and candidate.resolve().parent == root and candidate.is_file():
            return candidate
    return None


@dataclass(frozen=True)
class EstimateView:
    """What the prediction shows of an estimate of a frame.

    Attributes
    ----------
    camera : (5,) MAP camera;  objects : (m, 7) MAP objects (``models.contract`` order)
    distance_m : (m,) MAP ground distances, metres;  interval_m : (m, 2) their ``hdi_prob`` HDIs
    p_iou : (m,) label quality P(IoU ≥ ``threshold``) of each target's MAP box
    source : ``"posterior"`` (sampled draws) or ``"laplace"`` (the Laplace approximation at the MAP)
    threshold, hdi_prob : the IoU threshold and the interval's probability
    converged : the sampler's verdict (None for the Laplace approximation)
    """

    camera: np.ndarray
    objects: np.ndarray
    distance_m: np.ndarray
    interval_m: np.ndarray
    p_iou: np.ndarray
    source: str
    threshold: float
    hdi_prob: float
    converged: bool | None = None

    @property
    def score(self) -> float:
        """The frame's label quality: its weakest label's P(IoU ≥ T)."""
        return float(np.min(self.p_iou))


def estimate_view(scene: Scene, result, *, threshold: float = 0.7, hdi_prob: float = 0.9, n_draws: int = 400,
                  seed=0, dataset: dict | None = None, base_seed: int = 0) -> EstimateView:
    """The view of ``result`` (a :class:`~creference_bayes.pipeline.Result` of ``scene``): its kept
    posterior draws, else ``n_draws`` draws of the Laplace approximation at its MAP
    (:func:`~creference_bayes.pipeline.result_draws`); the label quality as ``creference labels``
    states it (the MAP box against the draws' boxes in the labels' frame). A frame whose focal
    length the data set held (its ``dataset`` block) has its Laplace draws carry the held value's
    shared uncertainty as a batch's results do (kept draws carry it already;
    :func:`~creference_bayes.workflows.batch.dataset.shared_log_k`, ``base_seed`` the service's)."""
    from ..pipeline import map_state, rebuild_model, result_draws
    from ..workflows.batch.dataset import scale_draws, shared_log_k
    from ..workflows.labels.kitti import kitti_poses
    from ..workflows.labels.quality import label_quality

    d = result.to_dict()
    model = result.model if result.model is not None else rebuild_model(d, scene)
    cams, objs, source = result_draws(d, model, n=n_draws, seed=seed)
    log_k = shared_log_k(dataset, base_seed, len(cams)) if source == "laplace" else None
    if log_k is not None:
        cams, objs = scale_draws(cams, objs, log_k)
    camera, objects = map_state(d)
    box = kitti_poses(scene, camera[None], objects[None])[0]
    boxes = kitti_poses(scene, cams, objs)
    p = np.array([label_quality(box[i], boxes[:, i], (threshold,)).p_iou[threshold] for i in range(len(box))])
    dist = np.hypot(objs[..., O_X], objs[..., O_Z])
    return EstimateView(camera, objects, np.hypot(objects[:, O_X], objects[:, O_Z]), hdi(dist, hdi_prob), p, source,
                        threshold, hdi_prob, result.converged if source == "posterior" else None)


def _percent(uv: np.ndarray, width: int, height: int) -> list[list[float]]:
    return [[100.0 * float(u) / width, 100.0 * float(v) / height] for u, v in uv]


def object_text(scene: Scene, view: EstimateView, i: int) -> str:
    """One target's line: its distance, interval and label quality."""
    lo, hi = view.interval_m[i]
    return (f"{scene.targets[i].id}: {view.distance_m[i]:.2f} m "
            f"({100 * view.hdi_prob:g} % interval {lo:.2f}–{hi:.2f} m), "
            f"P(IoU ≥ {view.threshold:g}) {view.p_iou[i]:.2f}")


#: How the frame summary names each quantity a frame took: label → (name, unit)
_NAMES = {"focal_length_px": ("focal length", " px"), "height_m": ("camera height", " m"),
          "pitch_deg": ("pitch", "°"), "roll_deg": ("roll", "°"), "ref_scale": ("reference scale", ""),
          "distance_m": ("target distances", " m"), "corner_scale_px": ("corner scale", " px")}


def dataset_lines(block: dict | None) -> list[str]:
    """The frame summary's lines of a ``dataset`` block: what the frame took from the data set and
    how sure that was (the sd of the prior it was handed: a log quantity's in percent, an angle's
    in degrees), and what it did not take and why (one line per reason)."""
    lines, own = [], {}
    for label, entry in (block or {}).items():
        name, unit = _NAMES.get(label, (label, ""))
        group = entry.get("group")
        where = {"camera": f"camera {group}", "crowd": "the crowd", "setting": f"setting {group}"}.get(
            entry.get("shared_by"), group)
        if entry.get("from") != "data set":
            own.setdefault(entry.get("why"), []).append(name)
        elif "median" in entry:
            sd = math.hypot(entry["log_sd"], entry.get("spread_log_sd", 0.0))
            lines.append(f"{name} from the data set: {'median ' if label == 'distance_m' else ''}"
                         f"{entry['median']:.4g}{unit} ± {100 * sd:.2g} % ({where}, {entry['frames']} frames)")
        elif "mean" in entry:
            sd = math.hypot(entry["sd"], entry.get("spread_sd", 0.0))
            lines.append(f"{name} from the data set: {entry['mean']:.2f}{unit} ± {sd:.2g}{unit} "
                         f"({where}, {entry['frames']} frames)")
        else:  # the corner scale
            lines.append(f"{name} from the data set: {entry['sd']:.2g}{unit} ({where})")
    return lines + [f"{', '.join(names)}: not from the data set ({why})" for why, names in own.items()]


def summary_lines(scene: Scene, view: EstimateView, next_request: str | None,
                  dataset: dict | None = None) -> list[str]:
    """The frame's summary: its label quality, how it was estimated (with the data set's priors it
    took, :func:`dataset_lines`), the next request."""
    low = int(np.argmin(view.p_iou))
    how = ("MAP with the Laplace approximation (the posterior is being sampled in the background)"
           if view.source == "laplace" else
           f"posterior draws{'' if view.converged is not False else ' (the sampler did not converge)'}")
    lines = [f"label quality: lowest P(IoU ≥ {view.threshold:g}) {view.p_iou[low]:.2f} ({scene.targets[low].id}) "
             f"of {len(scene.targets)} target{'s' if len(scene.targets) != 1 else ''}",
             f"estimate: {how}", *dataset_lines(dataset)]
    lines.append(f"next request: {next_request}" if next_request else "next request: not known yet")
    return lines


def prediction(scene: Scene, view: EstimateView, controls: Controls, model_version: str,
               next_request: str | None = None, dataset: dict | None = None) -> dict:
    """The Label Studio prediction of a frame's estimate (module docstring): regions in the task's
    image coordinates (percent), ``score`` the frame's label quality."""
    from ..models.boxes import image_boxes

    w, h = scene.image_width, scene.image_height
    common = {"to_name": controls.image, "original_width": w, "original_height": h, "image_rotation": 0}
    result = []
    for i, t in enumerate(scene.targets):
        rid = f"estimate_{i}"
        uv = image_boxes(view.camera[None], view.objects[i][None], scene.principal_point)[0]
        if controls.box is not None and np.all(np.isfinite(uv)):
            result.append({"id": rid, "from_name": controls.box, "type": "polygonlabels", **common,
                           "value": {"points": _percent(uv[list(WIREFRAME)], w, h), "closed": True,
                                     "polygonlabels": [ESTIMATE_LABEL]}})
            if controls.text is not None:
                result.append({"id": rid, "from_name": controls.text, "type": "textarea", **common,
                               "value": {"text": [object_text(scene, view, i)]}})
    if controls.summary is not None:
        result.append({"id": "estimate_summary", "from_name": controls.summary, "type": "textarea", **common,
                       "value": {"text": summary_lines(scene, view, next_request, dataset)}})
    return {"model_version": model_version, "score": round(view.score, 6), "result": result}


def empty_prediction(controls: Controls, model_version: str, why: str) -> dict:
    """The prediction of a task with nothing to estimate yet: no region, no score, ``why`` as its
    summary."""
    result = [] if controls.summary is None else [
        {"id": "estimate_summary", "from_name": controls.summary, "to_name": controls.image, "type": "textarea",
         "value": {"text": [why]}}]
    return {"model_version": model_version, "result": result}
