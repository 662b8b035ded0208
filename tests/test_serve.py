"""``creference serve``, the Label Studio ML backend (docs/serve.md), through Flask's test client:
the protocol's shapes, predictions that reproject onto the estimate's MAP, the token, the body
limit, the image root, malformed bodies, and the webhook's job kept on disk."""

import base64
import copy
import json
import logging

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import creference_bayes as cb
from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.io.labelstudio import label_studio_task
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.models.boxes import image_boxes
from creference_bayes.pipeline import map_state
from creference_bayes.serve.app import ServeSettings, create_app
from creference_bayes.serve.predictions import WIREFRAME, serve_config, task_scene
from creference_bayes.workflows.advice import AdviceSettings

from fuzz_strategies import VALUES, fuzz_settings

CONFIG = serve_config("vectors")


def _scene(n_objects=2, seed=1):
    return scene_to_dict(parse_scene(simulate_scene(seed, tier="high", n_objects=n_objects, n_references=3,
                                                    n_target_annotations=3)))


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.fixture(scope="module")
def task(scene):
    return label_studio_task(scene, task_id=5, lines="vectors")


def _app(tmp_path, **kw):
    kw.setdefault("background", False)
    return create_app(ServeSettings(state_dir=tmp_path / "state", **kw), start_worker=False)


@pytest.fixture
def client(tmp_path):
    return _app(tmp_path).test_client()


def _predict(client, tasks, **kw):
    return client.post("/predict", json={"tasks": tasks, "project": "3.1700000000", "label_config": CONFIG, **kw})


def test_health_setup_and_predict_answer_label_studios_shapes(client, task):
    health = client.get("/health")
    assert health.status_code == 200 and health.json["status"] == "UP"
    setup = client.post("/setup", json={"project": "3.1700000000", "schema": CONFIG, "hostname": "http://x",
                                        "access_token": "secret", "extra_params": None})
    assert setup.status_code == 200 and setup.json["model_version"].startswith("creference-")
    r = _predict(client, [task])
    assert r.status_code == 200, r.json
    (pred,) = r.json["results"]
    assert pred["model_version"] == setup.json["model_version"]
    assert 0.0 <= pred["score"] <= 1.0
    kinds = [x["type"] for x in pred["result"]]
    assert kinds == ["polygonlabels", "textarea"] * 2 + ["textarea"]
    for x in pred["result"]:
        assert x["to_name"] == "image" and x["from_name"] in ("estimate_box", "estimate_text", "estimate_summary")
    texts = [x["value"]["text"] for x in pred["result"] if x["type"] == "textarea"]
    assert all("m (90 % interval" in t[0] and "P(IoU ≥ 0.7)" in t[0] for t in texts[:2])
    summary = " ".join(texts[-1])
    assert "Laplace approximation" in summary and f"{pred['score']:.2f}" in summary
    # the score is the weakest label's quality, each stated in its box's text
    p = [float(t[0].rsplit(" ", 1)[1]) for t in texts[:2]]
    assert pred["score"] == pytest.approx(min(p), abs=0.006)
    # another event than an annotation's: answered as the SDK does, nothing queued
    other = client.post("/webhook", json={"action": "PROJECT_UPDATED", "project": {"id": 3}})
    assert other.status_code == 200 and other.json["status"] == "Unknown event"


def test_predictions_reproject_onto_the_estimates_map(client, task, scene):
    (pred,) = _predict(client, [task]).json["results"]
    boxes = [x for x in pred["result"] if x["type"] == "polygonlabels"]
    result = cb.estimate(scene, posterior=False, seed=0)
    camera, objects = map_state(result)
    w, h = scene["image"]["width"], scene["image"]["height"]
    assert len(boxes) == len(objects) == 2
    for i, box in enumerate(boxes):
        assert box["original_width"] == w and box["original_height"] == h
        got = np.array(box["value"]["points"]) / 100.0 * [w, h]
        want = image_boxes(camera[None], objects[i][None], scene["principal_point"] if "principal_point" in scene
                           else [w / 2, h / 2])[0][list(WIREFRAME)]
        assert np.max(np.abs(got - want)) < 0.5


