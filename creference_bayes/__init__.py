"""creference_bayes: 3D location of a target object from rough crowd annotations on one photo.

The C-Reference method (Song et al., CSCW 2020) as a Bayesian estimator: the paper's cost is a
negative log-posterior over (x, y, z, yaw, focal length); its MAP seeds an emcee ensemble.

Layout (each folder uses only the folders below it)::

    cli/         the ``creference`` command, one module per command group
    workflows/   batch runs over a data set, advice on more annotations, confidence maps
    bench/       simulator, benchmark, report, figures, peers (PoseLib), Cramér–Rao bound
    pipeline.py  estimate(): one scene's target, from scene to Result (the wiring)
    vision/      OpenCV horizon, matplotlib plots
    inference/   optimiser presets, log-posterior, emcee adapter, arviz adapter
    io/          scene and result files
    models/      the paper model, the metrology model, their shared parameter space
    core/        units, geometry, ground-plane metrology, costs, metrics (NumPy/SciPy only)

Quick start::

    import creference_bayes as cb
    result = cb.estimate("scene.json", seed=0)
    print(result.to_dict()["map"])
"""

__version__ = "0.1.0"

import os as _os

# Every array this package factors is tiny (4x4 solves, 8x4 batches, 5x5 Hessians); a threaded
# BLAS only adds overhead there (measured: 0.93 s vs 0.13 s per MAP on 2 cores). Applies only when
# numpy is not imported yet and the user has not chosen a thread count; estimate() also limits an
# already-loaded BLAS to one thread while it runs (inference/threads.py), unless the user chose.
_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_USER_SET_THREADS = any(_var in _os.environ for _var in _THREAD_VARS)
for _var in _THREAD_VARS:
    _os.environ.setdefault(_var, "1")

from .core.metrics import (location_percentage_error, percentage_error, range_percentage_error,
                           range_precision)
from .io.result import MapEstimate, Result
from .io.scene import Scene, SceneError, SceneWarning, load_scene, parse_scene
from .inference import threads as _threads
from .pipeline import estimate
from .frame_pipeline import estimate_frame

_threads.USER_SET_THREADS = _USER_SET_THREADS

__all__ = [
    "__version__",
    "estimate",
    "estimate_frame",
    "load_scene",
    "parse_scene",
    "Scene",
    "SceneError",
    "SceneWarning",
    "Result",
    "MapEstimate",
    "percentage_error",
    "range_percentage_error",
    "location_percentage_error",
    "range_precision",
]
