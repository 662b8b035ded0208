"""Check the Label Studio and CVAT converters against the real tools, not only against our reading
of their documentation.

Label Studio (its own virtual environment, ``pip install label-studio``): start a server bound to
127.0.0.1 with its outward calls disabled; for each shipped config (keypoints, vectors) create a
project (the server validates the config), import tasks made from simulated scenes of several
targets, create one user per worker, post the annotations through the API — those our exporter
writes, and one task whose results Label Studio's own SDK builds (``label_studio_sdk.label_interface``,
without ``original_width``/``original_height``, as a client may post them) — validate every result
with the SDK against the config, export through the API, run ``creference import label-studio`` on
that export and compare with the simulated scenes. The server is stopped by its process id at the end.

Datumaro (its own virtual environment, ``pip install datumaro``; CVAT's own format library):
(1) Datumaro builds a dataset from the simulated scenes' shapes and writes it as CVAT for images
1.1, which ``creference import cvat`` reads; (2) Datumaro reads the XML our exporter writes and
writes it again, which we read back. Both are compared with the simulated scenes.

    python examples/check_real_tools.py --label-studio-venv /path/to/venv-ls \\
        --datumaro-venv /path/to/venv-dm [--workdir DIR] [--n-scenes 3] [--seed 0]

(``CREFERENCE_LABEL_STUDIO_VENV`` / ``CREFERENCE_DATUMARO_VENV`` are the defaults.) Prints a table
and writes ``report.json`` in the work folder; the exit status is 1 if any check failed.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.io.cvat import cvat_xml
from creference_bayes.io.labelstudio import label_studio_config, label_studio_task
from creference_bayes.io.scene import parse_scene, scene_differences, scene_to_dict

# ----------------------------------------------------------------------------------------------
# scenes and comparison


def make_scenes(n: int, seed: int) -> list[dict]:
    """``n`` simulated scenes of one to three targets (every reference format appears), as
    ``creference-scene/2`` dicts; the k-th is photo ``img{k}``."""
    rng = np.random.default_rng(seed)
    scenes = [simulate_scene(rng, tier="high", n_objects=1 + k % 3, n_references=5, n_target_annotations=3,
                             format_offset=5 * k) for k in range(n)]
    for s in scenes:  # a stated confidence on some references, as workers may give one
        for j, r in enumerate(s["references"]):
            if j % 2 == 0:
                r["confidence"] = 0.8
    return [scene_to_dict(parse_scene(s)) for s in scenes]


def run_import(tool: str, export: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    """``creference import TOOL EXPORT --out OUT`` in this interpreter."""
    cmd = [sys.executable, "-m", "creference_bayes", "import", tool, str(export), "--out", str(out), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def compare_dir(out: Path, scenes: list[dict], atol: float, drop=()) -> dict:
    """Differences between each scene and the file ``img{k}.json`` imported for it."""
    result = {}
    for k, s in enumerate(scenes):
        path = out / f"img{k}.json"
        result[path.stem] = (["not imported"] if not path.exists()
                             else scene_differences(json.loads(path.read_text()), s, atol, drop))
    return result


# ----------------------------------------------------------------------------------------------
# Label Studio

_SDK_RESULTS = r'''
import json, sys
from label_studio_sdk.label_interface import LabelInterface
job = json.load(sys.stdin)
li = LabelInterface(job["config"])

def field(name, kind, value, region):
    r = li.get_control(name).label(**{kind: value})
    r.id = region.id
    return r._dict()

out = []
for ann in job["annotations"]:
    res = []
    for t in ann["targets"]:
        if job["lines"] == "keypoints":
            for label, (x, y) in zip(job["target_labels"], t["corners"]):
                p = li.get_control("points").label(label=label, x=x, y=y)
                res += [p._dict(), field("target", "text", [t["id"]], p)]
        else:
            v = li.get_control("targets").label(label="target", closed=False,
                                                vertices=[{"x": x, "y": y} for x, y in t["corners"]])
            res += [v._dict(), field("target", "text", [t["id"]], v)]
    for ref in ann["references"]:
        if job["lines"] == "keypoints":
            a = li.get_control("points").label(label="reference start", x=ref["a"][0], y=ref["a"][1])
            b = li.get_control("points").label(label="reference end", x=ref["b"][0], y=ref["b"][1])
            a.add_relation(b)
            res += [a._dict(), b._dict()] + a._dict_relations()
        else:
            a = li.get_control("lines").label(label="reference", closed=False,
                                              vertices=[{"x": ref["a"][0], "y": ref["a"][1]},
                                                        {"x": ref["b"][0], "y": ref["b"][1]}])
            res.append(a._dict())
        res += [field(name, kind, value, a) for name, kind, value in ref["fields"]]
    out.append(res)
json.dump(out, sys.stdout)
'''

_SDK_VALIDATE = r'''
import json, sys
from label_studio_sdk.label_interface import LabelInterface
job = json.load(sys.stdin)
li = LabelInterface(job["config"])
json.dump([li.validate_prediction({"result": r}, return_errors=True) for r in job["results"]], sys.stdout)
'''


def _venv_python(venv: Path) -> str:
    return str(Path(venv) / "bin" / "python")


def _in_venv(venv: Path, code: str, payload) -> object:
    proc = subprocess.run([_venv_python(venv), "-c", code], input=json.dumps(payload),
                          capture_output=True, text=True, timeout=600)
    if proc.returncode:
        raise RuntimeError(f"{venv}: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout)


class LabelStudioServer:
    """A Label Studio server on 127.0.0.1 for the duration of a ``with`` block."""

    def __init__(self, venv: Path, data_dir: Path, port: int, log: Path):
        self.venv, self.data_dir, self.port, self.log = Path(venv), Path(data_dir), port, log
        # a reused data folder keeps the admin user made at its first start: keep its token too
        saved = self.data_dir / "creference-check-token"
        if not saved.exists():
            saved.write_text(secrets.token_hex(20))
        self.token = saved.read_text().strip()
        self.base = f"http://127.0.0.1:{port}"
        self.proc = None

    def __enter__(self):
        env = {k: v for k, v in os.environ.items()
               if k not in ("USERNAME", "PASSWORD", "USER_TOKEN") and not k.startswith("LABEL_STUDIO_")}
        env.update(LATEST_VERSION_CHECK="false", SENTRY_DSN="", FRONTEND_SENTRY_DSN="",
                   COLLECT_ANALYTICS="false")
        cmd = [str(self.venv / "bin" / "label-studio"), "start", "--no-browser",
               "--internal-host", "127.0.0.1", "--port", str(self.port), "--data-dir", str(self.data_dir),
               "--username", "admin@example.com", "--password", secrets.token_hex(12),
               "--user-token", self.token, "--enable-legacy-api-token"]
        self.t0 = time.monotonic()
        self._logf = open(self.log, "w")
        self.proc = subprocess.Popen(cmd, stdout=self._logf, stderr=subprocess.STDOUT, env=env,
                                     cwd=self.data_dir)
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"label-studio exited with {self.proc.returncode}; see {self.log}")
            try:
                with urllib.request.urlopen(f"{self.base}/health", timeout=2) as r:
                    if r.status == 200:
                        break
            except (urllib.error.URLError, OSError):
                pass
            if time.monotonic() - self.t0 > 300:
                raise RuntimeError(f"label-studio did not answer within 300 s; see {self.log}")
            time.sleep(1)
        self.startup_seconds = time.monotonic() - self.t0
        return self

    def __exit__(self, *exc):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()  # this process only, by its id
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=30)
        self._logf.close()

    def call(self, path: str, body=None, method: str = "GET"):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path, data=data, method=method, headers={
            "Authorization": f"Token {self.token}", "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                raw = r.read()
                return r.status, (json.loads(raw) if raw else None)
        except urllib.error.HTTPError as e:
            return e.code, e.read().decode(errors="replace")[:2000]


def _percent(p, w, h):
    return [100.0 * p[0] / w, 100.0 * p[1] / h]


def _sdk_job(scene: dict, lines: str) -> dict:
    """The scene's annotations described for the SDK script: one annotation per item (a target's
    set of dimension lines or a reference), each with its worker and seconds."""
    from creference_bayes.io.labelstudio_results import TARGET_LABELS

    w, h = scene["image"]["width"], scene["image"]["height"]
    anns = [{"targets": [{"id": t["id"], "corners": [_percent(p, w, h) for p in d["corners"]]}], "references": [],
             "worker": d.get("worker"), "seconds": d.get("seconds")}
            for t in scene["targets"] for d in t["dimension_lines"]]
    for r in scene.get("references", []):
        fields = [("measure", "choices", [r["measure"]]), ("mode", "choices", [r["mode"]])]
        if "range" in r:
            fields += [("range_low", "number", r["range"][0]), ("range_high", "number", r["range"][1])]
        else:
            fields.append(("value", "number", r["value"]))
        if r.get("unit"):
            fields.append(("unit", "choices", [r["unit"]]))
        if r.get("confidence") is not None:
            fields.append(("confidence_pct", "number", round(100 * r["confidence"], 10)))
        if r.get("object"):
            fields.append(("object", "text", [r["object"]]))
        if r.get("target"):
            fields.append(("target", "text", [r["target"]]))
        anns.append({"targets": [], "worker": r.get("worker"), "seconds": r.get("seconds"),
                     "references": [{"a": _percent(r["line"][0], w, h), "b": _percent(r["line"][1], w, h),
                                     "fields": fields}]})
    return {"lines": lines, "target_labels": list(TARGET_LABELS), "annotations": anns}


def check_label_studio(venv: Path, workdir: Path, scenes: list[dict], port: int = 18090,
                       data_dir: Path | None = None) -> dict:
    """Run the Label Studio check; returns a report dict (``ok`` is the verdict)."""
    workdir.mkdir(parents=True, exist_ok=True)
    data_dir = Path(data_dir) if data_dir else workdir / "ls-data"
    data_dir.mkdir(parents=True, exist_ok=True)
    version = subprocess.run([_venv_python(venv), "-c", "import label_studio; print(label_studio.__version__)"],
                             capture_output=True, text=True).stdout.strip()
    report: dict = {"label_studio_version": version, "checks": {}}
    with LabelStudioServer(venv, data_dir, port, workdir / "label-studio.log") as srv:
        report["startup_seconds"] = round(srv.startup_seconds, 1)
        st, body = srv.call("/api/projects", {"title": "broken", "label_config":
                            '<View><Image name="image" value="$image"/><KeyPointLabels name="points" '
                            'toName="nosuch"><Label value="a"/></KeyPointLabels></View>'}, "POST")
        report["broken_config_rejected"] = {"status": st, "detail": str(body)[:300]}
        st, users = srv.call("/api/users/")
        known = {u["username"]: u["id"] for u in users if u.get("username")}
        for lines in ("keypoints", "vectors"):
            rep: dict = {}
            st, project = srv.call("/api/projects", {"title": f"creference {lines}",
                                                     "label_config": label_studio_config(lines)}, "POST")
            rep["project_status"] = st
            if st != 201:
                rep["error"] = str(project)[:500]
                report["checks"][lines] = rep
                continue
            pid = project["id"]
            # the last scene's annotations are built by Label Studio's SDK, without original sizes
            ours = [label_studio_task(s, lines=lines, image_url=f"/data/local-files/?d=img{k}.jpg")
                    for k, s in enumerate(scenes)]
            sdk_results = _in_venv(venv, _SDK_RESULTS, {"config": label_studio_config(lines),
                                                        **_sdk_job(scenes[-1], lines)})
            tasks_data = [t["data"] for t in ours]
            st, imp = srv.call(f"/api/projects/{pid}/import", tasks_data, "POST")
            rep["import_status"] = st
            st, listed = srv.call(f"/api/projects/{pid}/tasks/?page_size=1000")
            task_ids = {t["data"]["image"]: t["id"] for t in listed}
            posted, to_validate = [], []
            for k, (task, scene) in enumerate(zip(ours, scenes)):
                if k == len(scenes) - 1:
                    job = _sdk_job(scene, lines)["annotations"]
                    anns = [{"result": res, "completed_by": a["worker"], "lead_time": a["seconds"]}
                            for a, res in zip(job, sdk_results)]
                else:
                    anns = task["annotations"]
                for a in anns:
                    name = a.get("completed_by")
                    if name and name not in known:
                        st, u = srv.call("/api/users/", {"email": f"{name}@example.com", "username": name}, "POST")
                        known[name] = u["id"]
                    body = {"result": a["result"], "lead_time": a.get("lead_time")}
                    if name:
                        body["completed_by"] = known[name]
                    st, r = srv.call(f"/api/tasks/{task_ids[task['data']['image']]}/annotations/", body, "POST")
                    posted.append(st)
                    to_validate.append(a["result"])
            rep["annotations_posted"] = {str(s): posted.count(s) for s in sorted(set(posted))}
            errors = _in_venv(venv, _SDK_VALIDATE, {"config": label_studio_config(lines), "results": to_validate})
            rep["sdk_validation_errors"] = [e for errs in errors for e in errs][:10]
            st, export = srv.call(f"/api/projects/{pid}/export?exportType=JSON")
            rep["export_status"] = st
            export_path = workdir / f"label-studio-export-{lines}.json"
            export_path.write_text(json.dumps(export, indent=1))
            st, users = srv.call("/api/users/")
            users_path = workdir / "label-studio-users.json"
            users_path.write_text(json.dumps(users))
            out = workdir / f"scenes-label-studio-{lines}"
            proc = run_import("label-studio", export_path, out, "--users", str(users_path))
            rep["import_exit"] = proc.returncode
            rep["import_stderr"] = proc.stderr.strip()[-1000:]
            diffs = compare_dir(out, scenes, atol=1e-9)
            rep["differences"] = diffs
            rep["ok"] = (rep["import_exit"] == 0 and not rep["sdk_validation_errors"]
                         and all(not d for d in diffs.values()) and set(posted) == {201})
            report["checks"][lines] = rep
    report["ok"] = (report["broken_config_rejected"]["status"] == 400
                    and all(c.get("ok") for c in report["checks"].values()))
    return report


# ----------------------------------------------------------------------------------------------
# Datumaro

_DM_WRITE = r'''
import json, sys, os
import datumaro as dm
from datumaro.components.annotation import Points, PolyLine, LabelCategories, AnnotationType
from datumaro.components.media import Image
job = json.load(sys.stdin)
cats = LabelCategories(attributes={"occluded"})
for name, attrs in job["labels"].items():
    cats.add(name, attributes=set(attrs))
items = []
for img in job["images"]:
    anns = []
    for sh in img["shapes"]:
        cls = Points if sh["kind"] == "points" else PolyLine
        anns.append(cls(sh["points"], label=cats.find(sh["label"])[0], attributes=sh["attributes"]))
    items.append(dm.DatasetItem(id=img["id"], media=Image.from_file(path=img["id"] + ".jpg",
                 size=(img["height"], img["width"])), annotations=anns))
ds = dm.Dataset.from_iterable(items, categories={AnnotationType.label: cats})
ds.export(job["out"], "cvat", save_media=False)
print(json.dumps(sorted(os.listdir(job["out"]))))
'''

_DM_RELAY = r'''
import json, sys, os
import datumaro as dm
job = json.load(sys.stdin)
ds = dm.Dataset.import_from(job["src"], "cvat")
ds.export(job["out"], "cvat", save_media=False)
print(json.dumps({"items": len(ds), "files": sorted(os.listdir(job["out"]))}))
'''


def _datumaro_job(scenes: list[dict], out: Path) -> dict:
    """The scenes as shapes with attributes, written straight from the scene dicts (not through
    our CVAT writer), one image per scene."""
    from creference_bayes.io.cvat import LABEL_ATTRIBUTES

    images = []
    for k, s in enumerate(scenes):
        shapes = []
        for t in s["targets"]:
            size = {f"{key}_m": str(v) for key, v in (t.get("dimensions_m") or {}).items()}
            shapes += [{"label": "target", "kind": "points", "points": [c for p in d["corners"] for c in p],
                        "attributes": {"target_id": t["id"], "class": t.get("class", ""), **size,
                                       "worker": d.get("worker", "")}}
                       for d in t["dimension_lines"]]
        for r in s.get("references", []):
            attrs = {"target_id": r.get("target", ""), "object": r.get("object", ""), "measure": r["measure"],
                     "mode": r["mode"], "unit": r.get("unit", ""), "worker": r.get("worker", ""),
                     "value": str(r["value"]) if "value" in r else "",
                     "range_low": str(r["range"][0]) if "range" in r else "",
                     "range_high": str(r["range"][1]) if "range" in r else "",
                     "confidence_pct": str(round(100 * r["confidence"], 10)) if r.get("confidence") is not None else ""}
            shapes.append({"label": "reference", "kind": "polyline",
                           "points": [c for p in r["line"] for c in p], "attributes": attrs})
        if s.get("horizon"):
            shapes.append({"label": "horizon", "kind": "polyline",
                           "points": [c for p in s["horizon"] for c in p], "attributes": {"worker": ""}})
        images.append({"id": f"img{k}", "width": s["image"]["width"], "height": s["image"]["height"],
                       "shapes": shapes})
    return {"labels": {k: list(v) for k, v in LABEL_ATTRIBUTES.items()}, "images": images, "out": str(out)}


def check_datumaro(venv: Path, workdir: Path, scenes: list[dict]) -> dict:
    """Run the Datumaro checks; returns a report dict (``ok`` is the verdict)."""
    workdir.mkdir(parents=True, exist_ok=True)
    version = subprocess.run([_venv_python(venv), "-c", "import datumaro; print(datumaro.__version__)"],
                             capture_output=True, text=True).stdout.strip()
    report: dict = {"datumaro_version": version, "checks": {}}
    drop = ("seconds", "ground_truth", "classes")  # what CVAT files cannot carry
    # (1) Datumaro writes CVAT XML from its own dataset model
    out1 = workdir / "datumaro-written"
    files = _in_venv(venv, _DM_WRITE, _datumaro_job(scenes, out1))
    xml = out1 / "default.xml" if (out1 / "default.xml").exists() else out1 / "annotations.xml"
    proc = run_import("cvat", xml, workdir / "scenes-datumaro-written")
    diffs = compare_dir(workdir / "scenes-datumaro-written", scenes, atol=0.005, drop=drop)
    report["checks"]["datumaro_writes"] = {"files": files, "import_exit": proc.returncode,
                                           "import_stderr": proc.stderr.strip()[-1000:], "differences": diffs,
                                           "ok": proc.returncode == 0 and all(not d for d in diffs.values())}
    # (2) Datumaro reads our XML and writes it again (it needs the image files beside the XML)
    src = workdir / "ours"
    (src / "images").mkdir(parents=True, exist_ok=True)
    names = [f"img{k}.jpg" for k in range(len(scenes))]
    for n in names:
        (src / "images" / n).write_bytes(b"")
    (src / "annotations.xml").write_text(cvat_xml(scenes, image_names=names))
    out2 = workdir / "datumaro-relayed"
    relay = _in_venv(venv, _DM_RELAY, {"src": str(src / "annotations.xml"), "out": str(out2)})
    proc = run_import("cvat", out2 / "annotations.xml", workdir / "scenes-datumaro-relayed")
    diffs = compare_dir(workdir / "scenes-datumaro-relayed", scenes, atol=0.005, drop=drop)
    report["checks"]["datumaro_reads_ours"] = {"relay": relay, "import_exit": proc.returncode,
                                               "import_stderr": proc.stderr.strip()[-1000:],
                                               "differences": diffs,
                                               "ok": proc.returncode == 0 and all(not d for d in diffs.values())}
    report["ok"] = all(c["ok"] for c in report["checks"].values())
    return report


# ----------------------------------------------------------------------------------------------


def _table(report: dict) -> str:
    rows = [("check", "result", "detail")]
    ls = report.get("label_studio")
    if ls:
        rows.append(("label studio " + ls.get("label_studio_version", "?"), "",
                     f"server up in {ls.get('startup_seconds')} s"))
        b = ls["broken_config_rejected"]
        rows.append(("  broken config rejected", "ok" if b["status"] == 400 else "FAIL", f"HTTP {b['status']}"))
        for lines, c in ls["checks"].items():
            n_diff = sum(len(d) for d in c.get("differences", {}).values())
            rows.append((f"  {lines}: project, tasks, annotations, export, import",
                         "ok" if c.get("ok") else "FAIL",
                         f"project HTTP {c.get('project_status')}, annotations {c.get('annotations_posted')}, "
                         f"SDK validation errors {len(c.get('sdk_validation_errors', []))}, "
                         f"import exit {c.get('import_exit')}, differences {n_diff}"))
    dm_rep = report.get("datumaro")
    if dm_rep:
        rows.append(("datumaro " + dm_rep.get("datumaro_version", "?"), "", ""))
        for name, c in dm_rep["checks"].items():
            n_diff = sum(len(d) for d in c["differences"].values())
            rows.append((f"  {name}", "ok" if c["ok"] else "FAIL",
                         f"import exit {c['import_exit']}, differences {n_diff}"))
    widths = [max(len(str(r[i])) for r in rows) for i in range(3)]
    return "\n".join("  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--label-studio-venv", default=os.environ.get("CREFERENCE_LABEL_STUDIO_VENV"))
    p.add_argument("--datumaro-venv", default=os.environ.get("CREFERENCE_DATUMARO_VENV"))
    p.add_argument("--workdir", help="where to put exports, scenes and the report (default: a temporary folder)")
    p.add_argument("--ls-data-dir", help="reuse this Label Studio data folder (a restart takes seconds)")
    p.add_argument("--port", type=int, default=18090)
    p.add_argument("--n-scenes", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if not args.label_studio_venv and not args.datumaro_venv:
        p.error("give --label-studio-venv and/or --datumaro-venv (or set the environment variables)")
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="creference-real-tools-"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenes = make_scenes(args.n_scenes, args.seed)
    report: dict = {"n_scenes": len(scenes), "seed": args.seed, "workdir": str(workdir)}
    if args.label_studio_venv:
        report["label_studio"] = check_label_studio(Path(args.label_studio_venv), workdir / "label-studio",
                                                    scenes, port=args.port, data_dir=args.ls_data_dir)
    if args.datumaro_venv:
        report["datumaro"] = check_datumaro(Path(args.datumaro_venv), workdir / "datumaro", scenes)
    (workdir / "report.json").write_text(json.dumps(report, indent=1))
    print(_table(report))
    print(f"\nreport: {workdir / 'report.json'}")
    ok = all(report[k]["ok"] for k in ("label_studio", "datumaro") if k in report)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