def test_config_without_the_estimate_controls_gets_the_score_only(client, task):
    from creference_bayes.io.labelstudio import label_studio_config

    r = _predict(client, [task], label_config=label_studio_config("vectors"))
    (pred,) = r.json["results"]
    assert r.status_code == 200 and pred["result"] == [] and 0 <= pred["score"] <= 1


def test_a_task_without_annotations_has_nothing_to_estimate(client, task):
    r = _predict(client, [{**task, "annotations": []}])
    (pred,) = r.json["results"]
    assert r.status_code == 200 and "score" not in pred
    assert pred["result"][0]["value"]["text"] == ["no dimension lines yet: nothing to estimate"]


def test_the_token_is_required_when_set(tmp_path):
    c = _app(tmp_path, token="s3cret").test_client()
    assert c.get("/health").status_code == 401
    assert c.get("/health", headers={"Authorization": "Bearer wrong"}).status_code == 401
    bad = base64.b64encode(b"user:wrong").decode()
    assert c.get("/health", headers={"Authorization": f"Basic {bad}"}).status_code == 401
    good = base64.b64encode(b"labelstudio:s3cret").decode()
    assert c.get("/health", headers={"Authorization": f"Basic {good}"}).status_code == 200
    assert c.get("/health", headers={"Authorization": "Bearer s3cret"}).status_code == 200
    r = c.post("/predict", json={"tasks": []})
    assert r.status_code == 401 and "token" in r.json["error"]


def test_an_oversized_body_is_refused_with_413(tmp_path, task):
    c = _app(tmp_path, max_body_bytes=2000).test_client()
    r = c.post("/predict", data=json.dumps({"tasks": [task], "label_config": CONFIG}),
               content_type="application/json")
    assert r.status_code == 413 and "error" in r.json


def test_no_path_outside_the_image_root_is_read(tmp_path, task):
    root = tmp_path / "photos"
    root.mkdir()
    (tmp_path / "secret.png").write_bytes(b"not yours")
    (root / "street.png").write_bytes(b"")
    c = _app(tmp_path, image_root=root).test_client()
    for data in ({"image_path": "../secret.png"}, {"image_path": str(tmp_path / "secret.png")},
                 {"image": "/data/local-files/?d=../secret.png"}):
        t = copy.deepcopy(task)
        t["data"].update(data)
        r = _predict(c, [t])
        assert r.status_code == 403 and "outside the image root" in r.json["error"], data
    long = copy.deepcopy(task)
    long["data"]["image_path"] = "a" * 5000
    assert _predict(c, [long]).status_code == 422
    inside = copy.deepcopy(task)
    inside["data"]["image_path"] = "street.png"
    assert task_scene(inside, root).scene.image_path == root.resolve() / "street.png"
    assert task_scene(inside, None).scene.image_path is None  # without a root no photo is read


# ------------------------------------------------------------------------------------------------
# malformed bodies: each a 4xx with a message, never a 500


def _not(kind):
    return VALUES.filter(lambda v: not isinstance(v, kind))


