"""The screenshot of docs/serve.md: Label Studio's editor showing a frame's served estimate.

Starts Label Studio (from ``--label-studio-venv``, which also needs ``selenium``; Chromium and
chromedriver from the system) on 127.0.0.1 with local files served from a work folder, and
``creference serve``; creates a project with the served config, connects the backend, imports a
simulated frame of three targets drawn on a plain synthetic photo, posts its annotations, waits for
the background posterior, retrieves the predictions, then opens the task in headless Chromium and
saves the page. Every process it starts is stopped by its id.

    python docs/figures/make_serve_screenshot.py --label-studio-venv /path/to/venv \
        --out docs/figures/serve_labelstudio.png
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

_BROWSER = r'''
import json, sys, time
from selenium import webdriver
from selenium.webdriver.common.by import By
from selenium.webdriver.common.action_chains import ActionChains
job = json.load(sys.stdin)
opts = webdriver.ChromeOptions()
for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1500,1750", "--disable-dev-shm-usage"):
    opts.add_argument(a)
d = webdriver.Chrome(options=opts)
try:
    d.get(job["base"] + "/user/login/")
    d.find_element(By.NAME, "email").send_keys(job["email"])
    d.find_element(By.NAME, "password").send_keys(job["password"])
    d.find_element(By.CSS_SELECTOR, "button[type=submit], input[type=submit]").click()
    time.sleep(5)
    d.get(job["base"] + job["path"])
    time.sleep(job["wait"])
    for text in job.get("click", []):  # the prediction's tab, clicked as a user would
        found = d.find_elements(By.XPATH, f"//*[contains(text(), '{text}')]")
        if found:
            d.execute_script("arguments[0].click();", found[0])
            time.sleep(5)
    regions = [el for el in d.find_elements(By.XPATH, "//*[text()='estimate']") if el.location["x"] > 1000]
    if regions:  # the first box, selected in the regions list: its numbers show under the photo
        ActionChains(d).move_to_element(regions[0]).click().perform()
        time.sleep(4)
    d.save_screenshot(job["out"])
finally:
    d.quit()
'''


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _call(base, token, path, body=None, method="GET"):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method,
                                 headers={"Authorization": f"Token {token}", "Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=300) as r:
        raw = r.read()
        return json.loads(raw) if raw else None


def _wait(url, seconds, headers=None):
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        try:
            with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}), timeout=5) as r:
                return json.loads(r.read() or b"{}")
        except (urllib.error.URLError, OSError, ValueError):
            time.sleep(2)
    raise RuntimeError(f"{url} did not answer within {seconds} s")


def _photo(scene: dict, path: Path) -> None:
    """A plain synthetic photo of the scene's size: sky above its horizon, a tiled floor below."""
    import numpy as np
    from PIL import Image

    w, h = scene["image"]["width"], scene["image"]["height"]
    (u0, v0), (u1, v1) = scene.get("horizon") or [[0, h * 0.4], [w, h * 0.4]]
    y, x = np.mgrid[0:h, 0:w]
    above = y < v0 + (v1 - v0) * (x - u0) / (u1 - u0)
    img = np.where(above[..., None], [205, 215, 228], [150, 140, 128]).astype(np.uint8)
    img[~above & (((x // 120) + (y // 120)) % 2 == 0)] = [160, 150, 138]
    Image.fromarray(img).save(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label-studio-venv", required=True, type=Path)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "serve_labelstudio.png")
    ap.add_argument("--seed", type=int, default=4)
    args = ap.parse_args(argv)

    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.io.labelstudio import label_studio_task
    from creference_bayes.io.scene import parse_scene, scene_to_dict
    from creference_bayes.serve.predictions import serve_config

    work = Path(tempfile.mkdtemp(prefix="serve-shot-"))
    (work / "files" / "photos").mkdir(parents=True)
    scene = scene_to_dict(parse_scene(simulate_scene(args.seed, tier="high", n_objects=3, n_references=3,
                                                     n_target_annotations=3)))
    _photo(scene, work / "files" / "photos" / "frame.png")
    email, password, token = "admin@example.com", secrets.token_hex(12), secrets.token_hex(20)
    serve_token = secrets.token_hex(16)
    ls_port, serve_port = _port(), _port()
    base = f"http://127.0.0.1:{ls_port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("LABEL_STUDIO_")}
    env.update(LATEST_VERSION_CHECK="false", SENTRY_DSN="", FRONTEND_SENTRY_DSN="", COLLECT_ANALYTICS="false",
               ML_BLOCK_LOCAL_IP="false", SSRF_PROTECTION_ENABLED="false",
               LABEL_STUDIO_LOCAL_FILES_SERVING_ENABLED="true",
               LABEL_STUDIO_LOCAL_FILES_DOCUMENT_ROOT=str(work / "files"))
    procs = []
    try:
        procs.append(subprocess.Popen(
            [str(args.label_studio_venv / "bin" / "label-studio"), "start", "--no-browser", "--internal-host",
             "127.0.0.1", "--port", str(ls_port), "--data-dir", str(work / "ls"), "--username", email,
             "--password", password, "--user-token", token, "--enable-legacy-api-token"],
            stdout=open(work / "ls.log", "w"), stderr=subprocess.STDOUT, env=env, cwd=work))
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "creference_bayes", "serve", "--port", str(serve_port), "--state",
             str(work / "state"), "--advice-draws", "60", "--advice-futures", "10"],
            stdout=open(work / "serve.log", "w"), stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONPATH": str(ROOT), "CREFERENCE_SERVE_TOKEN": serve_token}))
        _wait(base + "/health", 900)
        pid = _call(base, token, "/api/projects", {"title": "street", "label_config": serve_config("vectors")},
                    "POST")["id"]
        _call(base, token, "/api/ml", {"project": pid, "title": "creference", "url": f"http://127.0.0.1:{serve_port}",
                                       "auth_method": "BASIC_AUTH", "basic_auth_user": "labelstudio",
                                       "basic_auth_pass": serve_token, "auto_update": True}, "POST")
        hook = next(h for h in _call(base, token, f"/api/webhooks/?project={pid}") if h["url"].endswith("/webhook"))
        _call(base, token, f"/api/webhooks/{hook['id']}/", {"headers": {"Authorization": f"Bearer {serve_token}"}},
              "PATCH")
        _call(base, token, "/api/storages/localfiles", {"project": pid, "title": "photos", "use_blob_urls": False,
                                                         "path": str(work / "files" / "photos")}, "POST")
        task = label_studio_task(scene, lines="vectors", image_url="/data/local-files/?d=photos/frame.png")
        _call(base, token, f"/api/projects/{pid}/import", [task["data"]], "POST")
        tid = _call(base, token, f"/api/projects/{pid}/tasks/")[0]["id"]
        for ann in task["annotations"]:
            _call(base, token, f"/api/tasks/{tid}/annotations/", {"result": ann["result"]}, "POST")
        key = work / "state" / "advice" / f"p{pid}_t{tid}.json"
        t0 = time.monotonic()
        health = f"http://127.0.0.1:{serve_port}/health"
        while not key.exists() or _wait(health, 60, {"Authorization": f"Bearer {serve_token}"})["jobs"]:
            if time.monotonic() - t0 > 1800:
                raise RuntimeError("the background estimate did not finish within 30 min")
            time.sleep(3)
        _call(base, token, f"/api/projects/{pid}", {"show_collab_predictions": True}, "PATCH")
        _call(base, token, f"/api/dm/actions?id=retrieve_tasks_predictions&project={pid}",
              {"selectedItems": {"all": True, "excluded": []}}, "POST")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        job = {"base": base, "email": email, "password": password, "path": f"/projects/{pid}/data?task={tid}",
               "wait": 15, "out": str(args.out.resolve()), "click": ["creferen"]}
        proc = subprocess.run([str(args.label_studio_venv / "bin" / "python"), "-c", _BROWSER], input=json.dumps(job),
                              capture_output=True, text=True, timeout=600)
        if proc.returncode:
            raise RuntimeError(proc.stderr[-2000:])
        print(f"wrote {args.out} (work folder {work})")
    finally:
        for p in procs:  # each process this script started, by its id
            p.terminate()
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
