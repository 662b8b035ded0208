"""The focal length's floor measured on frames whose focal length is known (docs/studies/rig.md,
"The floor, measured"; creference_bayes/workflows/batch/dataset.py).

    python examples/focal_floor.py BATCH [--blocks 3,5,7,10,14] [--partitions 400] [--bootstrap 150] [--group 0-24]

BATCH is a ``creference batch`` folder whose ``first_pass/`` is complete and whose scenes carry the
truth (``ground_truth.focal_length_px``: ``simulate --from-kitti`` writes P2's). For the camera with
the most frames, its informative readings (each frame's focal length read given the other frames'
pooled pitch and roll, what the layer pools) are split at random into disjoint blocks of b frames;
each block is pooled without a floor, and floor² = mean over blocks of (error² − stated variance),
the part of a pool's error its statistical variance does not state. Printed per block size: the
floor (signed square root), the rms stated sd, the rms error, the mean error and the 16–84 %
interval of the floor over bootstrap resamples of the frames. ``--group LO-HI``: only the frames
named LO to HI (integers, e.g. KITTI's index), read and pooled apart. Log µ throughout (natural
log of px).
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from pathlib import Path

import numpy as np

from creference_bayes.workflows.batch import dataset as D

from dataset_pool import frames_of, in_group


def block_errors(m, p, truth, b, partitions, rng):
    """(errors, stated variances) of the pools of disjoint blocks of ``b`` readings, ``partitions``
    random partitions of them."""
    errors, variances = [], []
    for _ in range(partitions):
        order = rng.permutation(len(m))
        for j in range(0, len(m) - b + 1, b):
            block = order[j:j + b]
            center, var, _ = D.combine(m[block], p[block], "shared")
            errors.append(center - truth)
            variances.append(var)
    return np.array(errors), np.array(variances)


def signed_sqrt(x: float) -> float:
    return math.copysign(math.sqrt(abs(x)), x)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batch", type=Path)
    ap.add_argument("--blocks", default="3,5,7,10,14", help="comma-separated block sizes (frames)")
    ap.add_argument("--partitions", type=int, default=400)
    ap.add_argument("--bootstrap", type=int, default=150)
    ap.add_argument("--group", default=None, help="an integer range of frame names (e.g. 0-24)")
    args = ap.parse_args(argv)
    first = args.batch / "first_pass"
    group = tuple(int(x) for x in args.group.split("-")) if args.group else None
    frames = [f for f in frames_of(first) if in_group(f[0], group)]
    camera = Counter(c for _, c, _, _ in frames if c is not None).most_common(1)[0][0]
    truths = {t for _, c, _, t in frames if c == camera}
    if len(truths) != 1 or None in truths:
        raise SystemExit(f"{camera}: the scenes do not carry one true focal length (ground_truth.focal_length_px)")
    truth = math.log(truths.pop())
    pool = D.DataSet.from_first_pass([(k, c) for k, c, _, _ in frames], first, ("log_focal", "pitch", "roll"))
    _, m, p = pool.pools["log_focal"].groups[camera]
    keep = p >= D.SHARED["log_focal"].max_sd ** -2
    m, p = m[keep], p[keep]
    center, var, _ = D.combine(m, p, "shared")
    print(f"{camera}: {keep.sum()} informative readings of {len(keep)}; all: error {center - truth:+.3f}, "
          f"stated sd {math.sqrt(var):.3f}")
    print("b    floor    rms sd   rms error   mean error   bootstrap 16-84 %")
    rng = np.random.default_rng(0)
    for b in (int(v) for v in args.blocks.split(",")):
        if b > len(m):
            continue
        e, v = block_errors(m, p, truth, b, args.partitions, rng)
        boots = []
        for _ in range(args.bootstrap):
            pick = rng.integers(0, len(m), len(m))
            eb, vb = block_errors(m[pick], p[pick], truth, b, max(1, args.partitions // 10), rng)
            boots.append(float(np.mean(eb**2 - vb)))
        lo, hi = np.percentile(boots, [16, 84])
        print(f"{b:<4d} {signed_sqrt(np.mean(e**2 - v)):+.3f}   {math.sqrt(np.mean(v)):.3f}    "
              f"{math.sqrt(np.mean(e**2)):.3f}       {np.mean(e):+.3f}       {signed_sqrt(lo):+.3f} .. {signed_sqrt(hi):+.3f}")


if __name__ == "__main__":
    main()