@st.composite
def bad_bodies(draw, task_json):
    """(route, body bytes) of a request the service cannot use."""
    task = json.loads(task_json)
    route = draw(st.sampled_from(["/predict", "/webhook"]))
    good = ({"tasks": [task], "project": "3.1", "label_config": CONFIG} if route == "/predict" else
            {"action": "ANNOTATION_CREATED", "project": {"id": 3}, "task": {k: task[k] for k in ("id", "data")},
             "annotation": task["annotations"][0]})
    how = draw(st.sampled_from(["truncated", "not an object", "envelope", "task", "region", "deleted"]))
    if how == "deleted":  # the ids of deleted annotations, not as a list of {"id": …}
        def valid(v):
            return isinstance(v, list) and all(isinstance(a, dict) and isinstance(a.get("id"), (int, str))
                                               and not isinstance(a.get("id"), bool) for a in v)
        bad = draw(st.one_of(VALUES, st.lists(st.dictionaries(st.just("id"), VALUES), max_size=3)).filter(
            lambda v: not valid(v)))
        return "/webhook", json.dumps({"action": "ANNOTATIONS_DELETED", "project": {"id": 3},
                                       "annotations": bad}).encode()
    if how == "truncated":  # no prefix of a JSON object is JSON
        text = json.dumps(good)
        return route, text[:draw(st.integers(0, len(text) - 1))].encode()
    if how == "not an object":
        return route, json.dumps(draw(_not(dict))).encode()
    body = copy.deepcopy(good)
    ann = task["annotations"][0] if route == "/predict" else body["annotation"]
    if route == "/predict":
        t = body["tasks"][0]
        ann = t["annotations"][0]
        choice = {"envelope": ["tasks", "label_config"], "task": ["task", "id", "data", "annotations"],
                  "region": ["value", "type", "points"]}[how]
    else:
        t = body["task"]
        ann = body["annotation"]
        choice = {"envelope": ["action", "task"], "task": ["id", "data", "annotation", "annotation id"],
                  "region": ["value", "type", "points"]}[how]
    what = draw(st.sampled_from(choice))
    region = ann["result"][0]
    if what == "tasks":
        body["tasks"] = draw(VALUES.filter(lambda v: not (isinstance(v, list) and v)))
    elif what == "label_config":
        body["label_config"] = draw(st.one_of(_not(str), st.text(max_size=20).filter(lambda s: "<" not in s)))
    elif what == "task":
        if route == "/predict":
            body["tasks"][draw(st.integers(0, 0))] = draw(_not(dict))
        else:
            body["task"] = draw(_not(dict))
    elif what == "action":
        body["action"] = draw(st.one_of(_not(str), st.just("")))
    elif what == "id":
        t["id"] = draw(st.one_of(VALUES.filter(lambda v: isinstance(v, bool) or not isinstance(v, int)),
                                 st.integers(max_value=-1)))
    elif what == "data":
        t["data"] = draw(_not(dict))
    elif what == "annotations":
        t["annotations"] = draw(VALUES.filter(lambda v: v is not None and not isinstance(v, list)))
    elif what == "annotation":
        body["annotation"] = draw(_not(dict))
    elif what == "annotation id":
        body["annotation"]["id"] = draw(st.one_of(st.just(None), st.booleans(), st.floats(), st.lists(st.none())))
    elif what == "value":
        region["value"] = draw(_not(dict))
    elif what == "type":
        region["type"] = draw(_not(str))
    else:  # the target line's vertices
        region["value"]["vertices"] = draw(_not(list))
    return route, json.dumps(body).encode()


@pytest.fixture(scope="module")
def fuzz_client(tmp_path_factory):
    return create_app(ServeSettings(state_dir=tmp_path_factory.mktemp("fuzz"), background=False),
                      start_worker=False).test_client()


@pytest.fixture(scope="module")
def task_json(task):
    return json.dumps(task)


def test_malformed_bodies_get_a_4xx_with_a_message(fuzz_client, task_json, caplog):
    seen = []

    @fuzz_settings(200)
    @given(data=st.data())
    def check(data):
        route, raw = data.draw(bad_bodies(task_json))
        r = fuzz_client.post(route, data=raw, content_type="application/json")
        seen.append(r.status_code)
        assert 400 <= r.status_code < 500, (route, raw[:300], r.get_data(as_text=True)[:300])
        assert r.json["error"] and "Traceback" not in r.get_data(as_text=True)

    with caplog.at_level(logging.ERROR, logger="creference.serve"):
        check()
    assert len(seen) == 200 and not [rec for rec in caplog.records if rec.levelno >= logging.ERROR]


# ------------------------------------------------------------------------------------------------
# the webhook's job: on disk, used by the next /predict, kept across a restart

FAST = dict(sampling={"min_ess": 100, "max_steps": 3000}, advice_settings=AdviceSettings(n_draws=60, n_futures=10,
                                                                                            iou_pairs=4))


