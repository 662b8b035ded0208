"""Length units accepted in scene files (formats.md): m, cm, ft, in, yd."""

from __future__ import annotations

__all__ = ["UNITS_TO_M", "to_metres"]

#: Metres per unit.
UNITS_TO_M: dict[str, float] = {
    "m": 1.0,
    "cm": 0.01,
    "ft": 0.3048,
    "in": 0.0254,
    "yd": 0.9144,
}


def to_metres(value: float, unit: str) -> float:
    """Convert ``value`` in ``unit`` to metres.

    Raises
    ------
    ValueError
        If ``unit`` is not one of :data:`UNITS_TO_M`.
    """
    try:
        return float(value) * UNITS_TO_M[unit]
    except KeyError:
        raise ValueError(f"unknown unit {unit!r} (expected one of {sorted(UNITS_TO_M)})") from None
