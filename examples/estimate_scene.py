"""Estimate a scene's target from Python: the MAP and, with ground truth, its location error.

    python examples/estimate_scene.py [SCENE.json] [--seed 0]

Without SCENE.json it uses the synthetic example scene shipped with the package. Writes nothing.
"""

import argparse

import creference_bayes as cb
from creference_bayes.cli.main import example_scene_path


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", nargs="?", default=None, metavar="SCENE.json",
                        help="a creference-scene/1 file (default: the shipped example scene)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    args = parser.parse_args(argv)
    result = cb.estimate(args.scene or example_scene_path(), seed=args.seed, posterior=False)
    print("MAP:", {k: round(v, 4) for k, v in result.to_dict()["map"].items()})
    if result.evaluation is not None:
        print(f"location error: {result.evaluation.location_pct_error:.2f} %")


if __name__ == "__main__":
    main()