def test_webhook_job_lands_on_disk_and_the_next_predict_answers_from_it(tmp_path, monkeypatch):
    one = label_studio_task(_scene(1, seed=3), task_id=9, lines="vectors")
    app = _app(tmp_path, **FAST)
    c, worker = app.test_client(), app.extensions["creference"]["worker"]
    hook = {"action": "ANNOTATION_CREATED", "project": {"id": 3, "label_config": CONFIG},
            "task": {"id": 9, "data": one["data"]}}
    for ann in one["annotations"]:
        r = c.post("/webhook", json={**hook, "annotation": ann})
        assert r.status_code == 201 and r.json["result"]["queued"] == "p3_t9"
    assert worker.busy("p3_t9")
    before = c.get("/health").json
    worker.run_pending()  # one job for the task, with every annotation the webhooks brought
    after = c.get("/health").json
    assert before["jobs"] == 1 and after["jobs"] == 0
    assert after["model_version"] != before["model_version"]  # Label Studio asks again for newer predictions
    state = tmp_path / "state"
    result = json.loads((state / "results" / "p3_t9.json").read_text())
    advice = json.loads((state / "advice" / "p3_t9.json").read_text())
    assert result["scene_id"]["sha256"] == advice["scene_sha256"] and result["draws"]
    assert advice["seconds"]["posterior"] > 0 and advice["seconds"]["advice_cpu"] > 0  # how long the job's steps took

    from creference_bayes.workflows.labels import export_labels

    export = export_labels(state, tmp_path / "labels")  # the folder reads as a batch folder
    assert [o.key for o in export.objects] == ["p3_t9"] and not export.skipped

    def no_estimate(*a, **k):
        raise AssertionError("the stored posterior should answer")

    monkeypatch.setattr(cb, "estimate", no_estimate)
    for fresh in (c, _app(tmp_path, **FAST).test_client()):  # the same service, and one restarted on the folder
        (pred,) = _predict(fresh, [{**one, "id": 9}]).json["results"]
        summary = " ".join(pred["result"][-1]["value"]["text"])
        assert "estimate: posterior draws" in summary
        assert (advice["request"] or advice["reason"]) in summary


def test_the_command_prints_the_served_config_and_refuses_an_open_port_without_a_token(capsys, monkeypatch):
    from creference_bayes.cli import main
    from creference_bayes.serve.predictions import Controls

    assert main(["serve", "--print-config", "--lines", "keypoints"]) == 0
    controls = Controls.from_config(capsys.readouterr().out)
    assert (controls.box, controls.text, controls.summary) == ("estimate_box", "estimate_text", "estimate_summary")
    monkeypatch.delenv("CREFERENCE_SERVE_TOKEN", raising=False)
    assert main(["serve", "--host", "0.0.0.0"]) == 2
    assert "only with a token" in capsys.readouterr().err


def test_one_job_per_task_at_a_time(tmp_path):
    from creference_bayes.serve.jobs import FrameStore, Worker

    worker, calls = Worker(FrameStore(tmp_path)), []

    def job(key):
        calls.append(key)
        if len(calls) == 1:  # asked for twice while it runs: run once more after it, not twice, not now
            worker.submit("a")
            worker.submit("a")
            assert worker.pending() == 2 and worker.busy("a")

    worker.run_job = job
    for key in ("a", "a", "b"):
        worker.submit(key)
    assert worker.pending() == 2
    worker.run_pending()
    assert calls == ["a", "b", "a"] and worker.pending() == 0


def test_deleted_annotations_leave_the_stored_task(tmp_path, task):
    app = _app(tmp_path)
    c, store = app.test_client(), app.extensions["creference"]["store"]
    hook = {"action": "ANNOTATION_CREATED", "project": {"id": 3}, "task": {"id": 5, "data": task["data"]}}
    for ann in task["annotations"][:2]:
        assert c.post("/webhook", json={**hook, "annotation": ann}).status_code == 201
    first, second = (a["id"] for a in task["annotations"][:2])
    gone = {"action": "ANNOTATIONS_DELETED", "project": {"id": 3}, "annotations": [{"id": first}]}
    r = c.post("/webhook", json=gone)
    assert r.status_code == 201 and r.json["result"]["queued"] == ["p3_t5"]
    assert [a["id"] for a in store.task("p3_t5")["annotations"]] == [second]
    r = c.post("/webhook", json={**gone, "project": {"id": 4}, "annotations": [{"id": second}]})
    assert r.json["result"]["queued"] == []  # another project's task is not touched
    assert c.post("/webhook", json={"action": "ANNOTATIONS_DELETED", "annotations": 7}).status_code == 400


