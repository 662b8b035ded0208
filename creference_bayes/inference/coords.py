"""Working coordinates of a scene's parameters, shared by its optimiser and its sampler.

The camera enters by the logarithms of its positive parameters; each object is *anchored to the
image*:

    camera: (log µ, pitch, roll, log height, log ref_scale)
    object: (u, v, ψ, log(length / z), log(width / z), log(height / z), ground)

(u, v) is the pixel of the object's bottom centre, ψ = yaw + atan2(z, x) its turn relative to the
viewing ray, its sizes relative to its depth z; the ray through (u, v) meets the object's ground
(the plane at ``height − ground``) at (x, z), so objects ride with the camera and the posterior is
close to a product of blocks (docs/inference.md). Known sizes stay fixed in metres.

The Jacobian of (u, v) → (x, z) on the plane y = y₀ is y₀² / (µ² d_y³), d = Rᵀ K⁻¹ (u, v, 1) the
viewing ray (a homography's Jacobian); each size contributes its value.

Arrays: cameras (n, 5), objects (n, m, 7), as :mod:`~creference_bayes.models.contract`.
"""

from __future__ import annotations

import numpy as np

from ..core.geometry import rotation_from_pitch_roll
from ..models.contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_SIZE, O_YAW, Model

__all__ = ["CAMERA_LOG", "WorkingCoords", "HorizonDistance", "FD_STEPS", "explored_whole"]

CAMERA_LOG = np.array([True, False, False, True, True])
#: Finite-difference steps in working coordinates (camera block, then object block).
FD_STEPS = np.array([1e-4, 1e-5, 1e-5, 1e-4, 1e-4, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4])
def explored_whole(model: Model) -> bool:
    """Whether the model's free parameters form the camera block and at most one object block (the
    camera pinned by that object alone, the two blocks pinning each other along curved ridges):
    its optimiser then refines both handednesses from the start and its sampler moves the whole
    vector by the ensemble kernel (docs/inference.md, "Sampling and summaries")."""
    return int(np.any(model.object_free, axis=1).sum()) <= 1


