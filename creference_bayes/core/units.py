"""Length units accepted in scene files (formats.md): m, cm, ft, in, yd."""

from __future__ import annotations

__all__ = ["UNITS_TO_M"]

#: Metres per unit.
UNITS_TO_M: dict[str, float] = {
    "m": 1.0,
    "cm": 0.01,
    "ft": 0.3048,
    "in": 0.0254,
    "yd": 0.9144,
}
