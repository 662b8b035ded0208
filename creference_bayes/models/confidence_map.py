"""Confidence maps: how often a worker's range at a stated confidence c holds the truth, g(c).

A range [lo, hi] stated with confidence c claims to be a central c-interval of the worker's
belief. Stated intervals are over-confident, so the package reads the range at the *calibrated*
coverage g(c) (docs/confidence.md):

- ``identity``: g(c) = c, workers taken at their word;
- a fitted map (``creference confidence fit``): g at a few stated levels, with an uncertainty per
  level, PCHIP between them (monotone data stay monotone), constant beyond; optionally one curve
  per measure and mode (``"length/direct"``, …) with the pooled curve for the others;
- ``none`` (``None`` in Python): the confidence is ignored (the crowd scale of :mod:`.metrology`).

In log-length the range is a central interval of half-width w = (log hi − log lo)/2 around the
log-centre m = (log hi + log lo)/2; read at coverage p = g(c) through a symmetric distribution D
with scale s, P(|ε| < w/s) = p gives

    s = w / q_D((1 + p)/2),

q_D the quantile of D: the standard normal (``dof`` None) or a Student-t with ``dof`` degrees of
freedom (a fitted map chooses it). The metrology model treats m as a measurement of log ℓ with
that scale. g is kept within [:data:`COVERAGE_FLOOR`, :data:`COVERAGE_CEIL`]: a stated 100 % would
otherwise be an exact constraint, a stated 0 % an infinitely wide one.

The file format is ``creference-confidence-map/1`` (JSON; docs/confidence.md).

NumPy/SciPy and the standard library only.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.special import ndtri, stdtrit

__all__ = ["CONFIDENCE_MAP_FORMAT", "MAP_NAMES", "DEFAULT_CONFIDENCE_MAP", "COVERAGE_FLOOR", "COVERAGE_CEIL",
           "CoverageCurve", "ConfidenceMap", "ConfidenceMapError", "resolve_confidence_map",
           "describe_confidence_map", "group_key", "interval_quantile"]

CONFIDENCE_MAP_FORMAT = "creference-confidence-map/1"
#: The maps that need no file.
MAP_NAMES = ("none", "identity")
#: The map ``estimate`` and ``batch`` use unless told otherwise (docs/studies/confidence.md: the study
#: behind the choice). ``none`` keeps the treatment of scenes from before confidences were read.
DEFAULT_CONFIDENCE_MAP = "none"
#: Limits of the coverage a range is read at.
COVERAGE_FLOOR = 0.01
COVERAGE_CEIL = 0.999


class ConfidenceMapError(ValueError):
    """An invalid confidence map (file): the message names the key and the value."""


def group_key(measure: str, mode: str) -> str:
    """The key of a measure and mode in a map's ``groups``, e.g. ``"length/direct"``."""
    return f"{measure}/{mode}"


def interval_quantile(p, dof: float | None = None) -> np.ndarray:
    """q_D((1 + p)/2): the half-width, in scales, of D's central interval of probability ``p``.

    Parameters
    ----------
    p : coverage(s) in (0, 1)
    dof : Student-t degrees of freedom, or None for the standard normal
    """
    u = 0.5 * (1.0 + np.asarray(p, float))
    return ndtri(u) if dof is None else stdtrit(float(dof), u)


