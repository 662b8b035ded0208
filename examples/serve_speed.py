"""Time ``creference serve``'s /predict on simulated frames (docs/serve.md, "Speed").

For each frame size, a simulated scene of N targets (three sets of dimension lines each, five
references) becomes a Label Studio task, and /predict (Flask's test client, no background job) is
timed ``--repeats`` times on a fresh service: the MAP and the Laplace approximation, the label
quality, the prediction. Prints one row per size: the median and the largest time in seconds.

    taskset -c 0 python examples/serve_speed.py --targets 1 5 10 --repeats 3
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.io.labelstudio import label_studio_task
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.serve.app import ServeSettings, create_app
from creference_bayes.serve.predictions import serve_config


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, nargs="+", default=[1, 5, 10])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    config = serve_config("vectors")
    print("targets  median s  max s")
    for n in args.targets:
        scene = scene_to_dict(parse_scene(simulate_scene(args.seed, tier="high", n_objects=n, n_references=5,
                                                         n_target_annotations=3)))
        task = label_studio_task(scene, task_id=1, lines="vectors")
        times = []
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                settings = ServeSettings(state_dir=Path(tmp), background=False)
                client = create_app(settings, start_worker=False).test_client()
                t0 = time.perf_counter()
                r = client.post("/predict", json={"tasks": [task], "label_config": config})
                times.append(time.perf_counter() - t0)
                assert r.status_code == 200, r.json
        print(f"{len(scene['targets']):7d}  {np.median(times):8.2f}  {max(times):5.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