class WorkingCoords:
    """Natural parameters ↔ working coordinates for one model (module docstring)."""

    def __init__(self, model: Model):
        self.model = model
        self.pp = np.asarray(model.principal_point, float)
        self.known = ~model.object_free[:, O_SIZE]  # (m, 3)
        self.known_sizes = np.array([o.initial_sizes for o in model.objects])

    def camera_from_work(self, wc: np.ndarray) -> np.ndarray:
        cams = np.array(wc, float)
        with np.errstate(over="ignore"):
            cams[..., CAMERA_LOG] = np.exp(cams[..., CAMERA_LOG])
        return self.model.complete_camera(cams)

    def to_work(self, cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Natural (n, 5), (n, m, 7) → working coordinates."""
        cams = self.model.complete_camera(np.atleast_2d(cams))
        objs = np.asarray(objs, float).reshape(len(cams), -1, 7)
        wc = cams.copy()
        wc[:, CAMERA_LOG] = np.log(cams[:, CAMERA_LOG])
        R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])  # (n, 3, 3)
        P = np.stack([objs[..., 0], cams[:, C_HEIGHT, None] - objs[..., O_GROUND], objs[..., 1]], axis=-1)
        pc = np.einsum("nij,nmj->nmi", R, P)
        mu = cams[:, C_FOCAL, None]
        wo = objs.copy()
        wo[..., 0] = mu * pc[..., 0] / pc[..., 2] + self.pp[0]
        wo[..., 1] = mu * pc[..., 1] / pc[..., 2] + self.pp[1]
        wo[..., O_YAW] = objs[..., O_YAW] + np.arctan2(objs[..., 1], objs[..., 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            wo[..., O_SIZE] = np.log(objs[..., O_SIZE]) - np.log(objs[..., 1:2])
        return wc, wo

    def rays(self, cams: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """(n, m, 3) viewing rays Rᵀ K⁻¹ (u, v, 1) in the gravity-aligned frame."""
        R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])
        mu = cams[:, C_FOCAL, None]
        p = np.stack([(wo[..., 0] - self.pp[0]) / mu, (wo[..., 1] - self.pp[1]) / mu, np.ones(wo.shape[:-1])], axis=-1)
        return np.einsum("nji,nmj->nmi", R, p)

    def from_work(self, wc: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Working coordinates → natural (cameras completed: fixed and derived entries filled in);
        a pixel on or above the horizon gives a NaN object (zero density)."""
        return self.from_work_jacobian(wc, wo)[:2]

    def from_work_jacobian(self, wc: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`from_work` and the objects' part of :meth:`log_jacobian`, (n, m), in one pass."""
        cams = self.camera_from_work(np.atleast_2d(wc))
        wo = np.asarray(wo, float).reshape(len(cams), -1, 7)
        d = self.rays(cams, wo)
        y0 = cams[:, C_HEIGHT, None] - wo[..., O_GROUND]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t = np.where(d[..., 1] > 0, y0 / d[..., 1], np.nan)
            objs = wo.copy()
            objs[..., 0] = t * d[..., 0]
            objs[..., 1] = t * d[..., 2]
            objs[..., O_YAW] = wo[..., O_YAW] - np.arctan2(objs[..., 1], objs[..., 0])
            sizes = np.exp(wo[..., O_SIZE]) * objs[..., 1:2]
            objs[..., O_SIZE] = np.where(self.known, self.known_sizes, sizes)
            jac = (2 * np.log(y0) - 2 * np.log(cams[:, C_FOCAL, None]) - 3 * np.log(d[..., 1])
                   + np.sum(np.where(self.known, 0.0, wo[..., O_SIZE] + np.log(objs[..., 1:2])), axis=-1))
        return cams, objs, jac

    def log_jacobian(self, wc: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """log |∂natural/∂working| of the free parameters: (camera part (n,), object part (n, m))."""
        wc = np.atleast_2d(wc)
        cam = np.sum(wc[:, CAMERA_LOG & self.model.camera_free], axis=1)
        return cam, self.from_work_jacobian(wc, wo)[2]


class HorizonDistance:
    """Flat working coordinates of a scene ↔ the same with pitch replaced by log D of its first object.

    D = −sin(roll)(u − cx) + cos(roll)(v − cy) + µ tan(pitch) is the object's distance below the
    horizon (pixels, at its bottom centre (u, v)); z ≈ h µ / D, so in (log h, log µ, log D) a far
    object's ridge is straight (docs/inference.md). ∂pitch/∂log D = D cos²(pitch) / µ.

    Build it with :meth:`of`.
    """

    @classmethod
    def of(cls, model: Model) -> "HorizonDistance | None":
        """The coordinates for a model whose pitch and roll are free, else None (flat layout: the
        free camera coordinates, then the first object's u, v, …)."""
        cf = model.camera_free
        if not (cf[C_PITCH] and cf[C_ROLL]):
            return None
        hd, pos, kc = cls(), np.cumsum(cf) - 1, int(cf.sum())
        hd.pp, hd.focal = np.asarray(model.principal_point, float), model.focal_length_px
        hd.i_focal = int(pos[C_FOCAL]) if cf[C_FOCAL] else None  # None: µ known
        hd.i_pitch, hd.i_roll, hd.i_u, hd.i_v = int(pos[C_PITCH]), int(pos[C_ROLL]), kc, kc + 1
        return hd

    def _mu(self, v: np.ndarray) -> np.ndarray:
        return np.exp(v[:, self.i_focal]) if self.i_focal is not None else np.full(len(v), float(self.focal))

    def _offset(self, v: np.ndarray) -> np.ndarray:
        roll = v[:, self.i_roll]
        return -np.sin(roll) * (v[:, self.i_u] - self.pp[0]) + np.cos(roll) * (v[:, self.i_v] - self.pp[1])

    def forward(self, p: np.ndarray) -> np.ndarray:
        """(n, d) → (n, d), NaN where the object's bottom is not below the horizon (no ground)."""
        p = np.atleast_2d(np.asarray(p, float))
        q = p.copy()
        d = self._offset(p) + self._mu(p) * np.tan(p[:, self.i_pitch])
        with np.errstate(invalid="ignore", divide="ignore"):
            q[:, self.i_pitch] = np.where(d > 0, np.log(d), np.nan)
        return q

    def inverse(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        p = q.copy()
        with np.errstate(over="ignore"):
            p[:, self.i_pitch] = np.arctan((np.exp(q[:, self.i_pitch]) - self._offset(q)) / self._mu(q))
        return p

    def log_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(n,) log |∂p/∂q| = log D − log(1 + tan² pitch) − log µ."""
        q = np.atleast_2d(np.asarray(q, float))
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            t = (np.exp(q[:, self.i_pitch]) - self._offset(q)) / self._mu(q)
            return q[:, self.i_pitch] - np.log1p(t * t) - np.log(self._mu(q))
