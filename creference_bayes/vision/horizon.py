"""The horizon from an image (OpenCV adapter): segments → vanishing points → horizon
(docs/method.md, "The horizon from a photo").

1. Line segments: OpenCV's LSD detector where the installed OpenCV has it (4.1–4.5.3 ship a stub
   that raises), else probabilistic Hough on Canny edges. Chains of nearly collinear pieces are
   merged and refitted (a long line's direction is far more precise than its pieces', and distant
   vanishing points are set by small angles), each with a noise scale σ (:func:`merge_collinear`).
2. Vanishing points by seeded sequential RANSAC: a hypothesis is the intersection of two
   segments' lines (drawn ∝ length); a segment supports it when its endpoint residual
   ½ length · sin(angle to the point) is under ``inlier_px`` (or 3σ); the score is the supporting
   length. The best point is refined by Cauchy-weighted IRLS on the residuals in units of σ (which
   gives its covariance), its supporters removed, and the search repeated.
3. The vertical point is the best-supported one beyond one image height from the principal point
   within 30° of the vertical axis; it enters the fit as the horizon's point at infinity. The pair
   of points whose line agrees (χ² ≤ 16) with the most others wins and the line is refitted on the
   agreeing points by weighted total least squares. One horizontal point and no vertical one: the
   horizon is taken level through it. A horizon tilted more than :data:`MAX_ROLL_DEG` is taken
   level through the best-supported horizontal point (such tilts are nearly always a far vanishing
   point put in the wrong family).
4. :data:`HORIZON_PASSES` refining passes repeat 2–3 without the segments within
   :data:`NEAR_HORIZON` of the image height of the current horizon (there every ground direction
   looks nearly horizontal and blurs the families together); a pass that fails keeps the previous.

Uncertainty. ``sigma_rows_px`` is the statistical standard error of the horizon's rows at the
image borders, from the vanishing points' covariances; it does not see systematic errors, often
larger on real photos. The estimate therefore enters the model as a heavy-tailed measurement: the
true horizon's offsets from its two points follow a bivariate Student-t with :data:`HORIZON_DOF`
degrees of freedom and scale ``sd_px``, the statistical part combined in quadrature with
:data:`SYSTEMATIC_FRACTION` of the image's larger side (doubled when the horizon was assumed level).
``confidence`` is the probability, under that distribution, that the horizon lies within 1 % of
the image height of the estimate at a border.

Computation is in normalised coordinates (centred on the principal point, scaled by half the image
diagonal), where vanishing points are unit homogeneous 3-vectors: points at infinity need no case.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path

import cv2
import numpy as np
from scipy.stats import t as student_t

from .images import ImageError, image_bytes

__all__ = ["METHODS", "HorizonEstimate", "read_gray", "detect_segments", "merge_collinear", "find_vanishing_points",
           "estimate_horizon", "horizon_error"]

METHODS = ("auto", "lsd", "hough")
#: Floor on the endpoint residual scale (pixels) used for vanishing-point covariances.
MIN_SIGMA_PX = 0.3
#: Segments with both ends within this fraction of the image height of the horizon are left out
#: of the refining passes; HORIZON_PASSES such passes follow the first estimate.
NEAR_HORIZON = 0.2
HORIZON_PASSES = 2
#: A fitted horizon tilted more than this (degrees) is replaced by a level one through the
#: best-supported horizontal vanishing point.
MAX_ROLL_DEG = 10.0
#: Systematic error scale of an estimated horizon, as a fraction of the image's larger side (about
#: 1° of pitch): with :data:`HORIZON_DOF`, the stated 90 % interval holds 90 % of 51 KITTI frames
#: (examples/horizon_kitti_check.py; docs/method.md, "The horizon from a photo").
SYSTEMATIC_FRACTION = 0.012
#: Degrees of freedom of the bivariate Student-t of the horizon's error (1: a Cauchy, for the
#: heavy tail of real photos' errors).
HORIZON_DOF = 1.0


@dataclass(frozen=True)
class HorizonEstimate:
    """A horizon found in an image, or why none was (then falsy, ``points`` None).

    Attributes
    ----------
    points : (2, 2) horizon points at u = 0 and u = image width, pixels; None on failure
    confidence : probability in [0, 1] that the horizon lies within 1 % of the image height of
        the estimate at a border, under ``sd_px`` (module docstring); 0 on failure
    n_segments : line segments detected
    method : ``"lsd"`` or ``"hough"``
    vanishing_points : (k, 3) homogeneous vanishing points in pixels (w = 0 at infinity)
    vertical : index into ``vanishing_points`` of the vertical one, or None
    reason : why no horizon was found ('' on success)
    sigma_rows_px : (2,) standard error of the horizon's rows at u = 0 and u = width, pixels,
        from the vanishing points' covariances (statistical only)
    assumed_level : True when only one horizontal vanishing point was found and no vertical one,
        so the horizon was taken level through it
    sd_px : the scale of each horizon point's error, statistical and systematic, pixels (module
        docstring); None on failure
    dof : degrees of freedom of the error's Student-t (:data:`HORIZON_DOF`)
    """

    points: np.ndarray | None
    confidence: float
    n_segments: int
    method: str
    vanishing_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    vertical: int | None = None
    reason: str = ""
    sigma_rows_px: np.ndarray | None = None
    assumed_level: bool = False
    sd_px: float | None = None
    dof: float = HORIZON_DOF

    def __bool__(self) -> bool:
        return self.points is not None

    def to_dict(self) -> dict:
        return {"points": None if self.points is None else self.points.tolist(),
                "confidence": self.confidence, "n_segments": self.n_segments, "method": self.method,
                "reason": self.reason, "sd_px": self.sd_px, "dof": self.dof,
                "sigma_rows_px": None if self.sigma_rows_px is None else self.sigma_rows_px.tolist(),
                "assumed_level": self.assumed_level}


def read_gray(path: str | Path) -> np.ndarray:
    """An image file as an (h, w) uint8 array, without OpenCV's own messages on standard error:
    checked and read by :func:`~.images.image_bytes` (a regular file, an image no larger than
    :data:`~.images.MAX_IMAGE_PIXELS`, judged from its header) and decoded by ``cv2.imdecode``
    with OpenCV's logging silenced.

    Raises
    ------
    ImageError
        (an ``OSError``) When the file cannot be read, is not an image, or is too large;
        ``strerror`` says why, ``filename`` is the path.
    """
    data, _ = image_bytes(path)
    with _quiet_opencv():
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
        except cv2.error as exc:
            raise ImageError(path, f"cannot be decoded by OpenCV ({' '.join(str(exc).split())[:120]})") from None
    if img is None:
        raise ImageError(path, "not an image OpenCV can decode")
    return img


@contextmanager
def _quiet_opencv():
    """OpenCV's log level set to silent for the duration (restored after)."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None or not hasattr(log, "setLogLevel"):
        yield
        return
    previous = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        log.setLogLevel(previous)