def test_past_the_time_budget_a_frame_is_queued_not_estimated(tmp_path, task, monkeypatch):
    app = _app(tmp_path, time_budget_s=0.0)
    c, worker = app.test_client(), app.extensions["creference"]["worker"]
    monkeypatch.setattr(cb, "estimate", lambda *a, **k: pytest.fail("no MAP past the budget"))
    r = _predict(c, [task, {**task, "id": 6}])
    assert r.status_code == 200 and len(r.json["results"]) == 2
    for pred in r.json["results"]:
        assert "score" not in pred and "queued" in pred["result"][0]["value"]["text"][0]
    assert worker.busy("p3_t5") and worker.busy("p3_t6")


def test_an_annotation_that_kept_the_predicted_boxes_still_imports(client, task):
    (pred,) = _predict(client, [task]).json["results"]
    kept = copy.deepcopy(task)
    kept["annotations"][0]["result"] += pred["result"]  # the annotator accepted the prediction and drew on
    assert task_scene(kept).fingerprint == task_scene(task).fingerprint


# ------------------------------------------------------------------------------------------------
# in a batch folder: each frame with the data set's priors (the data-set layer's own hand-back)


@pytest.fixture(scope="module")
def batch_folder(tmp_path_factory):
    """A batch of two frames of camera cam-A, its focal length unknown; MAP only (the layer reads a
    MAP's Laplace approximation)."""
    from creference_bayes.workflows.batch import BatchSettings, run_batch
    from creference_bayes.workflows.batch.engines import LocalEngine

    root = tmp_path_factory.mktemp("batch")
    (root / "in").mkdir()
    for seed in range(2):
        (root / "in" / f"f{seed}.json").write_text(json.dumps(_camera_scene(seed)))
    report = run_batch([root / "in"], root / "out", LocalEngine(1), BatchSettings(seed=1, posterior=False))
    assert report.ok and "cam-A" in report.dataset["focal_length_px"]["groups"]
    return root / "out"


def test_a_batch_json_that_is_not_a_batchs_is_refused_naming_it(tmp_path):
    (tmp_path / "state").mkdir()
    (tmp_path / "state" / "batch.json").write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match=r"batch\.json: not a batch folder's batch\.json"):
        _app(tmp_path)


def _camera_scene(seed, camera="cam-A"):
    from conftest import truth_scene

    d, _ = truth_scene(seed, m=2, noise_px=1.0, n_annotations=2, sizes_known=False, focal_px=1400.0)
    d["camera"]["id"] = camera
    return d


def test_in_a_batch_folder_each_frame_takes_the_data_sets_priors(batch_folder, tmp_path, monkeypatch):
    import shutil

    state = tmp_path / "state"
    shutil.copytree(batch_folder, state)
    app = _app(tmp_path, background=True, **FAST)
    c, worker = app.test_client(), app.extensions["creference"]["worker"]
    learnt = json.loads((state / "batch.json").read_text())["dataset"]
    pooled = learnt["focal_length_px"]["groups"]["cam-A"]
    real, seen = cb.estimate, []

    def estimate(scene, **kw):  # what each estimate is given; MAP only (seconds)
        seen.append(scene)
        return real(scene, **{**kw, "posterior": False})

    monkeypatch.setattr(cb, "estimate", estimate)
    tasks = [label_studio_task(_camera_scene(7, camera), task_id=i, lines="vectors")
             for i, camera in ((11, "cam-A"), (12, "cam-B"))]
    r = _predict(c, tasks)
    assert r.status_code == 200, r.json
    same, other = (" | ".join(p["result"][-1]["value"]["text"]) for p in r.json["results"])
    assert f"focal length from the data set: {pooled['median']:.4g} px ± " in same and "camera cam-A" in same
    held = seen[0].focal_length_px  # held: the camera's one value (its uncertainty rides on the draws)
    assert pooled["held"] and held == pytest.approx(pooled["median"], rel=1e-3)
    # a camera the batch has no pool of: the frame's own camera priors, and the summary says why
    assert seen[1].focal_length_px is None and (seen[1].focal_prior is None or seen[1].focal_prior.source != "rig")
    assert "focal length" in other and "not from the data set (the data set has no pool of camera 'cam-B')" in other
    # the background job: the same priors, its result's dataset block says what it took
    worker.run_pending()
    assert seen[2].focal_length_px == held
    took = json.loads((state / "results" / "p3_t11.json").read_text())["dataset"]["focal_length_px"]
    assert took["from"] == "data set" and took["group"] == "cam-A" and took["median"] == pooled["median"]
    assert json.loads((state / "results" / "p3_t12.json").read_text())["dataset"]["focal_length_px"]["from"] \
        == "the frame"
    (again,) = _predict(c, tasks[:1]).json["results"]  # answered from the stored result of these priors
    summary = " | ".join(again["result"][-1]["value"]["text"])
    assert len(seen) == 4 and "focal length from the data set" in summary and "not known yet" not in summary
    assert worker.priors.dataset.summary() == learnt  # the batch's pools, read as the batch read them


