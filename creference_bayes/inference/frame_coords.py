"""Working coordinates of a frame's parameters, shared by its optimiser and its sampler.

In these coordinates the posterior is close to Gaussian: positive quantities enter by their
logarithms (µ, the camera height, the crowd's scale, an object's depth and sizes), so a far
object's long depth–size–focal-length ridge is straight, and an object's lateral position by
b = µ x / z, about its pixel offset from the principal point, which the camera barely moves (x / z
alone moves as 1 / µ along that ridge):

    camera: (log µ, pitch, roll, log height, log ref_scale)
    object: (µ x / z, log z, yaw, log length, log width, log height, ground)

Arrays: cameras (n, 5), objects (n, m, 7), as :mod:`~creference_bayes.models.frame`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CAMERA_LOG", "OBJECT_LOG", "to_work", "from_work", "log_jacobian", "FD_STEPS"]

CAMERA_LOG = np.array([True, False, False, True, True])
OBJECT_LOG = np.array([False, True, False, True, True, True, False])
#: Finite-difference steps in working coordinates (camera block, then object block).
FD_STEPS = np.array([1e-4, 1e-5, 1e-5, 1e-4, 1e-4, 1e-5, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4])


def to_work(cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural parameters → working coordinates."""
    wc = np.array(cams, float)
    wo = np.array(objs, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        wc[..., CAMERA_LOG] = np.log(wc[..., CAMERA_LOG])
        wo[..., 0] = objs[..., 0] / objs[..., 1] * np.asarray(cams, float)[..., 0][..., None]
        wo[..., OBJECT_LOG] = np.log(wo[..., OBJECT_LOG])
    return wc, wo


def from_work(wc: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Working coordinates → natural parameters."""
    cams = np.array(wc, float)
    objs = np.array(wo, float)
    with np.errstate(over="ignore"):
        cams[..., CAMERA_LOG] = np.exp(cams[..., CAMERA_LOG])
        objs[..., OBJECT_LOG] = np.exp(objs[..., OBJECT_LOG])
    objs[..., 0] = wo[..., 0] * objs[..., 1] / cams[..., 0][..., None]
    return cams, objs


def log_jacobian(wc: np.ndarray, wo: np.ndarray, camera_free: np.ndarray, object_free: np.ndarray):
    """log |∂natural/∂working| of the free parameters: (camera part (n,), object part (n, m)).

    Each logarithm contributes its coordinate; (b, log z) → (x, z), x = b z / µ, contributes
    2 log z − log µ.
    """
    cam = np.sum(wc[:, CAMERA_LOG & camera_free], axis=1)
    obj = (np.sum(np.where(object_free & OBJECT_LOG, wo, 0.0), axis=-1) + wo[..., 1]  # z counted twice
           - wc[:, 0, None])
    return cam, obj
