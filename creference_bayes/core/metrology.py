"""Single-view metrology on the ground plane: reference pairs → bounds on x and z (paper §5.2.2).

The exact, coordinate form of the paper's cross-ratio construction (docs/paper.md, "The paper
model", for the derivation).

Ground coordinates
------------------
With the horizon as a normalised line (a, b, c) (positive below it), ``dist(p)`` the signed
distance of pixel p from it, ``v_c`` the foot of the perpendicular from the principal point c onto
the horizon and ``e_h`` the horizon's unit direction pointing right,

    ζ(p) = 1 / dist(p),        ξ(p) = ((p − v_c)·e_h) / dist(p).

A ground point is X = H ξ, Z = V (ζ − ζ_f) with H = h / cos p, V = µ h / cos² p and, with
d_c = dist(c) = µ tan p, ζ_f = d_c H² / V². Hence, exactly and without µ,

    x = ξ_t H,        z = V ζ_t − d_c H² / V.

The paper's Eq. 8 (``z = αV``) drops the second term (an error of ``h tan p``); this module
applies it, so for noise-free input x and z are exact for any pitch, roll and principal point.
Each pair also yields µ = √((V/H)² − d_c²) and h = µ H² / V (reported per pair).

Pair solve
----------
A reference with real length ℓ gives ℓ² = (bH)² + (βV)², b = Δξ, β = Δζ (Eq. 9); two give a 2×2
linear system in (H², V²), conditioned by ``κ = |b₁²β₂² − b₂²β₁²| / (b₁²β₂² + b₂²β₁²)`` ∈ [0, 1]
(0 for parallel and for mirror-image segments: only squares enter). The rectangle of stated
squared lengths maps to a parallelogram in (H², V²), clipped to H² > 0, V² > d_c² H² and, with a
focal range [µ₋, µ₊], (d_c² + µ₋²) H² ≤ V² ≤ (d_c² + µ₊²) H². x, z and the ground distance have
no critical point inside it, so their extremes are sought on its boundary: its vertices and
:data:`EDGE_SAMPLES` points along each edge.

Skip rules
----------
Skipped pairs are counted with a reason (:data:`SKIP_REASONS`), never returned as NaN: an
endpoint on or above the horizon; κ < :data:`MIN_CONDITIONING`; no positive solution; the target
behind the camera; a distance bound over :data:`MAX_DISTANCE_M` (the paper's 10 km); and, beyond
the paper, *unstable* pairs, where a one-pixel move of one endpoint changes the target distance by
more than :data:`MAX_PIXEL_SENSITIVITY` (the κ rule alone lets most noisy near-parallel pairs
through).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from .cost import SoftConstraints

__all__ = [
    "MAX_DISTANCE_M", "MIN_CONDITIONING", "MIN_HORIZON_PX", "MAX_PIXEL_SENSITIVITY", "EDGE_SAMPLES",
    "SKIP_REASONS", "GroundFrame", "PairResult", "ReferenceReport", "SkipRules",
    "pair_conditioning", "solve_pair", "pair_bounds", "pixel_sensitivity", "target_ground_point",
    "assess_pair", "aggregate_references",
]

#: Pairs whose target distance could exceed this (metres) are skipped (the paper's example, §6.3).
MAX_DISTANCE_M = 1e4
#: Pairs with conditioning κ below this are skipped as near-parallel (see the module docstring).
MIN_CONDITIONING = 0.1
#: Points closer than this (pixels) to the horizon, or above it, cannot be measured.
MIN_HORIZON_PX = 1.0
#: Pairs whose target distance changes by more than this fraction when one reference endpoint
#: moves by one pixel are skipped as unstable (10 px of noise would then mean ≳ 20 % error).
MAX_PIXEL_SENSITIVITY = 0.02
#: Points evaluated along each boundary edge of a pair's feasible region.
EDGE_SAMPLES = 65

SKIP_REASONS = {
    "target_above_horizon": "a target corner lies on or above the horizon",
    "endpoint_above_horizon": "a reference endpoint lies on or above the horizon",
    "near_parallel": "the two segments are (nearly) parallel or mirror images: singular system",
    "no_positive_solution": "no stated lengths give H² > 0 and V² > d_c² H² (a real focal length in range)",
    "behind_camera": "the target's depth z is ≤ 0 for every solution",
    "implausible_distance": f"the target could be farther than {MAX_DISTANCE_M:g} m",
    "unstable": "moving one endpoint by a pixel changes the target distance by more than "
                f"{MAX_PIXEL_SENSITIVITY:.0%}",
}


@dataclass(frozen=True)
class GroundFrame:
    """Affine ground coordinates (ξ, ζ) defined by a horizon and the principal point.

    Attributes
    ----------
    line : (3,) horizon (a, b, c), a² + b² = 1, ``line @ (u, v, 1)`` positive below the horizon
    principal_point : (2,) pixels
    """

    line: np.ndarray
    principal_point: np.ndarray

    @classmethod
    def from_camera(cls, camera) -> "GroundFrame":
        """The frame of a :class:`~creference_bayes.core.geometry.Camera` (level when it has no horizon)."""
        pp = np.asarray(camera.principal_point, float)
        line = np.array([0.0, 1.0, -pp[1]]) if camera.horizon is None else np.asarray(camera.horizon, float)
        return cls(line, pp)

    @property
    def d_c(self) -> float:
        """Signed distance (pixels) of the principal point below the horizon, µ tan(pitch)."""
        return float(self.distance(self.principal_point[None])[0])

    @property
    def direction(self) -> np.ndarray:
        """e_h, the horizon's unit direction pointing right, (2,)."""
        return np.array([self.line[1], -self.line[0]])

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (pixels) of (n, 2) points from the horizon, positive below, (n,)."""
        p = np.asarray(points, float).reshape(-1, 2)
        return p @ self.line[:2] + self.line[2]

    def coordinates(self, points: np.ndarray) -> np.ndarray:
        """(ξ, ζ) of (n, 2) pixels below the horizon, shape (n, 2); 1/pixel units for ζ."""
        p = np.asarray(points, float).reshape(-1, 2)
        dist = self.distance(p)
        v_c = self.principal_point - self.d_c * self.line[:2]
        return np.column_stack([((p - v_c) @ self.direction) / dist, 1.0 / dist])


@dataclass(frozen=True)
class PairResult:
    """One pair of references (i, j): either its bounds or the reason it was skipped.

    Attributes
    ----------
    i, j : reference indices (``Reference.index``)
    reason : a key of :data:`SKIP_REASONS`, or None when the pair is used
    conditioning : κ ∈ [0, 1] (NaN only when an endpoint was unusable)
    x_bounds, z_bounds, distance_bounds : (2,) [low, high] in metres (None when skipped)
    x, z : estimate at the centres of both stated ranges, metres (None if infeasible there)
    focal_length_px, camera_height_m : µ and h implied at the centres (None if infeasible)
    pixel_sensitivity : :func:`pixel_sensitivity` at the centres (None when not computed)
    """

    i: int
    j: int
    reason: str | None = None
    conditioning: float = float("nan")
    x_bounds: np.ndarray | None = None
    z_bounds: np.ndarray | None = None
    distance_bounds: np.ndarray | None = None
    x: float | None = None
    z: float | None = None
    focal_length_px: float | None = None
    camera_height_m: float | None = None
    pixel_sensitivity: float | None = None

    @property
    def used(self) -> bool:
        return self.reason is None

    def to_dict(self) -> dict:
        d: dict = {"i": self.i, "j": self.j, "used": self.used}
        if self.reason is not None:
            d["reason"] = self.reason
        if np.isfinite(self.conditioning):
            d["conditioning"] = self.conditioning
        for key in ("x_bounds", "z_bounds", "distance_bounds"):
            value = getattr(self, key)
            if value is not None:
                d[key] = [float(v) for v in value]
        for key in ("x", "z", "focal_length_px", "camera_height_m", "pixel_sensitivity"):
            value = getattr(self, key)
            if value is not None and np.isfinite(value):
                d[key] = float(value)
        return d


@dataclass(frozen=True)
class ReferenceReport:
    """What the references contributed: per-pair outcomes and the soft constraints built.

    Attributes
    ----------
    n_references : references in the scene
    pairs : one :class:`PairResult` per unordered pair
    constraints : :class:`~creference_bayes.cost.SoftConstraints` of the used pairs, or None
    on : ``"xz"`` or ``"distance"`` (what the constraints penalise)
    enabled : False when references were turned off (``--no-references``)
    used_as : how the model used them: ``"pairwise bounds"`` (the paper model's soft
        constraints, built from the used pairs) or ``"likelihood"`` (the metrology model, which
        uses every reference below the horizon directly; the pairs are then only reported)
    in_likelihood : references that entered the metrology model's likelihood, or None
    """

    n_references: int
    pairs: tuple[PairResult, ...] = ()
    constraints: SoftConstraints | None = None
    on: str = "xz"
    enabled: bool = True
    used_as: str = "pairwise bounds"
    in_likelihood: int | None = None

    @property
    def pairs_used(self) -> int:
        return sum(p.used for p in self.pairs)

    @property
    def pairs_skipped(self) -> int:
        return len(self.pairs) - self.pairs_used

    @property
    def skipped_reasons(self) -> dict[str, int]:
        """Count of skipped pairs per reason key."""
        return dict(Counter(p.reason for p in self.pairs if not p.used))

    def to_dict(self) -> dict:
        return {"pairs_used": self.pairs_used, "pairs_skipped": self.pairs_skipped,
                "skipped_reasons": self.skipped_reasons, "n_references": self.n_references,
                "enabled": self.enabled, "on": self.on, "used_as": self.used_as,
                **({} if self.in_likelihood is None else {"in_likelihood": self.in_likelihood}),
                "pairs": [p.to_dict() for p in self.pairs]}


def pair_conditioning(d1: np.ndarray, d2: np.ndarray) -> float:
    """κ of two segments given their (Δξ, Δζ), see the module docstring; 0 when singular."""
    s11, s12 = d1[0] ** 2 * d2[1] ** 2, d2[0] ** 2 * d1[1] ** 2
    total = s11 + s12
    return 0.0 if total <= 0 else float(abs(s11 - s12) / total)


def solve_pair(d1: np.ndarray, d2: np.ndarray, l1_sq, l2_sq) -> np.ndarray:
    """(H², V²) from ℓ₁² = b₁²H² + β₁²V², ℓ₂² = b₂²H² + β₂²V² (Eq. 9).

    Parameters
    ----------
    d1, d2 : (2,) (Δξ, Δζ) of each segment
    l1_sq, l2_sq : squared real lengths, m², scalars or arrays of one shape

    Returns
    -------
    (..., 2) array (H², V²), m² and m²·px²; raises ``numpy.linalg.LinAlgError`` if singular
    """
    A = np.array([[d1[0] ** 2, d1[1] ** 2], [d2[0] ** 2, d2[1] ** 2]])
    rhs = np.stack(np.broadcast_arrays(np.asarray(l1_sq, float), np.asarray(l2_sq, float)), axis=-1)
    return np.linalg.solve(A, rhs[..., None])[..., 0]


def target_ground_point(corners: np.ndarray, frame: GroundFrame) -> np.ndarray:
    """(ξ_t, ζ_t) of the box's bottom centre: c1 + (c2 − c1)/2 + (c3 − c1)/2 in (ξ, ζ).

    ``corners`` are the (4, 2) or (3, 2) dimension-line corners t1..t3(..t4), pixels. The centre is
    taken in ground coordinates (affine maps keep midpoints; image averages do not).
    """
    g = frame.coordinates(np.asarray(corners, float)[:3])
    return g[0] + 0.5 * (g[1] - g[0]) + 0.5 * (g[2] - g[0])


def _xz(hv: np.ndarray, target: np.ndarray, d_c: float) -> tuple[np.ndarray, np.ndarray]:
    """x and z for (..., 2) arrays of (H², V²) (method: module docstring)."""
    H, V = np.sqrt(hv[..., 0]), np.sqrt(hv[..., 1])
    return target[0] * H, V * target[1] - d_c * hv[..., 0] / V


def _clip(poly: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Sutherland–Hodgman: keep the part of convex polygon (k, 2) where normal·p ≥ offset."""
    if len(poly) == 0:
        return poly
    s = poly @ normal - offset
    out = []
    for k in range(len(poly)):
        a, b, sa, sb = poly[k], poly[(k + 1) % len(poly)], s[k], s[(k + 1) % len(poly)]
        if sa >= 0:
            out.append(a)
        if (sa >= 0) != (sb >= 0):
            out.append(a + (b - a) * (sa / (sa - sb)))
    return np.array(out).reshape(-1, 2)


