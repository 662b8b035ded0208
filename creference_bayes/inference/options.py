"""Sampler settings from a user's dict: one rule for every sampler's settings dataclass."""

from __future__ import annotations

from dataclasses import fields

__all__ = ["settings_from_options"]


def settings_from_options(cls, options: dict | None):
    """``cls(**options)``; keys that are not fields of the dataclass ``cls`` are rejected with a
    :class:`ValueError` naming them (and the field's own checks name a bad value)."""
    options = dict(options or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ValueError(f"sampling: unknown option(s) {unknown} (expected some of {sorted(known)})")
    return cls(**options)
