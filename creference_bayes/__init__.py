"""creference_bayes: 3D locations of objects from rough crowd annotations on one photo.

The C-Reference method (Song et al., CSCW 2020) as a Bayesian estimator: the annotations'
negative log-likelihood and the priors make a posterior over the camera and every annotated
object; its MAP seeds an emcee run, and the result reports the estimate, credible regions and
diagnostics. A scene is one photo with one or more targets (a one-target scene is a frame of one).

Layout (each folder uses only the folders below it)::

    cli/         the ``creference`` command, one module per command group
    workflows/   batch runs over a data set, labels, advice on more annotations, confidence maps
    bench/       simulator, benchmark, report, figures, peers (PoseLib), Cramér–Rao bound
    pipeline.py  estimate(): a scene, from its file to its Result (the wiring)
    evaluation/  KITTI's AP3D and the labels' reliability
    vision/      OpenCV horizon, matplotlib figures
    inference/   MAP, the emcee adapter (driver and moves), the arviz adapter
    io/          scene and result files, labels, Label Studio / CVAT import
    models/      the model contract and its two models (metrology, the paper's), priors
    core/        units, geometry, ground-plane metrology, costs, metrics (NumPy/SciPy only)

Quick start::

    import creference_bayes as cb
    result = cb.estimate("scene.json", seed=0)
    print(result.to_dict()["objects"][0]["map"])
"""

__version__ = "0.2.0"

import os as _os

# Every array this package factors is tiny (4x4 solves, 5x5 Hessians): a threaded BLAS only adds
# overhead. Applies when numpy is not imported yet and the user has not chosen a thread count;
# estimate() also limits an already-loaded BLAS to one thread while it runs (inference/threads.py).
_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_USER_SET_THREADS = any(_var in _os.environ for _var in _THREAD_VARS)
for _var in _THREAD_VARS:
    _os.environ.setdefault(_var, "1")

from .core.metrics import (location_percentage_error, percentage_error, range_percentage_error,
                           range_precision)
from .io.result import Result, load_result
from .io.scene import Scene, SceneError, SceneWarning, load_scene, parse_scene
from .inference import threads as _threads
from .pipeline import estimate

_threads.USER_SET_THREADS = _USER_SET_THREADS

__all__ = ["__version__", "estimate", "load_scene", "parse_scene", "load_result", "Scene", "SceneError",
           "SceneWarning", "Result", "percentage_error", "range_percentage_error",
           "location_percentage_error", "range_precision"]
