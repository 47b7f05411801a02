"""The insertion task's options."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from wirecraft.assets.connectors import CONNECTORS, make_connector
from wirecraft.cli_args import number
from wirecraft.tasks.options import TaskOptions, option


@dataclass(frozen=True)
class InsertionOptions(TaskOptions):
    family: ClassVar[str] = "insertion"

    connector: str = option("ethernet", "plug and port", names=CONNECTORS.names)
    clearance: float = option(0.003, "socket clearance per side (m)", parse=number(0))

    def __post_init__(self) -> None:
        make_connector(self.connector, self.clearance)  # ValueError listing the valid ones
