"""Time ``creference serve``'s /predict on simulated frames (docs/serve.md, "Speed").

For each frame size, a simulated scene of N targets (three sets of dimension lines each, five
references) becomes a Label Studio task, and /predict (Flask's test client, no background job) is
timed ``--repeats`` times, each time as a new task (no stored estimate answers it): the MAP and the
Laplace approximation, the label quality, the prediction. Prints one row per size: the median and
the largest time in seconds, wall clock and CPU (the process's: on a machine other jobs share, the
CPU time is what the request would take on a core of its own), then the load average.

With ``--batch DIR`` the service runs in a copy of that batch folder (``creference batch … --out
DIR``): each frame takes the data set's priors (docs/serve.md, "A data set's priors"), its camera
``--camera-id``; the time the service takes to read the data set at its start is printed too.
``--profile`` then profiles one more request of the last size (CPU time, cProfile).

With ``--jobs`` it times instead, for each frame size, the background job a webhook queues (the
posterior as ``creference estimate`` samples it, then the next request, by default with the
service's ``--advice-draws 200 --advice-futures 40``) against ``creference batch`` on the same frame (the
command, run as a user runs it: its process's start included). Prints, in seconds: the batch
command and its estimate of the frame (the result's ``seconds``), the job and its two steps (as
the job records them in its advice file, wall clock and the process's CPU).

    taskset -c 0 python examples/serve_speed.py --targets 1 5 10 --repeats 3
    taskset -c 0 python examples/serve_speed.py --jobs --targets 1 3 5
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.io.labelstudio import label_studio_task
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.serve.app import ServeSettings, create_app
from creference_bayes.serve.predictions import serve_config


def _clock():
    return time.perf_counter(), time.process_time()


def _since(t0) -> tuple[float, float]:
    wall, cpu = _clock()
    return wall - t0[0], cpu - t0[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, nargs="+", default=[1, 5, 10])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", default=None, metavar="DIR", help="run the service in a copy of this batch folder")
    ap.add_argument("--camera-id", default=None, help="the tasks' camera (data.camera_id)")
    ap.add_argument("--profile", action="store_true", help="then profile one more /predict of the last size (CPU "
                    "time, cProfile) and print where it goes")
    ap.add_argument("--jobs", action="store_true", help="time the background job against creference batch")
    ap.add_argument("--min-ess", type=float, default=None, help="the sampler's effective sample size (--jobs; "
                    "default: the sampler's)")
    ap.add_argument("--advice-draws", type=int, default=200, help="the job's advice (--jobs; default: the service's)")
    ap.add_argument("--advice-futures", type=int, default=40, help="the job's advice (--jobs; default: the service's)")
    args = ap.parse_args(argv)
    if args.jobs:
        return _jobs(args)
    config = serve_config("vectors")
    with tempfile.TemporaryDirectory() as tmp:
        state = Path(tmp) / "state"
        state.mkdir()
        if args.batch is not None:  # the batch's files the data set is read from, not its results
            for part in ("batch.json", "first_pass", "scenes"):
                src = Path(args.batch) / part
                (shutil.copytree if src.is_dir() else shutil.copy)(src, state / part)
        t0 = _clock()
        client = create_app(ServeSettings(state_dir=state, background=False), start_worker=False).test_client()
        if args.batch is not None:
            print("reading the data set at the start: {:.2f} s, CPU {:.2f} s".format(*_since(t0)))
        print("targets  median s  max s  CPU median s  CPU max s")
        task_id = 0
        for n in args.targets:
            scene = _scene(n, args.seed)
            task = label_studio_task(scene, task_id=1, lines="vectors")
            if args.camera_id is not None:
                task["data"]["camera_id"] = args.camera_id
            times = []
            for _ in range(args.repeats):
                task_id += 1
                t0 = _clock()
                r = client.post("/predict", json={"tasks": [{**task, "id": task_id}], "label_config": config})
                times.append(_since(t0))
                assert r.status_code == 200, r.json
            wall, cpu = np.array(times).T
            print(f"{len(scene['targets']):7d}  {np.median(wall):8.2f}  {wall.max():5.2f}  {np.median(cpu):12.2f}  "
                  f"{cpu.max():9.2f}")
        if args.profile:
            import cProfile
            import pstats

            profile = cProfile.Profile(timer=time.process_time)
            profile.runcall(client.post, "/predict", json={"tasks": [{**task, "id": task_id + 1}],
                                                           "label_config": config})
            pstats.Stats(profile).sort_stats("cumulative").print_stats(r"creference_bayes", 25)
    print("load average (1, 5, 15 min): {:.1f} {:.1f} {:.1f}".format(*os.getloadavg()))
    return 0


def _scene(n: int, seed: int) -> dict:
    return scene_to_dict(parse_scene(simulate_scene(seed, tier="high", n_objects=n, n_references=5,
                                                    n_target_annotations=3)))


def _jobs(args) -> int:
    """``--jobs`` (module docstring)."""
    from creference_bayes.workflows.advice import AdviceSettings

    sampling = {} if args.min_ess is None else {"min_ess": args.min_ess}
    advice = AdviceSettings(n_draws=args.advice_draws, n_futures=args.advice_futures)
    config = serve_config("vectors")
    print("targets  batch s  estimate s  job s  posterior s (CPU)  advice s (CPU)")
    for n in args.targets:
        scene = _scene(n, args.seed)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "frame.json"
            path.write_text(json.dumps(scene))
            cmd = [sys.executable, "-m", "creference_bayes", "batch", str(path), "--out", str(Path(tmp) / "batch"),
                   "--workers", "1"] + ([] if args.min_ess is None else ["--min-ess", str(args.min_ess)])
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            batch = time.perf_counter() - t0, json.loads((Path(tmp) / "batch" / "results" / "frame.json").read_text())[
                "seconds"]
            settings = ServeSettings(state_dir=Path(tmp) / "state", sampling=sampling or None, advice_settings=advice)
            app = create_app(settings, start_worker=False)
            client, worker = app.test_client(), app.extensions["creference"]["worker"]
            task = label_studio_task(scene, task_id=1, lines="vectors")
            hook = {"action": "ANNOTATION_CREATED", "project": {"id": 1, "label_config": config},
                    "task": {"id": 1, "data": task["data"]}}
            for ann in task["annotations"]:
                assert client.post("/webhook", json={**hook, "annotation": ann}).status_code == 201
            t0 = time.perf_counter()
            worker.run_pending()
            job = time.perf_counter() - t0
            steps = json.loads((Path(tmp) / "state" / "advice" / "p1_t1.json").read_text())["seconds"]
        print(f"{n:7d}  {batch[0]:7.1f}  {batch[1]:10.1f}  {job:5.1f}  {steps['posterior']:8.1f} "
              f"({steps['posterior_cpu']:5.1f})  {steps['advice']:7.1f} ({steps['advice_cpu']:5.1f})")
    print("load average (1, 5, 15 min): {:.1f} {:.1f} {:.1f}".format(*os.getloadavg()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
