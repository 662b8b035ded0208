"""``creference-result/2``: the estimate of a frame — the shared camera and every target.

The result records how it was made (``provenance``: the model's options, the camera's treatment,
the seed, the sampler settings, the classes given by the user; ``pilot_camera`` and each target's
``handedness``), so :func:`creference_bayes.frame_pipeline.rebuild_model` makes the same model
again from the result and its scene in one call. See docs/result_format.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models.frame import C_HEIGHT, CAMERA_NAMES, O_GROUND, O_SIZE, O_YAW, OBJECT_NAMES

__all__ = ["FRAME_RESULT_FORMAT", "RESULT_DRAWS", "FrameResult", "StoredDraws", "hdi", "stored_draws"]

FRAME_RESULT_FORMAT = "creference-result/2"
#: Posterior draws a result keeps (``draws``: evenly spaced over every chain's draws), enough for
#: the labels' P(IoU ≥ t) to about ±0.025 and small enough for a batch of thousands of frames.
RESULT_DRAWS = 400
#: Decimals of the kept draws (10 µm, 10 µrad, 10⁻⁵ px).
DRAW_DECIMALS = 5
OBJECT_REPORT = ("x", "y", "z", "yaw", "length_m", "width_m", "height_m", "ground_m", "distance_m")


def hdi(samples: np.ndarray, prob: float) -> np.ndarray:
    """Highest-density interval of each column of (N, k) samples: the narrowest window holding
    ``prob`` of the sorted draws, (k, 2)."""
    x = np.sort(np.asarray(samples, float), axis=0)
    n = len(x)
    w = max(1, min(n - 1, int(np.floor(prob * n))))
    widths = x[w:] - x[:n - w]
    i = np.argmin(widths, axis=0)
    cols = np.arange(x.shape[1])
    return np.column_stack([x[i, cols], x[i + w, cols]])


def _object_table(cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
    """(N, m, 9) reported quantities: x, y = camera height − ground, z, yaw, sizes, ground, distance."""
    y = cams[:, C_HEIGHT, None] - objs[..., O_GROUND]
    d = np.hypot(objs[..., 0], objs[..., 1])
    return np.concatenate([objs[..., :1], y[..., None], objs[..., 1:2], objs[..., O_YAW:O_YAW + 1],
                           objs[..., O_SIZE], objs[..., O_GROUND:O_GROUND + 1], d[..., None]], axis=-1)


def _summary(x: np.ndarray, prob: float) -> dict:
    iv = hdi(x, prob)
    return {"mean": x.mean(axis=0), "median": np.median(x, axis=0), "sd": x.std(axis=0, ddof=1), "hdi": iv}


@dataclass(frozen=True)
class StoredDraws:
    """Draws read back from a result's ``draws``: cameras (1, n, 5), objects (1, n, m, 7), natural
    parameters in the order of ``CAMERA_NAMES`` and ``OBJECT_NAMES`` (one chain: the kept draws
    of every chain, in the sampler's chain-major order)."""

    cameras: np.ndarray
    objects: np.ndarray


def _column(v: np.ndarray):
    """A kept column: one number when every draw has it (a fixed parameter), else the list."""
    v = np.round(np.asarray(v, float), DRAW_DECIMALS)
    return float(v[0]) if np.all(v == v[0]) else v.tolist()


def _keep_draws(cams: np.ndarray, objs: np.ndarray, n_keep: int) -> dict:
    n = len(cams)
    idx = np.unique(np.linspace(0, n - 1, min(n_keep, n)).round().astype(int))
    return {"n": int(len(idx)), "of": int(n),
            "camera": {k: _column(cams[idx, j]) for j, k in enumerate(CAMERA_NAMES)},
            "objects": [{k: _column(objs[idx, i, j]) for j, k in enumerate(OBJECT_NAMES)}
                        for i in range(objs.shape[1])]}


def stored_draws(d: dict) -> StoredDraws | None:
    """The draws a ``creference-result/2`` dict keeps (its ``draws``), or None when it has none
    (a result made with ``posterior=False`` or ``keep_draws=0``).

    Raises
    ------
    ValueError : ``draws`` is malformed (names the key)
    """
    kept = d.get("draws")
    if not kept:
        return None
    try:
        n = int(kept["n"])
        col = lambda v: np.broadcast_to(np.asarray(v, float), (n,))
        cams = np.column_stack([col(kept["camera"][k]) for k in CAMERA_NAMES])
        objs = np.stack([np.column_stack([col(o[k]) for k in OBJECT_NAMES]) for o in kept["objects"]], axis=1)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"draws: not the draws of a creference-result/2 ({' '.join(str(exc).split())})") from None
    if not (np.all(np.isfinite(cams)) and np.all(np.isfinite(objs))):
        raise ValueError("draws: expected finite numbers")
    if objs.shape[1] != len(d.get("objects", ())):
        raise ValueError(f"draws.objects: {objs.shape[1]} objects, the result has {len(d.get('objects', ()))}")
    return StoredDraws(cams[None], objs[None])


def _r(v, nd=6):
    return None if v is None or not np.isfinite(v) else round(float(v), nd)


