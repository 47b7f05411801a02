"""The seating task's options."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from wirecraft import validation
from wirecraft.assets.connectors import CONNECTORS, make_connector
from wirecraft.tasks.options import TaskOptions, option

CHANNELS = ("straight", "curved")


@dataclass(frozen=True)
class SeatingOptions(TaskOptions):
    family: ClassVar[str] = "seating"

    channel: str = option("straight", "channel shape", names=lambda: list(CHANNELS))
    connector: str = option("ethernet", "plug on the cable's end", names=CONNECTORS.names)

    def __post_init__(self) -> None:
        validation.one_of("seating", "channel", self.channel, CHANNELS)
        make_connector(self.connector)
