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
    for obj in result.objects:                 # MAP location (m), ground distance and its HDI
        print(obj.id, obj.location_m, obj.distance_m, obj.hdi.get("distance_m"))
    print(result.summary())                    # a table: MAP, mean, sd, HDI, ESS, R-hat
    idata = result.to_inference_data()         # arviz: az.loo(idata), az.plot_posterior(idata)
    result.save("result.json")                 # cb.load_result("result.json") reads it back

The package leaves the process's environment alone: it limits the BLAS to one thread only while
its own numerics run (:mod:`.inference.threads`).
"""

__version__ = "0.2.0"

from .core.metrics import (location_percentage_error, percentage_error, range_percentage_error,
                           range_precision)
from .io.result import CameraEstimate, ObjectEstimate
from .io.scene import Scene, SceneError, SceneWarning, load_scene, parse_scene
from .pipeline import EstimateSettings, Result, ResultWarning, estimate, load_result

__all__ = ["__version__", "estimate", "EstimateSettings", "load_scene", "parse_scene", "load_result", "Scene", "SceneError",
           "SceneWarning", "Result", "ResultWarning", "ObjectEstimate", "CameraEstimate", "percentage_error", "range_percentage_error",
           "location_percentage_error", "range_precision"]
