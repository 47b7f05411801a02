"""WireCraft: a simulation benchmark for wire and cable manipulation on MuJoCo."""

from __future__ import annotations

__version__ = "0.1.0"
