"""The data set's pool of each camera's focal length, recomputed offline from a batch folder's first
pass: each frame read alone, and given its camera's pooled pitch and roll (docs/studies/rig.md,
"The data-set layer"; creference_bayes/workflows/batch/dataset.py).

    python examples/dataset_pool.py BATCH [--groups 0-24,25-50]

BATCH is a ``creference batch`` folder whose ``first_pass/`` is complete (a MAP first pass is read
through its Laplace approximation, a first pass that kept posterior draws through them). For every
camera with ten frames or more, for all its frames and each group of frames (frames named by an
integer, e.g. KITTI's index: ``0-24`` takes frames 0 to 24), under each reading (``alone``: the
frame's prior divided out; ``given``: and its draws moved to the other frames' pitch and roll),
the pooled focal length and, when the scenes carry the truth (``ground_truth.focal_length_px``,
which ``simulate --from-kitti`` writes), the error, z = error / stated sd, and each frame's reading
against the truth by objects per frame (median; in brackets how many frames were read).
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.io.scene import SceneWarning, load_scene
from creference_bayes.workflows.batch import dataset as D
from creference_bayes.workflows.batch.rig import camera_id_of

#: reading → whether the focal length is read given the other frames' pitch and roll
READINGS = {"alone": False, "given": True}


def frames_of(first: Path) -> list[tuple[str, str | None, int, float | None]]:
    """(KEY, camera id, objects, true focal length px or None) of every first-pass result."""
    out = []
    for path in sorted((first / "results").glob("*.json")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            scene = load_scene(first / "scenes" / path.name)
        out.append((path.stem, camera_id_of(scene), len(scene.targets), (scene.ground_truth or {}).get("focal_length_px")))
    return out


def in_group(key: str, rng) -> bool:
    return rng is None or (key.isdigit() and rng[0] <= int(key) <= rng[1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batch", type=Path)
    ap.add_argument("--groups", default="", help="comma-separated integer ranges of frame names (e.g. 0-24,25-50)")
    args = ap.parse_args(argv)
    first = args.batch / "first_pass"
    frames = frames_of(first)
    groups = [("all", None)] + [(g, tuple(int(x) for x in g.split("-"))) for g in filter(None, args.groups.split(","))]
    objects = {k: n for k, _, n, _ in frames}
    for label, rng in groups:
        chosen = [(k, c) for k, c, _, _ in frames if in_group(k, rng)]
        for reading, given in READINGS.items():
            pool = D.DataSet.from_first_pass(chosen, first, ("log_focal",),
                                             focal_given_orientation=given).pools["log_focal"]
            for cam, (keys, m, p) in pool.groups.items():
                if sum(c == cam for _, c in chosen) < 10 or (est := pool.estimate(cam)) is None:
                    continue
                truths = {t for k, c, _, t in frames if c == cam}
                truth = truths.pop() if len(truths) == 1 else None
                sd = math.sqrt(est.var)
                line = (f"{label:6s} {reading:6s} {cam[:18]:18s} µ {math.exp(est.center):7.1f} px  sd {sd:.3f}  "
                        f"n {est.frames}/{est.check.offered}  n_eff {est.check.n_eff:4.1f}  D {est.check.d:+5.2f}")
                if truth:
                    line += f"  {100 * (math.exp(est.center) / truth - 1):+5.1f} %  z {(est.center - math.log(truth)) / sd:+5.2f} |"
                    for lo, hi, lab in ((1, 1, "1"), (2, 2, "2"), (3, 10**6, "3+")):
                        e = [100 * (math.exp(v) / truth - 1) for k, v in zip(keys, m) if lo <= objects[k] <= hi]
                        line += f"  {lab}: {np.median(e):+6.1f} % ({len(e)})" if e else f"  {lab}: -"
                print(line)


if __name__ == "__main__":
    main()
