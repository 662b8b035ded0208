"""The public entry point: :func:`estimate` one scene's target, from scene to :class:`Result`.

Data flow (one way): scene → camera/horizon → references → model per handedness → MAP →
(posterior) → result. Each stage lives in its own module; this one only wires them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .geometry import HANDEDNESS, Camera
from .metrics import location_percentage_error
from .model import PaperModel
from .optimize import optimize_map, preset_bounds
from .result import Evaluation, Result
from .scene import Scene, load_scene

__all__ = ["MODELS", "estimate", "build_models"]

MODELS = ("paper",)


def build_models(scene: Scene, *, model: str = "paper", preset: str = "default",
                 camera: Camera | None = None, constraints=None, **options) -> list:
    """One model per handedness for ``scene``.

    Parameters
    ----------
    model : one of :data:`MODELS`
    preset : optimiser preset; it decides the bounds
    camera : the camera (defaults to the scene's; pass one with an estimated horizon)
    constraints : soft constraints from the references (paper model), or None
    options : model settings (``sigma`` for the paper model)
    """
    if model not in MODELS:
        raise ValueError(f"model: unknown model {model!r} (expected one of {list(MODELS)})")
    bounds = preset_bounds(preset, scene.image_width, scene.image_height)
    unknown = set(options) - {"sigma"}
    if unknown:
        raise ValueError(f"model options: unknown option(s) {sorted(unknown)} for model {model!r}")
    return [PaperModel.from_scene(scene, h, bounds=bounds, constraints=constraints,
                                  camera=camera, **options) for h in HANDEDNESS]


def estimate(scene: Scene | str | Path, *, preset: str = "default", model: str = "paper",
             use_references: bool = True, seed=None, **options) -> Result:
    """Estimate the target's 3D location in one scene.

    Parameters
    ----------
    scene : a :class:`Scene` or a path to a ``creference-scene/1`` file
    preset : ``default`` (θ scan + local refinement), ``paper`` or ``paper-controlled``
    model : the likelihood model
    use_references : use the scene's reference annotations when it has any
    seed : int or Generator; the same seed gives the same result

    Returns
    -------
    Result
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    rng = np.random.default_rng(seed)
    warnings = list(scene.warnings)
    camera = Camera.from_scene(scene)
    if scene.horizon is None:
        warnings.append("no horizon and no image: assumed a level camera (horizon through the principal point)")
    models = build_models(scene, model=model, preset=preset, camera=camera, **options)
    map_est = optimize_map(models, preset=preset, rng=rng)
    evaluation = None
    if scene.ground_truth is not None:
        evaluation = Evaluation(location_pct_error=float(
            location_percentage_error(map_est.params[:3], scene.ground_truth.location_m)))
    return Result(target=scene.target.id, model=model, preset=preset, map=map_est,
                  scene=scene.source.name if scene.source else None, evaluation=evaluation,
                  warnings=tuple(warnings))