def pair_bounds(d1: np.ndarray, d2: np.ndarray, range1: tuple[float, float], range2: tuple[float, float],
                target: np.ndarray, d_c: float, *, focal_range_px: tuple[float, float] | None = None,
                edge_samples: int = EDGE_SAMPLES):
    """Bounds on x, z and the ground distance over all stated lengths that give a solution.

    Parameters
    ----------
    d1, d2 : (2,) (Δξ, Δζ) of the two reference segments
    range1, range2 : (low, high) real lengths, metres
    target : (2,) (ξ_t, ζ_t) of the target
    d_c : signed distance of the principal point below the horizon, pixels
    focal_range_px : (low, high) focal lengths (pixels) a solution may imply, or None (any µ > 0)

    Returns
    -------
    (x_bounds, z_bounds, distance_bounds) as (2,) arrays, or None when no stated lengths give
    H² > 0 and V² > d_c² H² (with µ in ``focal_range_px``). A singular system raises
    ``numpy.linalg.LinAlgError``; check :func:`pair_conditioning` first.
    """
    (a1, b1), (a2, b2) = np.square(range1), np.square(range2)
    corners = solve_pair(d1, d2, np.array([a1, b1, b1, a1]), np.array([a2, a2, b2, b2]))
    if not np.all(np.isfinite(corners)):
        return None
    scale = max(np.abs(corners).max(), 1e-300)
    poly = _clip(corners, np.array([1.0, 0.0]), 1e-12 * np.abs(corners[:, 0]).max())
    lo, hi = (0.0, None) if focal_range_px is None else focal_range_px
    poly = _clip(poly, np.array([-(d_c**2 + lo**2), 1.0]), 1e-12 * scale)
    if hi is not None:
        poly = _clip(poly, np.array([d_c**2 + hi**2, -1.0]), 0.0)
    if len(poly) == 0:
        return None
    t = np.linspace(0.0, 1.0, edge_samples)[:, None, None]
    edges = poly[None] + t * (np.roll(poly, -1, axis=0) - poly)[None]
    x, z = _xz(edges.reshape(-1, 2), target, d_c)
    dist = np.hypot(x, z)
    return (np.array([x.min(), x.max()]), np.array([z.min(), z.max()]),
            np.array([dist.min(), dist.max()]))


