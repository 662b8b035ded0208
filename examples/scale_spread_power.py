"""How often the data set reads its frames' corner scales as a spread (docs/studies/rig.md, "Frames
that name their setting"; workflows/batch/dataset.py, ``scale_spread``).

    python examples/scale_spread_power.py [--trials 300] [--seed 0]

Simulated residual readings, as the first pass's are: frame i's squares σᵢ² χ²(dᵢ) on dᵢ degrees of
freedom. Per crowd (one scale; two, half the frames at 5 px and half at 10 px; one scale with one
frame far off) and number of frames: the share of trials whose readings are read as a spread, at
each ``SPREAD_Z`` (the standard errors the excess over the χ² noise must show), and the median d₀
where they are. Prints a Markdown table.
"""

from __future__ import annotations

import argparse

import numpy as np

from creference_bayes.workflows.batch import dataset as D

#: (name, frames, degrees of freedom a frame (a number, or "1–15": uniform), variances px² of the frames)
CROWDS = (
    ("one scale (5 px)", 80, 3.0, lambda n: np.full(n, 25.0)),
    ("one scale (5 px)", 100, "1–15", lambda n: np.full(n, 25.0)),
    ("one scale, one frame 1000 times too precise", 101, 6.0, lambda n: np.r_[25.0e-3, np.full(n - 1, 25.0)]),
    ("one scale, one frame 50 times too noisy", 101, 6.0, lambda n: np.r_[1250.0, np.full(n - 1, 25.0)]),
    ("two (5 and 10 px)", 40, 3.0, lambda n: np.where(np.arange(n) % 2, 25.0, 100.0)),
    ("two (5 and 10 px)", 80, 3.0, lambda n: np.where(np.arange(n) % 2, 25.0, 100.0)),
    ("two (5 and 10 px)", 200, 2.5, lambda n: np.where(np.arange(n) % 2, 25.0, 100.0)),
    ("two (5 and 10 px)", 48, 15.0, lambda n: np.where(np.arange(n) % 2, 25.0, 100.0)),
)
ZS = (1.0, 1.5, 2.0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=300, help="simulated data sets per row (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    shipped = D.SPREAD_Z
    print("| crowd | frames | dof a frame | " + " | ".join(f"read as a spread, z = {z:g}" for z in ZS)
          + " | median d₀ where read |")
    print("|---|---|---|" + "---|" * len(ZS) + "---|")
    try:
        for name, n, dof, variances in CROWDS:
            rng = np.random.default_rng(args.seed)
            d = rng.uniform(1.0, 15.0, n) if isinstance(dof, str) else np.full(n, dof)
            data = [variances(n) * rng.chisquare(d) for _ in range(args.trials)]
            shares, d0 = [], []
            for z in ZS:
                D.SPREAD_Z = z
                fits = [D.scale_spread(squares, d) for squares in data]
                shares.append(np.mean([f is not None for f in fits]))
                if z == shipped:
                    d0 = [f[1] for f in fits if f is not None]
            median = f"{np.median(d0):.1f}" if d0 else "–"
            print(f"| {name} | {n} | {dof} | " + " | ".join(f"{100 * s:.0f} %" for s in shares) + f" | {median} |")
    finally:
        D.SPREAD_Z = shipped
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