def _gray(image) -> np.ndarray:
    if isinstance(image, (str, Path)):
        return read_gray(image)
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2:
        raise ValueError(f"image: expected an (h, w) or (h, w, 3) array, got shape {img.shape}")
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


def _lsd():
    if not hasattr(cv2, "createLineSegmentDetector"):
        return None
    try:
        return cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
    except cv2.error:  # stub in OpenCV 4.1–4.5.3 (license)
        return None


def detect_segments(image, *, method: str = "auto", min_length: float | None = None) -> tuple[np.ndarray, str]:
    """Line segments of an image.

    Parameters
    ----------
    image : (h, w) or (h, w, 3) array (BGR), or a path
    method : ``"auto"`` (LSD where available, else Hough), ``"lsd"`` or ``"hough"``
    min_length : shortest segment kept after merging collinear pieces, pixels (default 3 % of
        the image diagonal); pieces down to a third of it are detected and merged

    Returns
    -------
    segments : (n, 5) float array of (u1, v1, u2, v2, σ), pixels; σ is the endpoint noise scale
        (:func:`merge_collinear`)
    method : the detector used
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {list(METHODS)}, got {method!r}")
    gray = _gray(image)
    diag = float(np.hypot(*gray.shape))
    min_length = 0.03 * diag if min_length is None else float(min_length)
    lsd = _lsd() if method in ("auto", "lsd") else None
    if method == "lsd" and lsd is None:
        raise RuntimeError("method 'lsd': this OpenCV build has no line segment detector; use 'hough'")
    if lsd is not None:
        lines = lsd.detect(gray)[0]
        used = "lsd"
    else:
        edges = cv2.Canny(cv2.GaussianBlur(gray, (3, 3), 0), 50, 150)
        lines = cv2.HoughLinesP(edges, 1, np.pi / 720, threshold=max(10, int(min_length / 6)),
                                minLineLength=min_length / 3, maxLineGap=3)
        used = "hough"
    seg = np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(float)
    seg = seg[np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) >= min_length / 3]
    seg = merge_collinear(seg)
    keep = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) >= min_length
    return seg[keep], used


def merge_collinear(segments: np.ndarray, *, dist_px: float = 1.0, angle_deg: float = 1.0,
                    gap_px: float = 10.0) -> np.ndarray:
    """Merge chains of nearly collinear segments and refit each chain.

    Two segments link when their directions differ by less than ``angle_deg``, each one's
    endpoints lie within ``dist_px`` of the other's line and the gap between them along it is
    under ``gap_px``; linked groups (transitively) are refitted by length-weighted total least
    squares and span their extreme endpoints.

    Parameters
    ----------
    segments : (n, 4) pixels (u1, v1, u2, v2)

    Returns
    -------
    (m, 5) segments (u1, v1, u2, v2, σ), m ≤ n. σ (pixels) is the noise scale of the endpoint
    residual: :data:`MIN_SIGMA_PX` for a single piece; for a chain of N endpoints with RMS
    distance r from the refitted line, r √(3/N) (the precision of a line fitted to N points spread
    along it), floored at :data:`MIN_SIGMA_PX`. Chains of short, aliased pieces (far tiles) thus
    count for less than one clean edge.
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    if len(seg) < 2:
        return np.column_stack([seg, np.full(len(seg), MIN_SIGMA_PX)])
    p, q = seg[:, :2], seg[:, 2:]
    length = np.linalg.norm(q - p, axis=1)
    t = (q - p) / length[:, None]
    normal = np.column_stack([-t[:, 1], t[:, 0]])
    mid = 0.5 * (p + q)
    off_p, off_q = p[None] - mid[:, None], q[None] - mid[:, None]  # [i, j]: j's ends from i's middle
    across = np.maximum(np.abs(np.einsum("ik,ijk->ij", normal, off_p)),
                        np.abs(np.einsum("ik,ijk->ij", normal, off_q)))
    along_p, along_q = np.einsum("ik,ijk->ij", t, off_p), np.einsum("ik,ijk->ij", t, off_q)
    half = 0.5 * length[:, None]
    gap = np.maximum(np.minimum(along_p, along_q) - half, -half - np.maximum(along_p, along_q))
    link = (np.abs(t @ t.T) > np.cos(np.radians(angle_deg))) & (across < dist_px) & (gap < gap_px)
    link &= link.T
    parent = np.arange(len(seg))

    def root(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i, j in zip(*np.nonzero(np.triu(link, 1))):
        parent[root(i)] = root(j)
    roots = np.array([root(i) for i in range(len(seg))])
    out = []
    for r in np.unique(roots):
        m = roots == r
        if m.sum() == 1:
            out.append(np.append(seg[m][0], MIN_SIGMA_PX))
            continue
        pts, w = np.vstack([p[m], q[m]]), np.tile(length[m], 2)
        centre = w @ pts / w.sum()
        direction = np.linalg.eigh(((pts - centre) * w[:, None]).T @ (pts - centre))[1][:, 1]
        s = (pts - centre) @ direction
        rms = np.sqrt(w @ ((pts - centre) @ np.array([-direction[1], direction[0]])) ** 2 / w.sum())
        sigma = max(MIN_SIGMA_PX, rms * np.sqrt(3.0 / len(pts)))
        out.append(np.concatenate([centre + s.min() * direction, centre + s.max() * direction, [sigma]]))
    return np.array(out)


def _normalised(seg: np.ndarray, centre: np.ndarray, scale: float):
    """Unit-normal homogeneous lines (n, 3), midpoints (n, 2), unit directions (n, 2), lengths (n,)."""
    p, q = (seg[:, :2] - centre) / scale, (seg[:, 2:] - centre) / scale
    ones = np.ones((len(seg), 1))
    lines = np.cross(np.hstack([p, ones]), np.hstack([q, ones]))
    lines /= np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    d = q - p
    length = np.linalg.norm(d, axis=1)
    return lines, 0.5 * (p + q), d / length[:, None], length


def _residual(vps: np.ndarray, lines: np.ndarray, mid: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(k, n) endpoint residual ½ length · sin(angle) of segment n against point k.

    With unit-normal lines, ``l · v = n · (v_xy − m v_w)`` = ‖v_xy − m v_w‖ sin(angle).
    """
    to_vp = np.linalg.norm(vps[:, None, :2] - mid[None] * vps[:, None, 2:3], axis=-1)
    return half[None] * np.abs(vps @ lines.T) / np.maximum(to_vp, 1e-12)


def _refine(v: np.ndarray, lines: np.ndarray, mid: np.ndarray, half: np.ndarray,
            n_iter: int = 8, cauchy: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Robust IRLS for the point minimising Σ ρ(rᵢ), rᵢ the endpoint residuals in units of each
    segment's σ (``half`` is ½ length / σ) and ρ the Cauchy loss with scale ``cauchy``.

    Returns the unit homogeneous 3-vector and its (3, 3) covariance s² Σ_k e_k e_kᵀ / λ_k over
    the two tangent eigenpairs of the weighted normal matrix, s² the residual variance (≥ 1).
    """
    for _ in range(n_iter):
        to_vp = np.maximum(np.linalg.norm(v[:2] - mid * v[2], axis=-1), 1e-12)
        res = half * np.abs(lines @ v) / to_vp
        w = 1.0 / (1.0 + (res / cauchy) ** 2)
        L = lines * (np.sqrt(w) * half / to_vp)[:, None]
        lam, vec = np.linalg.eigh(L.T @ L)
        v_new = vec[:, 0]
        v = v_new if v_new @ v >= 0 else -v_new
    s2 = max(lam[0] / max(len(lines) - 2, 1), 1.0)
    cov = s2 * sum(np.outer(vec[:, k], vec[:, k]) / max(lam[k], 1e-300) for k in (1, 2))
    return v, cov


def find_vanishing_points(segments: np.ndarray, image_size: tuple[int, int], *, principal_point=None,
                          rng=0, n_hypotheses: int = 600, inlier_px: float = 1.5, max_points: int = 4,
                          min_support: int = 6) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Vanishing points by sequential RANSAC.

    Parameters
    ----------
    segments : (n, 4) or (n, 5) pixels, the fifth column each segment's σ (default
        :data:`MIN_SIGMA_PX`)
    image_size : (width, height) pixels
    principal_point : (2,) pixels (default: the image centre)
    rng : seed or Generator (deterministic by default)
    inlier_px : a segment supports a point when its endpoint residual is under ``inlier_px``
        or under 3σ
    max_points, min_support : at most this many points, each with at least this many segments

    Returns
    -------
    vps : (k, 3) unit homogeneous points in normalised coordinates (centred on the principal point,
        scaled by half the diagonal), best supported first
    covariances : (k, 3, 3) their covariances
    inliers : k index arrays into ``segments``
    """
    rng = np.random.default_rng(rng)
    w, h = image_size
    centre = np.array([w / 2.0, h / 2.0]) if principal_point is None else np.asarray(principal_point, float)
    scale = 0.5 * np.hypot(w, h)
    seg = np.asarray(segments, float)
    sigma = seg[:, 4] if seg.shape[1] > 4 else np.full(len(seg), MIN_SIGMA_PX)
    lines, mid, direction, length = _normalised(seg[:, :4], centre, scale)
    half = 0.5 * length * scale  # pixels
    tol = np.maximum(inlier_px, 3.0 * sigma)

    def support(points, idx):
        return _residual(points, lines[idx], mid[idx], half[idx]) < tol[idx]

    remaining = np.arange(len(lines))
    vps, covs, inliers = [], [], []
    while len(vps) < max_points and len(remaining) >= max(2, min_support):
        r = remaining
        ij = rng.choice(r, size=(n_hypotheses, 2), p=length[r] / length[r].sum())
        hyp = np.cross(lines[ij[:, 0]], lines[ij[:, 1]])
        norm = np.linalg.norm(hyp, axis=1)
        hyp = hyp[norm > 1e-12] / norm[norm > 1e-12, None]
        if not len(hyp):
            break
        best = hyp[np.argmax(support(hyp, r).astype(float) @ length[r])]
        members = r[support(best[None], r)[0]]
        for _ in range(3):  # refine on the supporters, then re-select them
            if len(members) < min_support:
                break
            best, cov = _refine(best, lines[members], mid[members], half[members] / sigma[members])
            members = r[support(best[None], r)[0]]
        if len(members) < min_support:
            break
        vps.append(best)
        covs.append(cov)
        inliers.append(members)
        remaining = np.setdiff1d(remaining, members)
    return np.array(vps).reshape(-1, 3), np.array(covs).reshape(-1, 3, 3), inliers


def _to_pixels(vps: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    T = np.array([[scale, 0, centre[0]], [0, scale, centre[1]], [0, 0, 1.0]])
    out = vps @ T.T
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def estimate_horizon(image, *, principal_point=None, scene_size: tuple[int, int] | None = None,
                     method: str = "auto", seed=0, min_length: float | None = None,
                     inlier_px: float = 1.5, n_hypotheses: int = 600) -> HorizonEstimate:
    """Estimate the horizon of an image (module docstring).

    Parameters
    ----------
    image : (h, w) or (h, w, 3) BGR array, or a path
    principal_point : (2,) pixels (default: the image centre), in the scene's pixels
    scene_size : (width, height) of the scene's pixel frame when the annotations were made on a
        resized copy of the image; ``principal_point`` and the returned points are in that frame
        (default: the image's own size)
    method : segment detector, one of :data:`METHODS`
    seed : RANSAC seed (the same seed gives the same horizon)
    min_length, inlier_px, n_hypotheses : see :func:`detect_segments` and
        :func:`find_vanishing_points`

    Returns
    -------
    HorizonEstimate (falsy with a ``reason`` when no horizon could be found)
    """
    gray = _gray(image)
    h, w = gray.shape
    to_image = np.array([1.0, 1.0]) if scene_size is None else np.array([w, h], float) / scene_size
    centre = (np.array([w / 2.0, h / 2.0]) if principal_point is None
              else np.asarray(principal_point, float) * to_image)
    scale = 0.5 * float(np.hypot(w, h))
    seg, used = detect_segments(gray, method=method, min_length=min_length)
    if len(seg) < 4:
        return HorizonEstimate(None, 0.0, len(seg), used, reason=f"only {len(seg)} line segments")
    T_inv = np.array([[1 / scale, 0, -centre[0] / scale], [0, 1 / scale, -centre[1] / scale], [0, 0, 1.0]])
    use, fit = np.ones(len(seg), bool), None
    for _ in range(1 + HORIZON_PASSES):
        attempt = _horizon_pass(seg[use], (w, h), centre, scale, seed, n_hypotheses, inlier_px)
        if not isinstance(attempt, tuple):
            if fit is None:
                return HorizonEstimate(None, 0.0, len(seg), used, reason=attempt)
            break  # keep the previous pass
        fit = attempt
        # the next pass leaves out segments near this horizon (module docstring, step 4)
        px_line = fit[0] @ T_inv
        px_line = px_line / np.hypot(*px_line[:2])
        ends = np.abs(np.stack([seg[:, :2], seg[:, 2:4]]) @ px_line[:2] + px_line[2])
        far = ~np.all(ends < NEAR_HORIZON * h, axis=0)
        if far.sum() < 4 or np.array_equal(far, use):
            break
        use = far
    line, line_cov, assumed_level, vps, vertical = fit
    pix = _to_pixels(vps, centre, scale)
    rows = _border_rows(line, T_inv, w)
    jac = np.array([(_border_rows(line + e, T_inv, w) - rows) / 1e-7 for e in 1e-7 * np.eye(3)]).T
    sigma_rows = np.sqrt(np.maximum(np.diag(jac @ line_cov @ jac.T), 0.0)) / to_image[1]
    height_px = h / to_image[1]
    side_px = max(w / to_image[0], height_px)
    systematic = SYSTEMATIC_FRACTION * side_px * (2.0 if assumed_level else 1.0)
    sd = float(np.hypot(sigma_rows.max(), systematic))
    conf = float(2.0 * student_t.cdf(0.01 * height_px / sd, HORIZON_DOF) - 1.0)
    points = np.array([[0.0, rows[0]], [float(w), rows[1]]]) / to_image
    pix = pix / np.append(to_image, 1.0)
    return HorizonEstimate(points, float(conf), len(seg), used, pix, vertical,
                           sigma_rows_px=sigma_rows, assumed_level=assumed_level, sd_px=sd)


def _horizon_pass(seg, size, centre, scale, seed, n_hypotheses, inlier_px):
    """One pass: vanishing points and the horizon through them, or the reason there is none."""
    w, h = size
    vps, covs, inliers = find_vanishing_points(seg, size, principal_point=centre, rng=seed,
                                               n_hypotheses=n_hypotheses, inlier_px=inlier_px)
    vertical = _vertical_index(vps, h / scale)
    horizontal = [k for k in range(len(vps)) if k != vertical]
    if not horizontal:
        return "no horizontal vanishing point"
    supports = [len(i) for i in inliers]
    line, line_cov, assumed_level = _fit_horizon(vps, covs, supports, horizontal, vertical)
    if abs(line[1]) > 0 and abs(math.degrees(math.atan(line[0] / line[1]))) > MAX_ROLL_DEG:
        # far more often a vanishing point in the wrong family than a tilted camera: take it level
        line, line_cov, assumed_level = _fit_horizon(vps, covs, supports, horizontal[:1], None)
    if abs(line[1]) < abs(line[0]):
        return "the vanishing points give a horizon steeper than 45 degrees"
    return line, line_cov, assumed_level, vps, vertical


def _border_rows(line: np.ndarray, T_inv: np.ndarray, width: float) -> np.ndarray:
    """Rows (pixels) at u = 0 and u = width of a line given in normalised coordinates."""
    a, b, c = line @ T_inv  # a line l in normalised coordinates is l T⁻¹ in pixels
    return np.array([-c / b, -(c + a * width) / b])


def _vertical_index(vps: np.ndarray, far: float) -> int | None:
    """The best-supported point beyond ``far`` (normalised units) within 30° of the vertical axis."""
    for k, (x, y, wk) in enumerate(vps):  # vps are ordered by support
        r = np.hypot(x, y)
        if r > 0 and abs(y) / r > np.cos(np.radians(30.0)) and r > far * abs(wk):
            return k
    return None


def _fit_horizon(vps, covs, supports, horizontal, vertical, max_chi2: float = 16.0, n_iter: int = 10):
    """Weighted fit of the horizon line through the horizontal points (normalised coordinates).

    The vertical point v enters as the horizon's point at infinity J v, J a quarter turn. The pair
    whose line is consistent (χ² ≤ ``max_chi2``) with the most points wins, ties broken by segment
    support (so a spurious point cannot drag the line), and the line is refitted on those points,
    minimising Σ (l·p)² / (lᵀ C l) over unit l by reweighting. One horizontal point and no vertical
    one: the horizon is taken level through it.

    Returns
    -------
    line (3,), its covariance (3, 3), assumed_level
    """
    J = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    points = [(vps[k], covs[k], supports[k]) for k in horizontal]
    if vertical is not None:
        points.append((J @ vps[vertical], J @ covs[vertical] @ J.T, supports[vertical]))
    assumed_level = len(points) == 1
    if assumed_level:  # a level horizon: the point at infinity (1, 0, 0), nearly certain
        points.append((np.array([1.0, 0.0, 0.0]), 1e-8 * np.eye(3), 0))
    P, C, support = (np.array(v, float) for v in zip(*points))

    def chi2(line):
        return (P @ line) ** 2 / np.maximum(np.einsum("i,kij,j->k", line, C, line), 1e-300)

    best = (-1, -1.0, np.arange(len(points)))
    for i, j in combinations(range(len(points)), 2):
        line = np.cross(P[i], P[j])
        if np.linalg.norm(line) < 1e-12:
            continue
        c2 = chi2(line / np.linalg.norm(line))
        ok = np.flatnonzero(c2 <= max_chi2)
        key = (len(ok), support[ok].sum())
        if key > best[:2]:
            best = (*key, ok)
    keep = best[2]
    wts = 1.0 / np.maximum(np.trace(C[keep], axis1=1, axis2=2), 1e-300)
    for _ in range(n_iter):
        lam, vec = np.linalg.eigh((P[keep] * wts[:, None]).T @ P[keep])
        line = vec[:, 0]
        wts = 1.0 / np.maximum(np.einsum("i,kij,j->k", line, C[keep], line), 1e-300)
    cov = sum(np.outer(vec[:, k], vec[:, k]) / max(lam[k], 1e-300) for k in (1, 2))
    return line, cov, assumed_level


def horizon_error(estimated: np.ndarray, true: np.ndarray, width: float, height: float) -> float:
    """Horizon benchmark measure: the largest vertical gap at u = 0 and u = width, over the height.

    Parameters
    ----------
    estimated, true : (2, 2) points on each horizon, pixels
    """
    def rows(p):
        p = np.asarray(p, float)
        slope = (p[1, 1] - p[0, 1]) / (p[1, 0] - p[0, 0])
        return p[0, 1] + slope * (np.array([0.0, width]) - p[0, 0])

    return float(np.max(np.abs(rows(estimated) - rows(true))) / height)
