"""``creference serve`` against a real Label Studio (slow; docs/serve.md walks through the same steps).

Set ``CREFERENCE_LABEL_STUDIO_VENV`` to a virtual environment with ``label-studio`` (the version
docs/import.md names); without it the test is skipped. It starts Label Studio on 127.0.0.1 (local
ML backends and webhooks allowed: ``ML_BLOCK_LOCAL_IP=false``, ``SSRF_PROTECTION_ENABLED=false``)
and ``creference serve`` with a token, creates a project with the served config through the REST
API, connects the backend (basic auth) and gives its webhook the token, imports tasks made from
simulated scenes, posts their annotations (each a webhook: the frames are estimated in the
background), asks Label Studio for predictions, and checks them against ``creference estimate``
on the scenes imported from the project's export.
"""

import importlib.util
import json
import os
import secrets
import socket
import subprocess
import sys
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def checks():
    spec = importlib.util.spec_from_file_location("check_real_tools", ROOT / "examples" / "check_real_tools.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _wait_files(paths, seconds):
    t0 = time.monotonic()
    while not all(p.exists() for p in paths):
        if time.monotonic() - t0 > seconds:
            raise AssertionError(f"not written within {seconds} s: {[str(p) for p in paths if not p.exists()]}")
        time.sleep(2)


def _wait_idle(url, token, seconds):
    """Until the service has no job queued or running."""
    t0 = time.monotonic()
    while True:
        req = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}"})
        with urllib.request.urlopen(req, timeout=30) as r:
            if json.loads(r.read())["jobs"] == 0:
                return
        if time.monotonic() - t0 > seconds:
            raise AssertionError(f"the service's jobs did not finish within {seconds} s")
        time.sleep(2)


def test_label_studio_shows_the_served_estimate(checks, tmp_path, monkeypatch):
    import creference_bayes as cb
    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.io.labelstudio import label_studio_task, scenes_from_label_studio
    from creference_bayes.io.scene import parse_scene, scene_to_dict
    from creference_bayes.models.boxes import image_boxes
    from creference_bayes.pipeline import map_state
    from creference_bayes.serve.predictions import WIREFRAME, serve_config

    venv = os.environ.get("CREFERENCE_LABEL_STUDIO_VENV")
    if not venv or not (Path(venv) / "bin" / "label-studio").exists():
        why = "CREFERENCE_LABEL_STUDIO_VENV is not set to a virtual environment with label-studio"
        if os.environ.get("CREFERENCE_LABEL_STUDIO_REQUIRED"):  # .ci/integration: a bar that must run it
            pytest.fail(why)
        pytest.skip(why)
    monkeypatch.setenv("ML_BLOCK_LOCAL_IP", "false")  # the backend and its webhook are on this machine
    monkeypatch.setenv("SSRF_PROTECTION_ENABLED", "false")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenes = [scene_to_dict(parse_scene(simulate_scene(k, tier="high", n_objects=1 + k, n_references=3,
                                                           n_target_annotations=3))) for k in range(2)]
    token = secrets.token_hex(16)
    (tmp_path / "token").write_text(token)
    port, state = _free_port(), tmp_path / "state"
    log = open(tmp_path / "serve.log", "w")
    serve = subprocess.Popen([sys.executable, "-m", "creference_bayes", "serve", "--port", str(port), "--state",
                              str(state), "--token-file", str(tmp_path / "token"), "--advice-draws", "60",
                              "--advice-futures", "10"], stdout=log, stderr=subprocess.STDOUT,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    (tmp_path / "ls").mkdir()
    try:
        with checks.LabelStudioServer(Path(venv), tmp_path / "ls", _free_port(), tmp_path / "ls.log") as ls:
            st, project = ls.call("/api/projects", {"title": "served", "label_config": serve_config("vectors")}, "POST")
            assert st == 201, project
            pid = project["id"]
            st, backend = ls.call("/api/ml", {"project": pid, "title": "creference", "url": f"http://127.0.0.1:{port}",
                                              "auth_method": "BASIC_AUTH", "basic_auth_user": "labelstudio",
                                              "basic_auth_pass": token, "auto_update": True}, "POST")
            assert st == 201, backend
            st, hooks = ls.call(f"/api/webhooks/?project={pid}")
            (hook,) = [h for h in hooks if h["url"].endswith(f":{port}/webhook")]
            st, _ = ls.call(f"/api/webhooks/{hook['id']}/", {"headers": {"Authorization": f"Bearer {token}"}}, "PATCH")
            assert st == 200
            tasks = [label_studio_task(s, task_id=k + 1, lines="vectors", image_url=f"/data/local-files/?d=img{k}.jpg")
                     for k, s in enumerate(scenes)]
            st, _ = ls.call(f"/api/projects/{pid}/import", [t["data"] for t in tasks], "POST")
            assert st == 201
            st, listed = ls.call(f"/api/projects/{pid}/tasks/?page_size=100")
            ids = {t["data"]["image"]: t["id"] for t in listed}
            task_ids = [ids[t["data"]["image"]] for t in tasks]
            for tid, t in zip(task_ids, tasks):
                for ann in t["annotations"]:
                    st, _ = ls.call(f"/api/tasks/{tid}/annotations/", {"result": ann["result"]}, "POST")
                    assert st == 201
            keys = [f"p{pid}_t{tid}" for tid in task_ids]
            _wait_files([state / sub / f"{k}.json" for k in keys for sub in ("results", "advice")], 900)
            _wait_idle(f"http://127.0.0.1:{port}/health", token, 900)
            st, done = ls.call(f"/api/dm/actions?id=retrieve_tasks_predictions&project={pid}",
                               {"selectedItems": {"all": True, "excluded": []}}, "POST")
            assert st == 200, done
            st, export = ls.call(f"/api/projects/{pid}/export?exportType=JSON")
            report = scenes_from_label_studio(export)
            assert not report.errors and len(report.scenes) == 2
            by_task = {int(s.source.split()[1]): s.scene for s in report.scenes}
            for tid in task_ids:
                st, preds = ls.call(f"/api/predictions/?task={tid}")
                assert st == 200 and preds, preds
                pred = preds[-1]
                assert pred["model_version"].startswith("creference-") and 0 <= pred["score"] <= 1
                boxes = [r for r in pred["result"] if r["type"] == "polygonlabels"]
                summary = " ".join(next(r for r in pred["result"] if r["from_name"] == "estimate_summary")
                                   ["value"]["text"])
                assert "next request:" in summary and "posterior draws" in summary, summary
                scene = by_task[tid]
                camera, objects = map_state(cb.estimate(scene, posterior=False, seed=0))
                w, h = scene["image"]["width"], scene["image"]["height"]
                pp = scene.get("principal_point", [w / 2, h / 2])
                assert len(boxes) == len(objects)
                for i, box in enumerate(boxes):
                    got = np.array(box["value"]["points"]) / 100.0 * [w, h]
                    want = image_boxes(camera[None], objects[i][None], pp)[0][list(WIREFRAME)]
                    assert np.max(np.abs(got - want)) < 0.5, (tid, i, np.max(np.abs(got - want)))
            (tmp_path / "predictions.json").write_text(json.dumps(preds, indent=1))
    finally:
        serve.terminate()  # this process only, by its id
        serve.wait(timeout=30)
        log.close()
