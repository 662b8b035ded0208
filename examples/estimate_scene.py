"""Estimate a scene from Python: the MAP of its camera and of every object, with ground truth
their location errors.

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
                        help="a scene file, either format (default: the shipped example scene)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    args = parser.parse_args(argv)
    d = cb.estimate(args.scene or example_scene_path(), seed=args.seed, posterior=False).to_dict()
    print("camera:", {k: round(v, 4) for k, v in d["camera"]["map"].items()})
    for o in d["objects"]:
        error = (o.get("evaluation") or {}).get("location_pct_error")
        print(f"{o['id']}:", {k: round(v, 4) for k, v in o["map"].items()},
              "" if error is None else f"location error {error:.2f} %")


if __name__ == "__main__":
    main()
