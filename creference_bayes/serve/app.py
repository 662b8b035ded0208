"""The ML backend's web app (Flask): Label Studio's protocol (``GET /health``, ``POST /setup``,
``POST /predict``, ``POST /webhook``, as its ``label-studio-ml`` SDK answers them), with the
service's checks: a token, a limit on the body's size, a 4xx with a message for every body it
cannot use (docs/serve.md)."""

from __future__ import annotations

import base64
import binascii
import hmac
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..io.annotation_tools import ConversionError
from ..io.labelstudio import loads_export
from .predictions import (Controls, RequestError, empty_prediction, estimate_view, prediction, task_scene, task_id)
from .jobs import FrameStore, Worker, task_key
from .priors import DataSetPriors

__all__ = ["ServeSettings", "create_app", "FLASK_INSTALL_HINT", "MAX_TASKS"]

FLASK_INSTALL_HINT = 'creference serve needs Flask: pip install "creference-bayes[serve]"'
#: At most this many tasks in one /predict request (Label Studio sends every selected task at once).
MAX_TASKS = 10000
#: The webhook actions that re-estimate a task's frame.
REESTIMATE = ("ANNOTATION_CREATED", "ANNOTATION_UPDATED")
#: The webhook action whose annotations leave the stored tasks (and their frames are estimated again).
DELETED = "ANNOTATIONS_DELETED"

log = logging.getLogger("creference.serve")


@dataclass(frozen=True)
class ServeSettings:
    """How the service runs.

    Attributes
    ----------
    state_dir : the service's folder (:mod:`.jobs`)
    image_root : the folder the photos are read from (None: no photo is read)
    token : the secret a request must carry (HTTP basic auth with it as the password, or
        ``Authorization: Bearer TOKEN``); None: no check
    max_body_bytes : larger requests are refused (413)
    iou_threshold : the label quality is P(IoU ≥ this)
    hdi_prob : the probability of the distance's interval
    n_draws : draws of the Laplace approximation behind a fresh frame's numbers
    seed : base seed (each frame's derives from it and the scene, as a batch's)
    background : queue a posterior for every frame /predict estimates without one
    time_budget_s : a /predict finds no more MAPs once this many seconds have passed (Label Studio
        waits 100 s): the tasks left without a stored estimate are queued for the background and
        answered with a prediction that says so
    advice_settings : :class:`~creference_bayes.workflows.advice.AdviceSettings` of the next
        request (None: the defaults)
    sampling : sampler settings of the background posterior
    """

    state_dir: Path
    image_root: Path | None = None
    token: str | None = None
    max_body_bytes: int = 16 * 2**20
    iou_threshold: float = 0.7
    hdi_prob: float = 0.9
    n_draws: int = 400
    seed: int = 0
    background: bool = True
    time_budget_s: float = 60.0
    advice_settings: Any = None
    sampling: dict | None = field(default=None)


def _authorized(header: str | None, token: str) -> bool:
    """Whether an ``Authorization`` header carries the token (basic auth's password, or a bearer
    token), compared in constant time."""
    if not header:
        return False
    scheme, _, value = header.strip().partition(" ")
    scheme, value = scheme.lower(), value.strip()
    if scheme == "basic":
        try:
            value = base64.b64decode(value, validate=True).decode("utf-8").partition(":")[2]
        except (binascii.Error, UnicodeDecodeError, ValueError):
            return False
    elif scheme not in ("bearer", "token"):
        return False
    return hmac.compare_digest(value.encode("utf-8", "surrogatepass"), token.encode("utf-8"))


def _project_id(value: Any) -> int | None:
    """The project's id from ``"ID.TIMESTAMP"`` (what Label Studio sends), a number or an object
    with ``id``; None when not given. :class:`RequestError` for anything else."""
    if isinstance(value, dict):
        value = value.get("id")
    if value is None:
        return None
    if isinstance(value, bool):
        raise RequestError(f"project: expected 'ID.TIMESTAMP' or an id, got {value!r}")
    head = str(value).split(".", 1)[0] if isinstance(value, str) else value
    try:
        pid = int(head)
    except (TypeError, ValueError, OverflowError):
        pid = -1
    if pid < 0 or pid > 2**62:
        raise RequestError(f"project: expected 'ID.TIMESTAMP' or an id, got {str(value)[:60]!r}")
    return pid


