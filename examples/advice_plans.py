"""The advice on a few frames, its CPU seconds and what it recommends, and the same against an
earlier run (docs/studies/advice.md, "Cheaper summaries").

    python examples/advice_plans.py SCENES/000000.json SCENES/000032.json --out before/ --seeds 0 1
    # ... change the code, then:
    python examples/advice_plans.py SCENES/000000.json SCENES/000032.json --out after/ --seeds 0 1 --against before/

Each scene is estimated once (``estimate(scene, seed=0)``, its result kept in ``--out`` and read
again by later runs with the same ``--out``, so that a comparison sees the same draws: copy the
results into the second folder first) and advised at each seed (``advise_result``'s defaults), in
CPU seconds of this process (``process_time``) with one BLAS thread, as ``creference advise``
runs. Each advice's JSON is written to ``--out``. Prints a Markdown table: per frame and seed the
CPU seconds (and those of ``--against``), the recommended request, the plan (each target's
request) and the verdicts (g good, l lift, n none), whether those are the same in ``--against``,
and the largest change of a request's stated good-label gain.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def summary(advice: dict) -> tuple:
    """(recommended, plan, verdicts) of an advice JSON."""
    plan = ", ".join(r for r in advice["requests"] if r) or "–"
    return advice["recommended"] or "–", plan, "".join(v["verdict"][0] for v in advice["verdicts"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenes", nargs="+", type=Path)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--against", type=Path, help="a folder of an earlier run of this script")
    args = p.parse_args(argv)

    from creference_bayes.inference.threads import single_threaded_blas
    from creference_bayes.io.scene import load_scene
    from creference_bayes.pipeline import estimate
    from creference_bayes.workflows.advice.inputs import advise_result

    args.out.mkdir(parents=True, exist_ok=True)
    print("| frame | seed | estimate CPU s | advice CPU s" + (", before → after" if args.against else "")
          + " | recommended | plan | verdicts |" + (" the same before | largest change of a stated gain |"
                                                     if args.against else ""))
    print("|---|---|---|---|---|---|---|" + ("---|---|" if args.against else ""))
    for path in args.scenes:
        scene = load_scene(path)
        kept = args.out / f"{path.stem}.result.json"
        if not kept.exists():
            with single_threaded_blas():
                start = time.process_time()
                result = estimate(scene, seed=0).to_dict()
                result["cpu_s"] = time.process_time() - start
            kept.write_text(json.dumps(result))
        result = json.loads(kept.read_text())
        for seed in args.seeds:
            start = time.process_time()
            advice = advise_result(result, scene, seed=seed).to_dict()
            advice["cpu_s"] = time.process_time() - start
            (args.out / f"{path.stem}_{seed}.json").write_text(json.dumps(advice))
            cpu, row = f"{advice['cpu_s']:.1f}", summary(advice)
            tail = ""
            if args.against:
                old = json.loads((args.against / f"{path.stem}_{seed}.json").read_text())
                cpu = f"{old['cpu_s']:.1f} → {cpu}"
                gains = {q["candidate"]["key"]: q["good_gain"] for q in old["predictions"]}
                moved = max((abs(q["good_gain"] - gains[q["candidate"]["key"]]) for q in advice["predictions"]),
                            default=0.0)
                tail = f" {'yes' if summary(old) == row else 'no: ' + ' / '.join(summary(old))} | {moved:.2f} |"
            print(f"| {path.stem} | {seed} | {result['cpu_s']:.1f} | {cpu} | {' | '.join(row)} |{tail}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
