"""Wire models behind one ``WireConfig`` (see base.py and docs/physics.md)."""

from __future__ import annotations

from wirecraft.assets.wires import articulated, fem, rod  # noqa: F401  (registers the models)
from wirecraft.assets.wires.base import (
    ENDS,
    WIRE_MODELS,
    WireConfig,
    WireHandle,
    add_wire,
    end_gap,
)

__all__ = ["ENDS", "WIRE_MODELS", "WireConfig", "WireHandle", "add_wire", "end_gap"]