@dataclass(frozen=True)
class SkipRules:
    """Thresholds of the skip rules (:data:`SKIP_REASONS`).

    Attributes
    ----------
    min_conditioning : skip pairs with κ below this (near-parallel or mirror-image segments)
    max_distance_m : skip pairs whose target distance bound exceeds this, metres
    min_horizon_px : points closer than this to the horizon (or above it) are unusable, pixels
    max_pixel_sensitivity : skip pairs where moving one reference endpoint by one pixel changes
        the target's ground distance (at the centres of the stated ranges) by more than this
        fraction; None turns the rule off (it catches noisy, nearly parallel pairs that pass
        the κ rule)
    """

    min_conditioning: float = MIN_CONDITIONING
    max_distance_m: float = MAX_DISTANCE_M
    min_horizon_px: float = MIN_HORIZON_PX
    max_pixel_sensitivity: float | None = MAX_PIXEL_SENSITIVITY


def _distances(lines: np.ndarray, lengths_sq: np.ndarray, frame: GroundFrame, target: np.ndarray):
    """Target ground distance for (k, 2, 2, 2) pairs of lines; NaN where infeasible, shape (k,)."""
    g = frame.coordinates(lines.reshape(-1, 2)).reshape(-1, 2, 2, 2)
    d = g[:, :, 1] - g[:, :, 0]  # (k, 2 lines, (Δξ, Δζ))
    A = np.square(d)
    with np.errstate(all="ignore"):
        hv = np.linalg.solve(A, np.broadcast_to(lengths_sq, (len(A), 2))[..., None])[..., 0]
        ok = (hv[:, 0] > 0) & (hv[:, 1] > frame.d_c**2 * hv[:, 0])
        x, z = _xz(np.where(ok[:, None], hv, 1.0), target, frame.d_c)
    return np.where(ok, np.hypot(x, z), np.nan)