def _floats(value, path: str, *, lo: float = 0.0, hi: float = 1.0, increasing: str | None = None) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or not value:
        raise ConfidenceMapError(f"{path}: expected a non-empty list of numbers, got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            raise ConfidenceMapError(f"{path}[{i}]: expected a number in [{lo:g}, {hi:g}], got {v!r}")
        out.append(float(v))
    a = np.array(out)
    if increasing == "strict" and np.any(np.diff(a) <= 0):
        raise ConfidenceMapError(f"{path}: expected increasing values, got {list(value)}")
    if increasing == "weak" and np.any(np.diff(a) < 0):
        raise ConfidenceMapError(f"{path}: expected non-decreasing values (a map is monotone), got {list(value)}")
    return a


@dataclass(frozen=True)
class CoverageCurve:
    """g at a few stated confidence levels, with its uncertainty.

    Attributes
    ----------
    levels : (k,) stated confidences, strictly increasing, in [0, 1]
    coverage : (k,) the calibrated coverage g at each level, non-decreasing, in [0, 1]
    low, high : (k,) an interval of g at each level (probability: the map's ``interval_prob``), or None
    sd : (k,) standard error of g at each level, or None
    n : (k,) ranges behind each level, or None
    """

    levels: tuple[float, ...]
    coverage: tuple[float, ...]
    low: tuple[float, ...] | None = None
    high: tuple[float, ...] | None = None
    sd: tuple[float, ...] | None = None
    n: tuple[int, ...] | None = None

    def __post_init__(self):
        k = len(self.levels)
        for name in ("coverage", "low", "high", "sd", "n"):
            v = getattr(self, name)
            if v is not None and len(v) != k:
                raise ConfidenceMapError(f"{name}: expected {k} values (one per level), got {len(v)}")

    def __call__(self, c) -> np.ndarray:
        """g(c) for stated confidence(s) ``c``: PCHIP between the levels, constant beyond them."""
        return self._interp(self.coverage, c)

    def band(self, c) -> tuple[np.ndarray, np.ndarray]:
        """The interval of g(c) (``low``, ``high`` interpolated like g), or g itself without one."""
        if self.low is None or self.high is None:
            g = self(c)
            return g, g
        return self._interp(self.low, c), self._interp(self.high, c)

    def _interp(self, values, c) -> np.ndarray:
        x = np.asarray(self.levels, float)
        y = np.asarray(values, float)
        c = np.clip(np.asarray(c, float), x[0], x[-1])
        if len(x) == 1:
            return np.full(c.shape, y[0])
        return np.clip(PchipInterpolator(x, y)(c), 0.0, 1.0)

    def to_dict(self) -> dict:
        d = {"levels": list(self.levels), "coverage": list(self.coverage)}
        for name in ("low", "high", "sd"):
            if getattr(self, name) is not None:
                d[name] = list(getattr(self, name))
        if self.n is not None:
            d["n"] = [int(v) for v in self.n]
        return d

    @classmethod
    def from_dict(cls, d, path: str = "pooled") -> "CoverageCurve":
        if not isinstance(d, dict):
            raise ConfidenceMapError(f"{path}: expected an object, got {d!r}")
        unknown = set(d) - {"levels", "coverage", "low", "high", "sd", "n"}
        if unknown:
            raise ConfidenceMapError(f"{path}: unknown key(s) {sorted(unknown)}")
        for key in ("levels", "coverage"):
            if key not in d:
                raise ConfidenceMapError(f"{path}: missing required key {key!r}")
        levels = _floats(d["levels"], f"{path}.levels", increasing="strict")
        cov = _floats(d["coverage"], f"{path}.coverage", increasing="weak")
        opt = {k: tuple(_floats(d[k], f"{path}.{k}", hi=1.0)) for k in ("low", "high", "sd") if k in d}
        n = None
        if "n" in d:
            n = tuple(int(v) for v in _floats(d["n"], f"{path}.n", hi=math.inf))
        for k, v in {"coverage": cov, **opt, **({"n": n} if n is not None else {})}.items():
            if len(v) != len(levels):
                raise ConfidenceMapError(f"{path}.{k}: expected {len(levels)} values (one per level), got {len(v)}")
        return cls(tuple(levels), tuple(cov), opt.get("low"), opt.get("high"), opt.get("sd"), n)


@dataclass(frozen=True)
class ConfidenceMap:
    """A confidence map g (module docstring): the identity, or curves fitted from data.

    Attributes
    ----------
    kind : ``"identity"`` or ``"fitted"``
    pooled : the curve for every reference without a group of its own (None for the identity)
    groups : curves per ``"measure/mode"`` (:func:`group_key`)
    dof : the distribution a range is read through: None for the normal, else Student-t degrees
        of freedom
    interval_prob : probability of the curves' ``low``–``high`` intervals
    fit : how the map was made (a plain dict: method, scenes, ranges, bootstrap, seed, …)
    source : the file it was read from (not part of the map's content)
    """

    kind: str = "identity"
    pooled: CoverageCurve | None = None
    groups: dict = field(default_factory=dict)
    dof: float | None = None
    interval_prob: float = 0.95
    fit: dict = field(default_factory=dict)
    source: str | None = field(default=None, compare=False)

    def __post_init__(self):
        if self.kind not in ("identity", "fitted"):
            raise ConfidenceMapError(f"kind: expected 'identity' or 'fitted', got {self.kind!r}")
        if self.kind == "fitted" and self.pooled is None:
            raise ConfidenceMapError("pooled: a fitted map needs a pooled curve")
        if self.dof is not None and not (math.isfinite(self.dof) and self.dof > 0):
            raise ConfidenceMapError(f"dof: expected a number > 0 or null (normal), got {self.dof!r}")
        if not 0.0 < self.interval_prob < 1.0:
            raise ConfidenceMapError(f"interval_prob: expected a probability in (0, 1), got {self.interval_prob!r}")

    @classmethod
    def identity(cls, dof: float | None = None) -> "ConfidenceMap":
        """g(c) = c: workers taken at their word, read through the normal (or a Student-t)."""
        return cls(kind="identity", dof=dof)

    def curve(self, measure: str | None = None, mode: str | None = None) -> CoverageCurve | None:
        """The curve a reference of this measure and mode uses (None for the identity)."""
        if measure is not None and mode is not None and group_key(measure, mode) in self.groups:
            return self.groups[group_key(measure, mode)]
        return self.pooled

    def coverage(self, c, measure: str | None = None, mode: str | None = None) -> np.ndarray:
        """g(c), kept within [:data:`COVERAGE_FLOOR`, :data:`COVERAGE_CEIL`]."""
        c = np.asarray(c, float)
        curve = self.curve(measure, mode)
        g = c if curve is None else curve(c)
        return np.clip(g, COVERAGE_FLOOR, COVERAGE_CEIL)

    def scale(self, c, half_width, measure: str | None = None, mode: str | None = None) -> np.ndarray:
        """The scale s = w / q_D((1 + g(c))/2) of a range of log half-width(s) ``half_width``."""
        q = interval_quantile(self.coverage(c, measure, mode), self.dof)
        return np.asarray(half_width, float) / q

    def to_dict(self) -> dict:
        d = {"format": CONFIDENCE_MAP_FORMAT, "kind": self.kind, "dof": self.dof,
             "interval_prob": self.interval_prob}
        if self.pooled is not None:
            d["pooled"] = self.pooled.to_dict()
        if self.groups:
            d["groups"] = {k: self.groups[k].to_dict() for k in sorted(self.groups)}
        if self.fit:
            d["fit"] = self.fit
        return d

    def digest(self) -> str:
        """SHA-256 of the map's content (canonical JSON): two maps with equal digests read every
        range alike."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False)
        return hashlib.sha256(text.encode()).hexdigest()

    @classmethod
    def from_dict(cls, d, source: str | None = None) -> "ConfidenceMap":
        """A map from its ``creference-confidence-map/1`` document; :class:`ConfidenceMapError`
        naming the key and the value when it is invalid."""
        if not isinstance(d, dict):
            raise ConfidenceMapError(f"expected a JSON object, got {type(d).__name__}")
        if d.get("format") != CONFIDENCE_MAP_FORMAT:
            raise ConfidenceMapError(f"format: expected {CONFIDENCE_MAP_FORMAT!r}, got {d.get('format')!r}")
        unknown = set(d) - {"format", "kind", "dof", "interval_prob", "pooled", "groups", "fit"}
        if unknown:
            raise ConfidenceMapError(f"unknown key(s) {sorted(unknown)}")
        dof = d.get("dof")
        if dof is not None and (isinstance(dof, bool) or not isinstance(dof, (int, float))):
            raise ConfidenceMapError(f"dof: expected a number > 0 or null (normal), got {dof!r}")
        groups = d.get("groups", {})
        if not isinstance(groups, dict):
            raise ConfidenceMapError(f"groups: expected an object, got {groups!r}")
        fit = d.get("fit", {})
        if not isinstance(fit, dict):
            raise ConfidenceMapError(f"fit: expected an object, got {fit!r}")
        return cls(kind=d.get("kind", "fitted"),
                   pooled=None if d.get("pooled") is None else CoverageCurve.from_dict(d["pooled"]),
                   groups={k: CoverageCurve.from_dict(v, f"groups.{k}") for k, v in groups.items()},
                   dof=None if dof is None else float(dof), interval_prob=float(d.get("interval_prob", 0.95)),
                   fit=fit, source=source)

    @classmethod
    def load(cls, path: str | Path) -> "ConfidenceMap":
        """Read a map file; errors start with the file's path."""
        from ..core.jsonfile import read_json

        path = Path(path)
        d = read_json(path, lambda name, problem: ConfidenceMapError(f"{name}: {problem}"))
        try:
            return cls.from_dict(d, source=str(path))
        except ConfidenceMapError as exc:
            raise ConfidenceMapError(f"{path}: {exc}") from None


def resolve_confidence_map(value) -> ConfidenceMap | None:
    """The map meant by ``value``: ``"none"`` or None → None; ``"identity"``; ``"default"`` →
    :data:`DEFAULT_CONFIDENCE_MAP`; a :class:`ConfidenceMap` as it is; anything else is the path
    of a map file."""
    if value is None or isinstance(value, ConfidenceMap):
        return value
    if isinstance(value, str) and value == "default":
        value = DEFAULT_CONFIDENCE_MAP
    if isinstance(value, str) and value == "none":
        return None
    if isinstance(value, str) and value == "identity":
        return ConfidenceMap.identity()
    if not isinstance(value, (str, Path)):
        raise ConfidenceMapError(f"confidence map: expected 'none', 'identity', a file or a ConfidenceMap, "
                                 f"got {value!r}")
    return ConfidenceMap.load(value)


def describe_confidence_map(cmap: ConfidenceMap | None) -> dict:
    """A short, JSON-plain description of a map for results and batch settings: ``{"name":
    "none"}``, ``{"name": "identity", "dof": …}`` or ``{"name": "file", "source": …, "sha256": …}``."""
    if cmap is None:
        return {"name": "none"}
    if cmap.kind == "identity":
        return {"name": "identity", "dof": cmap.dof}
    return {"name": "file", "source": cmap.source, "sha256": cmap.digest()}
