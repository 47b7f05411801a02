"""Checks used by config dataclasses: a bad value fails at construction, naming the field."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np


def number(owner: str, field: str, value: float) -> float:
    """``value`` as a float: strings and booleans are not numbers."""
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{owner}.{field} must be a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{field} must be a number, got {value!r}") from None


def finite(owner: str, field: str, value: float) -> float:
    value = number(owner, field, value)
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


def integer(owner: str, field: str, value: int) -> int:
    """``value`` as an int: a bool or a float (even 2.0) is not an integer."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{owner}.{field} must be an integer, got {value!r}")
    return int(value)


def at_least_int(owner: str, field: str, value: int, low: int) -> int:
    value = integer(owner, field, value)
    if value < low:
        raise ValueError(f"{owner}.{field} must be >= {low}, got {value!r}")
    return value


def int_in_range(owner: str, field: str, value: int, low: int, high: int, why: str = "") -> int:
    if (
        isinstance(value, (bool, np.bool_))
        or not isinstance(value, (int, np.integer))
        or not low <= value <= high
    ):
        why = f" ({why})" if why else ""
        raise ValueError(f"{owner}.{field} must be an integer in {low}..{high}{why}, got {value!r}")
    return int(value)


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


def mapping(owner: str, field: str, value: object) -> dict:
    if not isinstance(value, Mapping):
        raise ValueError(f"{owner}.{field} must be a dict, got {value!r}")
    return dict(value)


def rgba(owner: str, field: str, value: Iterable[float]) -> tuple[float, float, float, float]:
    values = tuple(float(v) for v in value)
    if len(values) != 4 or not all(0.0 <= v <= 1.0 for v in values):
        raise ValueError(f"{owner}.{field} must be 4 numbers in [0, 1], got {value!r}")
    return values  # type: ignore[return-value]
