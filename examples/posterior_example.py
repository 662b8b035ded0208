"""The posterior of a scene: summary, diagnostics, NetCDF and figures, from Python.

    python examples/posterior_example.py [SCENE.json] [--out DIR] [--min-ess N]

Without SCENE.json it uses the synthetic example scene shipped with the package. Writes
result.json, posterior.nc and the figures of `creference plot` into DIR (default: ./posterior_example).
"""

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import creference_bayes as cb  # noqa: E402
from creference_bayes.cli import example_scene_path, format_tables  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
parser.add_argument("scene", nargs="?", default=None, metavar="SCENE.json",
                    help="a scene file, either format (default: the shipped example scene)")
parser.add_argument("--out", default="posterior_example", metavar="DIR",
                    help="folder for the result, the NetCDF file and the figures (default: %(default)s)")
parser.add_argument("--min-ess", type=float, default=400, metavar="N",
                    help="bulk ESS the sampler runs to (default: %(default)s; less for a quick look)")
args = parser.parse_args()

from creference_bayes.io.files import atomic_path  # noqa: E402
from creference_bayes.vision import plotting  # noqa: E402

scene = cb.load_scene(args.scene or example_scene_path())
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)

result = cb.estimate(scene, seed=0, hdi_prob=0.9, sampling={"min_ess": args.min_ess}, progress=sys.stderr.isatty())
d = result.to_dict()
print(format_tables(d))
for w in result.warnings:
    print("note:", w)
print(result.summary().round(4).to_string())  # MAP, mean, sd, median, HDI, ESS, R-hat per quantity
idata = result.to_inference_data()  # arviz: az.summary(idata), az.loo(idata), az.plot_trace(idata)
if idata is not None:
    with atomic_path(out / "posterior.nc") as tmp:
        idata.to_netcdf(tmp)
result.save(out / "result.json")
figures = plotting.scene_figures(scene, d, result.draws)
for name, fig in figures.items():
    with atomic_path(out / f"{name}.png") as tmp:
        fig.savefig(tmp, dpi=110)
print(f"wrote {out}/: result.json, {'posterior.nc, ' if idata is not None else ''}"
      f"{', '.join(f + '.png' for f in figures)}")
