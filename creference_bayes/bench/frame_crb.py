"""The Cramér–Rao bound of a frame: every object's location error at the true state.

The frame's parameters are the free ones of :mod:`~creference_bayes.models.frame` (the shared
camera, each object's location, yaw, size and ground offset). Sizes drawn from a class prior and
ground offsets drawn from theirs are random parameters, so the bound is the Bayesian one (van
Trees): the information of the data plus that of the priors,

    F = Σ_objects (K_i / σ²) Σ_corners Jᵀ J  +  J_hᵀ J_h / σ_h²  +  ∇² (−log prior),

with J the Jacobian of a projected dimension-line corner (K_i annotations of Gaussian noise σ per
pixel coordinate), J_h that of a measured horizon's offsets, and the prior's Hessian at the truth
(finite differences). Each object's location covariance is the (x, y, z) block of F⁻¹ (y is the
camera height minus the object's ground offset), reported as in :mod:`.crb`: the median of ‖e‖ for
e ~ N(0, C) over the true distance, in percent (paper Eq. 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.frame import C_HEIGHT, O_GROUND, FrameModel

__all__ = ["FrameBound", "frame_crb"]

_STEP_C = np.array([1e-4, 1e-7, 1e-7, 1e-6, 1e-6])  # relative for µ; absolute rad; relative h, s
_STEP_O = np.array([1e-6, 1e-6, 1e-7, 1e-6, 1e-6, 1e-6, 1e-6])


@dataclass(frozen=True)
class FrameBound:
    """The bound for one frame: ``cov`` over the free parameters (camera first, then each object's),
    per object the (3, 3) location covariance (m²), ``median_pct`` (m,) and ``rmse_pct`` (m,) of the
    location error in percent of the true distance, and ``distance_sd_m`` (m,)."""

    cov: np.ndarray
    location_cov: np.ndarray
    median_pct: np.ndarray
    rmse_pct: np.ndarray
    distance_sd_m: np.ndarray
    singular: bool


def _free_index(model: FrameModel):
    cam = list(np.flatnonzero(model.camera_free))
    objs = [list(np.flatnonzero(model.object_free[i])) for i in range(model.n_objects)]
    return cam, objs


def frame_crb(model: FrameModel, camera: np.ndarray, objects: np.ndarray, noise_px: float, *,
              seed: int = 0, n_draws: int = 4000) -> FrameBound:
    """The bound at the true ``camera`` (5,) and ``objects`` (m, 7) for dimension lines with
    Gaussian noise ``noise_px`` per coordinate (the model's handedness must be the truth's)."""
    cam_idx, obj_idx = _free_index(model)
    kc = len(cam_idx)
    offsets = np.cumsum([kc] + [len(o) for o in obj_idx])
    n = int(offsets[-1])
    m = model.n_objects
    F = np.zeros((n, n))
    camera = model.complete_camera(np.asarray(camera, float)[None])[0]
    objects = np.asarray(objects, float)
    counts = model.ann_mask.sum(axis=1)
    # Jacobians of every object's corners: perturb one coordinate (in every object at once)
    cols_c, cols_o = [], []
    for j in cam_idx:
        h = _STEP_C[j] * (abs(camera[j]) if j in (0, 3, 4) else 1.0)
        cp, cm = camera.copy(), camera.copy()
        cp[j] += h
        cm[j] -= h
        cp, cm = model.complete_camera(cp[None]), model.complete_camera(cm[None])
        up, _ = model.project(cp, objects[None])
        um, _ = model.project(cm, objects[None])
        cols_c.append(((up - um) / (2 * h))[0])  # (m, 4, 2)
    for j in range(7):
        h = _STEP_O[j] * np.maximum(1.0, np.abs(objects[:, j]))
        op, om = objects.copy(), objects.copy()
        op[:, j] += h
        om[:, j] -= h
        up, _ = model.project(camera[None], op[None])
        um, _ = model.project(camera[None], om[None])
        cols_o.append(((up - um) / (2 * h[:, None, None]))[0])
    for i in range(m):
        J = np.concatenate([np.stack([c[i] for c in cols_c], axis=-1).reshape(8, -1) if kc else np.zeros((8, 0)),
                            np.stack([cols_o[j][i] for j in obj_idx[i]], axis=-1).reshape(8, -1)], axis=1)
        idx = list(range(kc)) + list(range(offsets[i], offsets[i + 1]))
        F[np.ix_(idx, idx)] += counts[i] / noise_px**2 * J.T @ J
    F += _prior_hessian(model, camera, objects, cam_idx, obj_idx, offsets)
    hz = model.camera_terms.horizon
    if hz is not None and model.orientation == "free" and kc:
        F[:kc, :kc] += _horizon_information(model, camera, cam_idx)
    try:
        cov = np.linalg.inv(F)
        np.linalg.cholesky(cov)
        singular = False
    except np.linalg.LinAlgError:
        cov = np.full((n, n), np.inf)
        singular = True
    rng = np.random.default_rng(seed)
    loc_cov = np.zeros((m, 3, 3))
    med, rmse, dsd = np.zeros(m), np.zeros(m), np.zeros(m)
    for i in range(m):
        # (x, y, z) as linear functions of the free parameters
        A = np.zeros((3, n))
        pos = dict(zip(obj_idx[i], range(offsets[i], offsets[i + 1])))
        A[0, pos[0]] = 1.0
        A[2, pos[1]] = 1.0
        if C_HEIGHT in cam_idx:
            A[1, cam_idx.index(C_HEIGHT)] = 1.0
        if O_GROUND in pos:
            A[1, pos[O_GROUND]] = -1.0
        loc = np.array([objects[i, 0], camera[C_HEIGHT] - objects[i, O_GROUND], objects[i, 1]])
        if singular:
            loc_cov[i], med[i], rmse[i], dsd[i] = np.inf, np.inf, np.inf, np.inf
            continue
        C = A @ cov @ A.T
        loc_cov[i] = C
        e = rng.multivariate_normal(np.zeros(3), C, size=n_draws, method="eigh")
        med[i] = 100 * np.median(np.linalg.norm(e, axis=1)) / np.linalg.norm(loc)
        rmse[i] = 100 * np.sqrt(np.trace(C)) / np.linalg.norm(loc)
        g = np.array([objects[i, 0], 0.0, objects[i, 1]]) / np.hypot(objects[i, 0], objects[i, 1])
        dsd[i] = float(np.sqrt(g @ C @ g))
    return FrameBound(cov, loc_cov, med, rmse, dsd, singular)


def _prior_hessian(model, camera, objects, cam_idx, obj_idx, offsets) -> np.ndarray:
    """Hessian of −log prior at the truth over the free parameters (central differences; the
    prior is a sum of a camera term and one term per object, so blocks suffice)."""
    n = int(offsets[-1])
    H = np.zeros((n, n))

    def fc(c):
        return float(model.camera_neg_log_prior(model.complete_camera(c[None]))[0])

    kc = len(cam_idx)
    for a in range(kc):
        for b in range(a, kc):
            ja, jb = cam_idx[a], cam_idx[b]
            ha = _STEP_C[ja] * 100 * (abs(camera[ja]) if ja in (0, 3, 4) else 1.0)
            hb = _STEP_C[jb] * 100 * (abs(camera[jb]) if jb in (0, 3, 4) else 1.0)
            vals = []
            for sa, sb in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                c = camera.copy()
                c[ja] += sa * ha
                c[jb] += sb * hb
                vals.append(fc(c))
            H[a, b] = H[b, a] = (vals[0] - vals[1] - vals[2] + vals[3]) / (4 * ha * hb)
    for i, idx in enumerate(obj_idx):
        def fo(o):
            objs = objects.copy()
            objs[i] = o
            # the location is a fixed unknown here, not a random parameter: its prior is left out
            return float((model.object_neg_log_prior(camera[None], objs[None])
                          - model.map_log_jacobian(objs[None]))[0, i])

        for a in range(len(idx)):
            for b in range(a, len(idx)):
                ja, jb = idx[a], idx[b]
                ha = 1e-4 * max(1.0, abs(objects[i, ja]))
                hb = 1e-4 * max(1.0, abs(objects[i, jb]))
                vals = []
                for sa, sb in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                    o = objects[i].copy()
                    o[ja] += sa * ha
                    o[jb] += sb * hb
                    vals.append(fo(o))
                p, q = offsets[i] + a, offsets[i] + b
                H[p, q] = H[q, p] = (vals[0] - vals[1] - vals[2] + vals[3]) / (4 * ha * hb)
    return H


def _horizon_information(model, camera, cam_idx) -> np.ndarray:
    from ..models.camera_terms import horizon_offsets

    hz = model.camera_terms.horizon
    var = hz.sd_px**2 + (camera[0] * np.tan(model.ground_tilt_sd_rad)) ** 2

    def offs(c):
        full = np.zeros((1, 7))
        full[0, 4], full[0, 5], full[0, 6] = c[0], c[1], c[2]
        return horizon_offsets(hz.points, full, model.principal_point)[0]

    J = []
    for j in cam_idx:
        h = _STEP_C[j] * (abs(camera[j]) if j in (0, 3, 4) else 1.0)
        cp, cm = camera.copy(), camera.copy()
        cp[j] += h
        cm[j] -= h
        J.append((offs(cp) - offs(cm)) / (2 * h))
    J = np.array(J).T  # (2, kc)
    return J.T @ J / var
