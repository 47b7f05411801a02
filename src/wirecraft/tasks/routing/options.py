"""The routing task's options."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from wirecraft import validation
from wirecraft.assets.connectors import CONNECTORS, make_connector
from wirecraft.cli_args import number
from wirecraft.tasks.options import TaskOptions, option

MAX_CLIPS = 3


@dataclass(frozen=True)
class RoutingOptions(TaskOptions):
    family: ClassVar[str] = "routing"

    num_clips: int = option(1, "clips to route through", parse=number(1, 64, integer=True))
    # None: 2 mm narrower than the wire (its lips hold a seated wire; see RoutingTask).
    clip_opening: float | None = option(
        None, "clip mouth width (m)", parse=number(0, low_open=True)
    )
    connector: str = option("ethernet", "plug on the cable's end", names=CONNECTORS.names)

    def __post_init__(self) -> None:
        validation.int_in_range("routing", "num_clips", self.num_clips, 1, MAX_CLIPS)
        if self.clip_opening is not None:
            validation.positive("routing", "clip_opening", self.clip_opening)
        make_connector(self.connector)
