"""The posterior of a scene's target: summary, diagnostics, NetCDF and figures, from Python.

    python examples/posterior_example.py [SCENE.json] [--out DIR] [--min-ess N]

Without SCENE.json it uses the synthetic example scene shipped with the package. Writes
result.json, posterior.nc and four PNG figures into DIR (default: ./posterior_example).
"""

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import creference_bayes as cb  # noqa: E402
from creference_bayes.cli.main import example_scene_path  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
parser.add_argument("scene", nargs="?", default=None, metavar="SCENE.json",
                    help="a creference-scene/1 file (default: the shipped example scene)")
parser.add_argument("--out", default="posterior_example", metavar="DIR",
                    help="folder for the result, the NetCDF file and the figures (default: %(default)s)")
parser.add_argument("--min-ess", type=float, default=1000, metavar="N",
                    help="bulk ESS the sampler runs to (default: %(default)s; less for a quick look)")
args = parser.parse_args()

from creference_bayes.inference.summary import summary_table  # noqa: E402
from creference_bayes.io.scene import load_scene  # noqa: E402
from creference_bayes.vision import plotting  # noqa: E402

scene = load_scene(args.scene or example_scene_path())
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)

result = cb.estimate(scene, seed=0, hdi_prob=0.9, sampling={"min_ess": args.min_ess},
                     progress=sys.stderr.isatty())
post, diag = result.posterior, result.diagnostics
print(f"handedness {post.handedness:+d}, temperature {post.temperature:g}, {post.n_draws} draws")
for name in ("x", "z", "distance_m"):
    lo, hi = post.hdi[name]
    print(f"{name:>10}: posterior mean {post.mean[name]:.3f} m, {post.hdi_prob:.0%} HDI [{lo:.3f}, {hi:.3f}]")
print(f"converged: {diag.converged}  R-hat max {max(v for v in diag.r_hat.values() if v):.4f}  "
      f"bulk ESS min {min(v for v in diag.ess_bulk.values() if v):.0f}  ({diag.seconds:.2f} s)")
for w in diag.warnings:
    print("  ", w)
if result.evaluation is not None:
    ev = result.evaluation
    print(f"location error: MAP {ev.location_pct_error:.2f} %, posterior mean "
          f"{ev.posterior_location_pct_error:.2f} %; truth in HDI: {ev.in_hdi}")

print(summary_table(result.inference_data))  # az.summary, yaw as a circular variable
result.inference_data.to_netcdf(out / "posterior.nc")
result.to_json(out / "result.json")

d = result.to_dict()
draws = plotting.draws_from_result(d, result.inference_data)
figures = {"boxes": plotting.plot_boxes(d, scene, draws),
           "pairs": plotting.plot_pairs(draws, result=d, truth=plotting._truth(scene)),
           "ranks": plotting.plot_ranks(draws, result=d),
           "top_view": plotting.plot_top_view(d, draws, scene=scene)}
for name, fig in figures.items():
    fig.savefig(out / f"{name}.png", dpi=110)
print(f"wrote {out}/: result.json, posterior.nc and {', '.join(f + '.png' for f in figures)}")