def pixel_sensitivity(lines: np.ndarray, lengths: tuple[float, float], frame: GroundFrame,
                      target: np.ndarray) -> float:
    """Largest relative change of the target distance when one endpoint moves by one pixel.

    Parameters
    ----------
    lines : (2, 2, 2) the two reference segments, pixels
    lengths : their real lengths, metres

    Returns
    -------
    float, fraction per pixel; inf when a one-pixel move (or the unmoved lines) has no solution
    """
    lines = np.asarray(lines, float)
    moved = np.repeat(lines[None], 9, axis=0)
    moved.reshape(9, 8)[np.arange(1, 9), np.arange(8)] += 1.0
    try:
        dist = _distances(moved, np.square(lengths), frame, target)
    except np.linalg.LinAlgError:
        return float("inf")
    if not np.all(np.isfinite(dist)):
        return float("inf")
    return float(np.max(np.abs(dist[1:] - dist[0])) / dist[0])


def assess_pair(i: int, j: int, line_i: np.ndarray, line_j: np.ndarray, range_i: tuple[float, float],
                range_j: tuple[float, float], frame: GroundFrame, target: np.ndarray, *,
                rules: SkipRules | None = None, focal_range_px=None) -> PairResult:
    """Bounds from one pair of references, or the reason it is skipped.

    Parameters
    ----------
    i, j : reference indices (reported)
    line_i, line_j : (2, 2) segments, pixels, both endpoints below the horizon
    range_i, range_j : (low, high) real lengths, metres
    frame : the ground frame; target : (ξ_t, ζ_t) from :func:`target_ground_point`
    rules : :class:`SkipRules` (defaults); focal_range_px : see :func:`pair_bounds`
    """
    rules = rules or SkipRules()
    lines = np.stack([line_i, line_j]).astype(float)
    if np.any(frame.distance(lines.reshape(-1, 2)) < rules.min_horizon_px):
        return PairResult(i, j, "endpoint_above_horizon")
    g = frame.coordinates(lines.reshape(-1, 2)).reshape(2, 2, 2)
    d1, d2 = g[0, 1] - g[0, 0], g[1, 1] - g[1, 0]
    kappa = pair_conditioning(d1, d2)
    if kappa < rules.min_conditioning:
        return PairResult(i, j, "near_parallel", kappa)
    bounds = pair_bounds(d1, d2, range_i, range_j, target, frame.d_c, focal_range_px=focal_range_px)
    if bounds is None:
        return PairResult(i, j, "no_positive_solution", kappa)
    xb, zb, db = bounds
    if zb[1] <= 0:
        return PairResult(i, j, "behind_camera", kappa)
    if db[1] > rules.max_distance_m:
        return PairResult(i, j, "implausible_distance", kappa)
    centre = (float(np.mean(range_i)), float(np.mean(range_j)))
    hv = solve_pair(d1, d2, centre[0] ** 2, centre[1] ** 2)
    point = {}
    if hv[0] > 0 and hv[1] > frame.d_c**2 * hv[0]:
        x, z = _xz(hv, target, frame.d_c)
        mu = np.sqrt(hv[1] / hv[0] - frame.d_c**2)
        point = dict(x=float(x), z=float(z), focal_length_px=float(mu),
                     camera_height_m=float(mu * hv[0] / np.sqrt(hv[1])))
        point["pixel_sensitivity"] = pixel_sensitivity(lines, centre, frame, target)
        if rules.max_pixel_sensitivity is not None and point["pixel_sensitivity"] > rules.max_pixel_sensitivity:
            return PairResult(i, j, "unstable", kappa, pixel_sensitivity=point["pixel_sensitivity"])
    return PairResult(i, j, None, kappa, xb, zb, db, **point)


