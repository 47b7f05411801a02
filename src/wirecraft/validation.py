"""Checks used by config dataclasses: a bad value fails at construction, naming the field."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np


def finite(owner: str, field: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{field} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{owner}.{field} must be finite, got {value!r}")
    return value


def positive(owner: str, field: str, value: float) -> float:
    value = finite(owner, field, value)
    if value <= 0:
        raise ValueError(f"{owner}.{field} must be > 0, got {value!r}")
    return value


def non_negative(owner: str, field: str, value: float) -> float:
    value = finite(owner, field, value)
    if value < 0:
        raise ValueError(f"{owner}.{field} must be >= 0, got {value!r}")
    return value


def in_range(
    owner: str, field: str, value: float, low: float, high: float, *, high_open: bool = False
) -> float:
    value = finite(owner, field, value)
    if value < low or value > high or (high_open and value == high):
        bracket = ")" if high_open else "]"
        raise ValueError(f"{owner}.{field} must be in [{low}, {high}{bracket}, got {value!r}")
    return value


def at_least_int(owner: str, field: str, value: int, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{owner}.{field} must be an integer, got {value!r}")
    if value < low:
        raise ValueError(f"{owner}.{field} must be >= {low}, got {value!r}")
    return value


def boolean(owner: str, field: str, value: object) -> bool:
    # A string such as "false" would otherwise read as True.
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{owner}.{field} must be True or False, got {value!r}")
    return bool(value)


def one_of(owner: str, field: str, value: object, allowed: Iterable[object]) -> object:
    allowed = list(allowed)
    if value not in allowed:
        raise ValueError(
            f"{owner}.{field} must be one of {', '.join(map(repr, allowed))}; got {value!r}"
        )
    return value


def rgba(owner: str, field: str, value: Iterable[float]) -> tuple[float, float, float, float]:
    values = tuple(float(v) for v in value)
    if len(values) != 4 or not all(0.0 <= v <= 1.0 for v in values):
        raise ValueError(f"{owner}.{field} must be 4 numbers in [0, 1], got {value!r}")
    return values  # type: ignore[return-value]
