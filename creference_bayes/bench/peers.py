"""The peer solver: PoseLib's P4Pf (absolute pose with unknown focal length), a thin adapter.

The target's dimension lines give four 2D–3D correspondences in the object frame (c1..c4 of
:func:`~creference_bayes.core.geometry.dimension_corners`), exactly P4Pf's minimal problem. The peer:

1. solves P4Pf on the per-corner median of the annotations and on each annotation alone, for both
   handednesses (every real solution is a hypothesis). With noisy corners P4Pf (eight equations,
   seven unknowns) often has no real solution; then only, the hypotheses come from PoseLib's
   calibrated absolute pose (P3P in LO-RANSAC) at each focal length of :data:`FALLBACK_FOCALS`,
   and ``info["fallback"]`` says so;
2. refines each by least squares over all annotations' corners: ``refine_absolute_pose`` at a
   given focal length inside a bounded 1D search over log µ (PoseLib's API refines the pose only);
3. keeps the hypothesis with the smallest reprojection error.

The location is reported in the gravity-aligned frame G: with a horizon, G's rotation is R(µ) from
the horizon and the peer's µ; without one, gravity is the box's vertical axis as the peer estimated
it. The peer uses no references. PoseLib is optional (the ``peer`` extra): importing this module
works without it, :func:`estimate_p4pf` then raises an ImportError that says what to install.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from ..core.geometry import HANDEDNESS, Camera, dimension_corners
from ..core.metrics import location_percentage_error

__all__ = ["PeerEstimate", "estimate_p4pf", "poselib_available", "INSTALL_HINT"]

INSTALL_HINT = "the p4pf peer needs PoseLib: pip install creference-bayes[peer]"
#: The 1D focal search spans ±this in log µ around each hypothesis' focal length.
LOG_FOCAL_SPAN = 0.7
#: Focal lengths (pixels, relative to the image's larger side) tried when P4Pf has no solution.
FALLBACK_FOCALS = np.geomspace(0.15, 4.0, 16)


def _poselib():
    try:
        import poselib
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(INSTALL_HINT) from exc
    return poselib


def poselib_available() -> bool:
    """Whether PoseLib can be imported."""
    try:
        _poselib()
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class PeerEstimate:
    """The peer's estimate of the target.

    Attributes
    ----------
    params : (5,) x, y, z (m, gravity-aligned frame), yaw (rad), focal length (px)
    handedness : +1 or −1
    rms_px : root-mean-square reprojection error over all annotation corners, pixels
    seconds : wall time
    n_hypotheses : P4Pf solutions tried
    rotation, translation : the peer's own pose, object frame → camera frame (Pc = R·X + t): (3, 3)
        and (3,) metres. ``params`` re-expresses it in G; the box's tilt against gravity, which
        P4Pf is free to estimate, is dropped there (the package's pose has yaw only)
    info : what happened (plain dict)
    """

    params: np.ndarray
    handedness: int
    rms_px: float
    seconds: float
    n_hypotheses: int
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3), repr=False)
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)
    info: dict = field(default_factory=dict)

    def location_error(self, truth) -> float:
        """Eq. 3 against a true location (3,), percent."""
        return float(location_percentage_error(self.params[:3], truth))

    def to_dict(self) -> dict:
        keys = ("x", "y", "z", "yaw", "focal_length_px")
        return {"map": {k: float(v) for k, v in zip(keys, self.params)}, "handedness": self.handedness,
                "rms_px": self.rms_px, "seconds": self.seconds, "n_hypotheses": self.n_hypotheses,
                "info": dict(self.info)}


def _residual(R, t, f, X, x):
    pc = X @ R.T + t
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = f * pc[:, :2] / pc[:, 2:3]
    r = np.sum((uv - x) ** 2, axis=1)
    return float(np.sum(np.where((pc[:, 2] > 0) & np.isfinite(r), r, 1e12)))


def _refine(pl, pose, f0, X, x, refine: bool):
    """Pose refined at the best focal length near f0; returns (R, t, f, sse in px²)."""
    if not refine:
        return pose.R, pose.t, f0, _residual(pose.R, pose.t, f0, X, x)
    opts = {"loss_type": "TRIVIAL", "max_iterations": 50}

    def at(logf):
        f = float(np.exp(logf))
        cam = {"model": "SIMPLE_PINHOLE", "width": 0, "height": 0, "params": [f, 0.0, 0.0]}
        p, _ = pl.refine_absolute_pose(x, X, pose, cam, opts)
        return p, f, _residual(p.R, p.t, f, X, x)

    lf0 = np.log(f0)
    res = minimize_scalar(lambda lf: at(lf)[2], bounds=(lf0 - LOG_FOCAL_SPAN, lf0 + LOG_FOCAL_SPAN),
                          method="bounded", options={"xatol": 1e-6})
    p, f, sse = at(res.x)
    p0, f0_, sse0 = at(lf0)
    return (p.R, p.t, f, sse) if sse <= sse0 else (p0.R, p0.t, f0_, sse0)


def _gravity_frame(camera: Camera, R_obj: np.ndarray, focal: float) -> np.ndarray:
    """R taking G to camera coordinates: from the horizon, else from the box's vertical."""
    if camera.horizon is not None:
        return camera.rotation(focal)
    e_y = R_obj[:, 1] / np.linalg.norm(R_obj[:, 1])  # the object's +Y (down) in camera coords
    e_z = np.array([0.0, 0.0, 1.0]) - e_y[2] * e_y
    e_z /= np.linalg.norm(e_z)
    return np.column_stack([np.cross(e_y, e_z), e_y, e_z])


def estimate_p4pf(scene, *, annotations: np.ndarray | None = None, camera: Camera | None = None,
                  refine: bool = True, focal_bounds: tuple[float, float] = (50.0, 1e5)) -> PeerEstimate:
    """The P4Pf peer's estimate of the target of ``scene``.

    Parameters
    ----------
    scene : :class:`~creference_bayes.io.scene.Scene` of one target of known size (its size and
        annotations)
    annotations : (n, 4, 2) corners to use instead of all of the scene's, pixels
    camera : principal point and horizon (defaults to the scene's)
    refine : least-squares refinement over all corners (step 2 of the module docstring)
    focal_bounds : hypotheses with µ outside these (pixels) are discarded

    Returns
    -------
    PeerEstimate

    Raises
    ------
    ImportError
        When PoseLib is not installed (``pip install creference-bayes[peer]``).
    RuntimeError
        When P4Pf gives no usable solution for either handedness.
    """
    pl = _poselib()
    t0 = time.perf_counter()
    camera = camera or Camera.from_scene(scene)
    if len(scene.targets) != 1 or scene.targets[0].dimensions is None:
        raise ValueError("p4pf: needs a scene of one target of known size (dimensions_m)")
    t = scene.targets[0]
    size = t.dimensions
    ann = np.asarray(t.corners if annotations is None else annotations, float)
    if ann.ndim != 3 or ann.shape[1:] != (4, 2):
        raise ValueError(f"annotations: expected shape (n, 4, 2), got {ann.shape}")
    centred = ann - camera.principal_point
    samples = [np.median(centred, axis=0)] + ([c for c in centred] if len(centred) > 1 else [])
    x_all = centred.reshape(-1, 2)
    X_all = {hand: np.tile(dimension_corners(*size, hand), (len(centred), 1)) for hand in HANDEDNESS}
    hyps = {hand: [] for hand in HANDEDNESS}
    for hand in HANDEDNESS:
        X = dimension_corners(*size, hand)
        for sample in samples:
            poses, focals = pl.p4pf(sample, X, True)
            hyps[hand] += [(pose, float(f)) for pose, f in zip(poses, focals)
                           if np.isfinite(f) and focal_bounds[0] <= f <= focal_bounds[1]]
    n_p4pf = sum(len(h) for h in hyps.values())
    fallback = n_p4pf == 0
    if fallback:
        side = float(max(scene.image_width, scene.image_height))
        for hand in HANDEDNESS:
            for f in FALLBACK_FOCALS * side:
                cam = {"model": "SIMPLE_PINHOLE", "width": 0, "height": 0, "params": [float(f), 0.0, 0.0]}
                pose, _ = pl.estimate_absolute_pose(x_all, X_all[hand], cam, {"max_reproj_error": 1e6}, {})
                hyps[hand].append((pose, float(f)))
    best, n_hyp = None, 0
    for hand in HANDEDNESS:
        for pose, f in hyps[hand]:
            n_hyp += 1
            R, tr, f_ref, sse = _refine(pl, pose, f, X_all[hand], x_all, refine)
            if best is None or sse < best[0]:
                best = (sse, hand, np.asarray(R), np.asarray(tr), f_ref)
    if best is None:
        raise RuntimeError("p4pf: no usable pose for either handedness")
    sse, hand, R_obj, tr, f = best
    R_cam = _gravity_frame(camera, R_obj, f)
    location = R_cam.T @ tr
    M = R_cam.T @ R_obj  # object axes in G, ≈ Ry(yaw)
    yaw = float(np.arctan2(M[0, 2], M[0, 0]))
    params = np.array([*location, yaw, f])
    rms = float(np.sqrt(sse / len(x_all)))
    return PeerEstimate(params=params, handedness=int(hand), rms_px=rms, seconds=time.perf_counter() - t0,
                        n_hypotheses=n_hyp, rotation=R_obj, translation=tr, info={"samples": len(samples), "refined": refine,
                                                  "p4pf_solutions": n_p4pf, "fallback": fallback,
                                                  "gravity": "horizon" if camera.horizon is not None else "box"})