def aggregate_references(corners: np.ndarray, references, camera, *, on: str = "xz", rules: SkipRules | None = None,
                         focal_range_px: tuple[float, float] | None = None) -> ReferenceReport:
    """Every pair of references → bounds on a target's x and z (Eq. 8–11).

    Parameters
    ----------
    corners : (4, 2) the target's dimension-line corners t1..t4 (the per-corner median), pixels
    references : ground segments with their stated real length: objects with ``index``, ``line``
        ((2, 2) pixels), ``low`` and ``high`` (metres)
    camera : :class:`~creference_bayes.core.geometry.Camera` (its horizon; level when it has none)
    on : ``"xz"`` to penalise x and z, ``"distance"`` to penalise √(x² + z²)
    rules : :class:`SkipRules` (the module's defaults when None)
    focal_range_px : (low, high) focal lengths (pixels) a solution may imply (e.g. the optimiser's
        bounds on µ), or None for any µ > 0

    Returns
    -------
    ReferenceReport; its ``constraints`` is None when no pair is usable (fewer than 2 references)
    """
    if on not in ("xz", "distance"):
        raise ValueError(f"on: expected 'xz' or 'distance', got {on!r}")
    frame = GroundFrame.from_camera(camera)
    corners = np.asarray(corners, float)
    rules = rules or SkipRules()
    target_ok = bool(np.all(frame.distance(corners[:3]) >= rules.min_horizon_px))
    target = target_ground_point(corners, frame) if target_ok else np.zeros(2)
    pairs = tuple(
        assess_pair(ri.index, rj.index, ri.line, rj.line, (ri.low, ri.high), (rj.low, rj.high),
                    frame, target, rules=rules, focal_range_px=focal_range_px) if target_ok
        else PairResult(ri.index, rj.index, "target_above_horizon")
        for ri, rj in combinations(references, 2))
    used = [p for p in pairs if p.used]
    constraints = None
    if used:
        constraints = SoftConstraints(
            x_bounds=np.array([p.x_bounds for p in used]), z_bounds=np.array([p.z_bounds for p in used]),
            distance_bounds=np.array([p.distance_bounds for p in used]), on=on)
    return ReferenceReport(len(references), pairs, constraints, on)