# ------------------------------------------------------------------------------------------------
# tasks that share a photo: one frame, as `creference import label-studio` joins them


def test_tasks_of_one_photo_are_estimated_as_one_frame(tmp_path, monkeypatch):
    from creference_bayes.io.labelstudio import scenes_from_label_studio

    whole = scene_to_dict(parse_scene(simulate_scene(2, tier="high", n_objects=2, n_references=0,
                                                     n_target_annotations=3)))
    url = "/data/local-files/?d=street/0042.png"
    task_a, task_b = (label_studio_task({**whole, "targets": [t]}, task_id=21 + i, lines="vectors", image_url=url)
                      for i, t in enumerate(whole["targets"]))
    app = _app(tmp_path, background=True, **FAST)
    c, worker, state = app.test_client(), app.extensions["creference"]["worker"], tmp_path / "state"
    real = cb.estimate
    monkeypatch.setattr(cb, "estimate", lambda scene, **kw: real(scene, **{**kw, "posterior": False}))  # seconds

    def boxes(pred):
        return [np.array(x["value"]["points"]) for x in pred["result"] if x["type"] == "polygonlabels"]

    (alone,) = _predict(c, [task_b]).json["results"]
    assert len(boxes(alone)) == 1
    worker.run_pending()
    assert (state / "results" / "p3_t22.json").exists()  # a frame of its own, while it is its photo's only task
    (pred_a,) = _predict(c, [task_a]).json["results"]
    (pred_b,) = _predict(c, [task_b]).json["results"]
    assert len(boxes(pred_a)) == len(boxes(pred_b)) == 2  # each task shows its photo's frame
    assert all(np.array_equal(p, q) for p, q in zip(boxes(pred_a), boxes(pred_b)))
    (joined,) = scenes_from_label_studio([task_a, task_b]).scenes  # what the importer makes of them
    camera, objects = map_state(real(joined.scene, posterior=False, seed=0))
    w, h = whole["image"]["width"], whole["image"]["height"]
    for i, got in enumerate(boxes(pred_b)):
        want = image_boxes(camera[None], objects[i][None], whole.get("principal_point", [w / 2, h / 2]))[0][
            list(WIREFRAME)]
        assert np.max(np.abs(got / 100.0 * [w, h] - want)) < 0.5
    worker.run_pending()  # one result, under the first task's key; the second task's own one is gone
    assert len(json.loads((state / "results" / "p3_t21.json").read_text())["objects"]) == 2
    assert not (state / "results" / "p3_t22.json").exists() and not (state / "advice" / "p3_t22.json").exists()


def test_a_held_focal_lengths_laplace_draws_carry_the_data_sets_shared_scale(scene):
    """A frame whose focal length the data set held (its ``dataset`` block) is answered from the
    Laplace approximation with the held value fixed; its draws carry the pool's shared scale as a
    batch's results do, so the distance interval is wider and the label quality no higher than the
    same draws without it."""
    from creference_bayes.serve.predictions import estimate_view

    d = copy.deepcopy(scene)
    d["camera"]["focal_length_px"] = 1500.0
    s = parse_scene(d)
    result = cb.estimate(s, posterior=False, seed=0)
    block = {"focal_length_px": {"from": "data set", "group": "cam", "held": True, "shared_scale_log_sd": 0.1}}
    alone = estimate_view(s, result, seed=0)
    held = estimate_view(s, result, seed=0, dataset=block, base_seed=1)
    width = [np.diff(v.interval_m, axis=1).ravel() for v in (alone, held)]
    assert np.all(width[1] > 1.5 * width[0])
    assert np.all(held.p_iou <= alone.p_iou + 0.05) and np.allclose(held.distance_m, alone.distance_m)
