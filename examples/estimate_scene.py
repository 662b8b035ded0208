"""Estimate a scene's target from Python: the MAP and its error against the ground truth."""

import sys

import creference_bayes as cb
from creference_bayes.cli.main import example_scene_path

path = sys.argv[1] if len(sys.argv) > 1 else example_scene_path()
result = cb.estimate(path, seed=0)
print("MAP:", result.to_dict()["map"])
if result.evaluation is not None:
    print(f"location error: {result.evaluation.location_pct_error:.2f} %")