@dataclass(frozen=True)
class FrameResult:
    """The estimate of one frame (module docstring); :meth:`to_dict` is the file."""

    data: dict
    draws: object = None
    diagnostics: object = None
    warnings: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool | None:
        return None if self.diagnostics is None else bool(self.diagnostics.converged)

    def to_dict(self) -> dict:
        return self.data

    @classmethod
    def build(cls, frame, model, setup, map_est, draws, diag, *, hdi_prob: float, provenance: dict,
              seconds: float, keep_draws: int = RESULT_DRAWS) -> "FrameResult":
        warnings = list(frame.warnings) + list(setup.notes)
        cam_map = {n: _r(v) for n, v in zip(CAMERA_NAMES, map_est.camera)}
        camera = {"map": cam_map, "free": [n for n, f in zip(CAMERA_NAMES, model.camera_free) if f],
                  "setup": setup.to_dict()}
        objs_map = _object_table(map_est.camera[None], map_est.objects[None])[0]
        post_obj = post_cam = kept = None
        if draws is not None:
            cams = draws.cameras.reshape(-1, 5)
            objs = draws.objects.reshape(-1, model.n_objects, 7).copy()
            yaw0 = map_est.objects[:, O_YAW]
            objs[..., O_YAW] = yaw0 + (objs[..., O_YAW] - yaw0 + np.pi) % (2 * np.pi) - np.pi
            table = _object_table(cams, objs)  # (N, m, 9)
            if keep_draws > 0:
                kept = _keep_draws(cams, objs, keep_draws)
            post_obj = [_summary(table[:, i], hdi_prob) for i in range(model.n_objects)]
            post_cam = _summary(cams, hdi_prob)
            camera["posterior"] = {k: {n: _r(v) for n, v, f in zip(CAMERA_NAMES, post_cam[k], model.camera_free) if f}
                                   for k in ("mean", "median", "sd")}
            camera["posterior"]["hdi"] = {n: [_r(a), _r(b)] for n, (a, b), f in
                                          zip(CAMERA_NAMES, post_cam["hdi"], model.camera_free) if f}
            camera["posterior"]["hdi"]["prob"] = hdi_prob
            if not diag.converged:
                warnings += list(diag.warnings)
        objects = []
        for i, (t, o) in enumerate(zip(frame.targets, model.objects)):
            entry = {"id": t.id, "class": t.cls, "handedness": int(map_est.handedness[i]),
                     "size": "known" if o.sizes is not None else "class prior",
                     "n_annotations": len(o.annotations), "sigma_px": _r(model.sigma[i], 3),
                     "map": {n: _r(v) for n, v in zip(OBJECT_REPORT, objs_map[i])}}
            if post_obj is not None:
                p = post_obj[i]
                entry["posterior"] = {k: {n: _r(v) for n, v in zip(OBJECT_REPORT, p[k])} for k in ("mean", "median", "sd")}
                entry["posterior"]["hdi"] = {n: [_r(a), _r(b)] for n, (a, b) in zip(OBJECT_REPORT, p["hdi"])}
                entry["posterior"]["hdi"]["prob"] = hdi_prob
                if t.ground_truth is not None:
                    entry["evaluation"] = _evaluate(t.ground_truth, objs_map[i], p)
            elif t.ground_truth is not None:
                entry["evaluation"] = _evaluate(t.ground_truth, objs_map[i], None)
            objects.append(entry)
        from .frame_scene import frame_fingerprint

        data = {"format": FRAME_RESULT_FORMAT,
                "scene": frame.source.name if frame.source else None, "scene_format": frame.format,
                "scene_id": {"sha256": frame_fingerprint(frame)},
                "image_size": [frame.image_width, frame.image_height],
                "camera": camera, "objects": objects,
                "map_info": {k: _r(v, 4) if isinstance(v, float) else v for k, v in map_est.info.items()},
                "diagnostics": None if diag is None else diag.to_dict(),
                "pilot_camera": None if model.pilot is None else [float(v) for v in model.pilot],
                "provenance": provenance, "seconds": round(seconds, 3), "warnings": warnings}
        if kept is not None:
            data["draws"] = kept
        return cls(data, draws, diag, tuple(warnings))


def _evaluate(truth: dict, map_row: np.ndarray, post: dict | None) -> dict:
    loc = np.asarray(truth["location_m"], float)
    est = map_row[[0, 1, 2]]
    out = {"location_pct_error": _r(100 * np.linalg.norm(est - loc) / np.linalg.norm(loc), 4)}
    if post is not None:
        mean = post["mean"][[0, 1, 2]]
        out["posterior_location_pct_error"] = _r(100 * np.linalg.norm(mean - loc) / np.linalg.norm(loc), 4)
        d = float(np.hypot(loc[0], loc[2]))
        lo, hi = post["hdi"][OBJECT_REPORT.index("distance_m")]
        out["distance_in_hdi"] = bool(lo <= d <= hi)
        inside = {}
        for k, v in (("x", loc[0]), ("z", loc[2])):
            a, b = post["hdi"][OBJECT_REPORT.index(k)]
            inside[k] = bool(a <= v <= b)
        out["in_hdi"] = inside
    return out