def create_app(settings: ServeSettings, *, start_worker: bool = True):
    """The Flask app of the service; its worker (:class:`~.jobs.Worker`) is ``app.extensions
    ["creference"]["worker"]``, started (and resuming the stored tasks) unless ``start_worker`` is
    False (then run queued jobs with its ``run_pending``)."""
    try:
        from flask import Flask, Response, jsonify, request
        from werkzeug.exceptions import HTTPException
    except ImportError as exc:  # pragma: no cover - the extra is not installed
        raise ImportError(FLASK_INSTALL_HINT) from exc

    store = FrameStore(settings.state_dir)
    priors = DataSetPriors.from_folder(settings.state_dir)
    if priors is not None:
        log.info("%s (read in %.1f s)", priors.describe(), priors.seconds)
    worker = Worker(store, image_root=settings.image_root, seed=settings.seed, hdi_prob=settings.hdi_prob,
                    advice_settings=settings.advice_settings, sampling=settings.sampling, priors=priors)
    app = Flask("creference_bayes.serve")
    app.config["MAX_CONTENT_LENGTH"] = int(settings.max_body_bytes)
    app.extensions["creference"] = {"store": store, "worker": worker, "settings": settings}

    def model_version() -> str:
        return f"creference-{__version__}-{store.state_tag()}"

    def body() -> dict:
        raw = request.get_data(cache=False)  # 413 beyond MAX_CONTENT_LENGTH, before it is read
        if not raw:
            raise RequestError("empty body: expected a JSON object")
        try:
            doc = loads_export(raw, "request body")
        except ConversionError as exc:
            raise RequestError(str(exc)) from None
        if not isinstance(doc, dict):
            raise RequestError(f"the body must be a JSON object, got {type(doc).__name__}")
        return doc

    @app.errorhandler(RequestError)
    def refused(exc: RequestError):
        return jsonify({"status": "error", "error": str(exc)}), exc.status

    @app.errorhandler(HTTPException)
    def http_error(exc: HTTPException):
        response = jsonify({"status": "error", "error": f"{exc.name}: {exc.description}"})
        response.status_code = exc.code or 500
        if exc.code == 401:
            response.headers["WWW-Authenticate"] = 'Basic realm="creference"'
        return response

    @app.errorhandler(Exception)
    def failed(exc: Exception):  # a bug, not the client's fault: logged, said without a traceback
        log.exception("internal error")
        said = f"internal error ({type(exc).__name__}); see the service's log"
        return jsonify({"status": "error", "error": said}), 500

    @app.before_request
    def check_token():
        if settings.token is not None and not _authorized(request.headers.get("Authorization"), settings.token):
            return Response('{"status": "error", "error": "Unauthorized: give the token (basic auth password '
                            'or Authorization: Bearer TOKEN)"}', 401,
                            {"WWW-Authenticate": 'Basic realm="creference"', "Content-Type": "application/json"})
        return None

    @app.get("/")
    @app.get("/health")
    def health():
        return jsonify({"status": "UP", "model_class": "creference", "model_version": model_version(),
                        "jobs": worker.pending()})

    @app.post("/setup")
    def setup():
        doc = body()
        pid = _project_id(doc.get("project"))
        schema = doc.get("schema", doc.get("label_config"))
        controls = Controls.from_config(schema)
        if pid is not None:
            store.put_config(pid, schema)
        if controls.box is None:
            log.warning("project %s: its labelling config has no '%s' controls; print one that has with "
                        "`creference serve --print-config`", pid, "estimate_box")
        return jsonify({"model_version": model_version()})

    @app.post("/predict")
    def predict():
        doc = body()
        tasks = doc.get("tasks")
        if not isinstance(tasks, list) or not tasks:
            raise RequestError(f"tasks: expected a non-empty list of tasks, got {str(tasks)[:60]}")
        if len(tasks) > MAX_TASKS:
            raise RequestError(f"tasks: at most {MAX_TASKS} tasks per request, got {len(tasks)}", 413)
        pid = _project_id(doc.get("project"))
        config = doc.get("label_config")
        controls = Controls.from_config(config if config is not None else store.config(pid))
        keys = [task_key(pid, task_id(task)) for task in tasks]
        alone = [task_scene(task, settings.image_root) for task in tasks]  # every task checked before one is stored
        for key, task in zip(keys, tasks):
            store.put_task(key, task)
        frames = [worker.frame(key, task, alone=frame) for key, task, frame in zip(keys, tasks, alone)]
        version, until = model_version(), time.monotonic() + settings.time_budget_s
        return jsonify({"results": [_predict_one(task, frame, controls, version, until)
                                    for task, frame in zip(tasks, frames)], "model_version": version})

    def _predict_one(task: dict, frame, controls: Controls, version: str, until: float) -> dict:
        from .. import estimate
        from ..workflows.batch import derive_seed

        if frame is None:
            return empty_prediction(controls, version, "no dimension lines yet: nothing to estimate")
        key = frame.key  # the frame's: the first task of its photo
        seed = derive_seed(settings.seed, frame.fingerprint)
        result = store.result(key, frame)
        if result is None and time.monotonic() > until:  # past the budget: the background estimates it
            worker.submit(key)
            return empty_prediction(controls, version, "queued: this frame is being estimated in the background "
                                                       "(ask again)")
        if result is None:
            try:
                result = estimate(frame.scene, posterior=False, seed=seed, hdi_prob=settings.hdi_prob, **frame.kwargs)
            except ValueError as exc:  # a scene the model refuses (its message names the value)
                raise RequestError(f"task {task['id']}: {' '.join(str(exc).split())}", 422) from None
            if settings.background:
                worker.submit(key)
        view = estimate_view(frame.scene, result, threshold=settings.iou_threshold, hdi_prob=settings.hdi_prob,
                             n_draws=settings.n_draws, seed=seed, dataset=frame.dataset, base_seed=settings.seed)
        advice = store.advice(key, frame.fingerprint)
        said = None
        if advice is not None:
            said = advice["request"] or f"none ({advice['reason']})"
        elif worker.busy(key):
            said = "being computed in the background (ask again)"
        return prediction(frame.scene, view, controls, version, said, frame.dataset)

    @app.post("/webhook")
    def webhook():
        doc = body()
        action = doc.get("action")
        if not isinstance(action, str) or not action:
            raise RequestError(f"action: expected the event's name (text), got {str(action)[:60]}")
        if action == DELETED:
            return _deleted(doc)
        if action not in REESTIMATE:
            return jsonify({"status": "Unknown event", "action": action[:60]}), 200
        pid = _project_id(doc.get("project"))
        task, annotation = doc.get("task"), doc.get("annotation")
        tid = task_id(task)
        if not isinstance(annotation, dict):
            raise RequestError(f"annotation: expected an object, got {type(annotation).__name__}")
        aid = annotation.get("id")
        if isinstance(aid, bool) or not isinstance(aid, (int, str)):
            raise RequestError(f"annotation.id: expected an id, got {str(aid)[:60]}")
        key = task_key(pid, tid)
        if isinstance(doc.get("project"), dict) and isinstance(doc["project"].get("label_config"), str) \
                and pid is not None:
            store.put_config(pid, doc["project"]["label_config"])
        stored = {**(store.task(key) or {}), "id": tid, "data": task["data"]}
        others = [a for a in stored.get("annotations", []) if isinstance(a, dict) and a.get("id") != aid]
        task_scene({**stored, "annotations": others + [annotation]}, settings.image_root)  # 4xx before storing
        store.put_annotation(key, task, annotation)
        worker.submit(store.members(key)[0])
        return jsonify({"status": "ok", "result": {"queued": key}}), 201

    def _deleted(doc: dict):
        """``ANNOTATIONS_DELETED``: the annotations (``[{"id": …}, …]``) leave their stored tasks,
        whose frames are estimated again."""
        pid = _project_id(doc.get("project"))
        gone = doc.get("annotations")
        if not isinstance(gone, list) or not all(isinstance(a, dict) and isinstance(a.get("id"), (int, str))
                                                 and not isinstance(a.get("id"), bool) for a in gone):
            raise RequestError(f"annotations: expected a list of {{\"id\": …}}, got {str(gone)[:60]}")
        changed = store.drop_annotations(pid, [a["id"] for a in gone])
        for key in changed:
            worker.submit(store.members(key)[0])
        return jsonify({"status": "ok", "result": {"queued": changed}}), 201

    if start_worker:
        worker.start()
    return app
