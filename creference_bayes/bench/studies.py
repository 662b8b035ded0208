"""The benchmark's studies of the camera (pitch and roll without a horizon, the focal-length
prior) and of exact references, run by :func:`~.runner.run_bench` next to its main estimators."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..io.scene import Scene
from .runner import BenchConfig, _estimate, _parse, _posterior_fields, _record, variant
from .simulate import simulate_scene

__all__ = ["CAMERA_STUDIES", "camera_records", "exact_reference_scenes", "exact_reference_records"]


#: The camera studies' estimators and the estimate options that make them.
CAMERA_STUDIES = {"ours-metrology-nohorizon": {"orientation": "auto"},
                  "ours-metrology-flatfocal": {"focal_prior": "none"}}


def camera_records(sid: str, scene: Scene, config: BenchConfig, seed: int, truth: dict) -> list[dict]:
    """The metrology model without the horizon and with a flat focal prior, at 0 and all refs."""
    from .crb import cramer_rao_scene

    nt, all_refs = config.n_target, tuple(range(len(scene.references)))
    recs = []
    for name, refs in (("crb-target-nohorizon", False), ("crb-refs-nohorizon", True)):
        c = cramer_rao_scene(scene, n_annotations=nt, references=refs, orientation_free=True)
        recs.append(_record(sid, scene, name, n_target=nt, n_refs=len(all_refs) if refs else 0,
                            error=c.median_pct, rmse=c.rmse_pct))
    for estimator, options in CAMERA_STUDIES.items():
        base = replace(scene, horizon=None) if estimator.endswith("nohorizon") else scene
        for k in sorted({0, len(all_refs)}):
            post = k in config.posterior_ref_counts
            res = _estimate(variant(base, nt, all_refs[:k]), "metrology", "default", seed, posterior=post,
                            sampling=config.sampler, **options)
            rec = _record(sid, scene, estimator, model="metrology", preset="default", n_target=nt, n_refs=k,
                          error=res.evaluation.location_pct_error, seconds=res.map.seconds,
                          handedness_ok=res.map.handedness == scene.ground_truth.extra["handedness"])
            if post and res.posterior is not None:
                rec.update(_posterior_fields(res, truth))
            recs.append(rec)
    return recs


def exact_reference_scenes(n: int, seed: int = 0) -> list[tuple[str, Scene]]:
    """Noise-free outdoor scenes as annotation tools store them (0.01 px): targets 25–45 m away,
    pitch, roll up to 5°, an off-centre principal point, 13 exact target annotations and 20 exact
    references (single values, stated to 4 significant digits)."""
    out = []
    for i in range(n):
        d = simulate_scene(np.random.default_rng([seed, 99, i]), setting="outdoor", tier="none",
                           n_references=20, principal_offset=0.08, roll_deg=5.0,
                           distance_range=(25.0, 45.0), single_values=True)
        out.append((f"exact-outdoor-{i:02d}", _parse(d)))
    return out


def exact_reference_records(n: int, seed: int = 0, say=lambda s: None) -> list[dict]:
    """The default estimator's MAP on :func:`exact_reference_scenes`, with and without the references
    (exact references must help, never hurt)."""
    recs = []
    for sid, scene in exact_reference_scenes(n, seed):
        errors = {}
        for k in (0, len(scene.references)):
            res = _estimate(variant(scene, len(scene.target.dimension_lines), tuple(range(k))),
                            "metrology", "default", seed)
            errors[k] = res.evaluation.location_pct_error
            recs.append(_record(sid, scene, "exact-metrology", n_target=len(scene.target.dimension_lines),
                                n_refs=k, error=errors[k]))
        say(f"{sid}: exact references {errors}")
    return recs
