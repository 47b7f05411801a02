"""Typed task options: each family's keywords as a frozen dataclass, validated on creation.

A family declares its options with ``option(...)`` fields; everything that offers or records
task keywords reads them from the dataclass: the environment (``make(task, **options)``), the
command line (one flag per field, ``--num-clips`` for ``num_clips``), the evaluation's
variant keys and seed lists, collect's recorded settings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar


def option(
    default: Any,
    help: str,
    *,
    parse: Callable[[str], Any] = str,
    names: Callable[[], list[str]] | None = None,
) -> Any:
    """A task option: its default, its help text, how the command line parses it (an argparse
    ``type=``) and, for an option that names something, the callable listing the valid names."""
    return dataclasses.field(
        default=default, metadata={"help": help, "parse": parse, "names": names}
    )


@dataclasses.dataclass(frozen=True)
class TaskOptions:
    """Base of every family's options (a family without options keeps this one)."""

    family: ClassVar[str] = "task"

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        return {f.name: f.default for f in dataclasses.fields(cls)}

    @classmethod
    def build(cls, values: dict[str, Any]) -> TaskOptions:
        """Options from keyword values; an unknown keyword is a ValueError listing the valid
        ones (validation errors come from ``__post_init__``)."""
        unknown = [key for key in values if key not in cls.names()]
        if unknown:
            valid = ", ".join(cls.names()) or "none"
            raise ValueError(
                f"{cls.family}: unknown option {unknown[0]!r}; valid: {valid} (plus the "
                "environment's keywords)"
            )
        return cls(**values)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def split_options(options_cls: type[TaskOptions], kwargs: dict[str, Any]) -> tuple[dict, dict]:
    """(the task options in ``kwargs``, the rest)."""
    names = set(options_cls.names())
    return (
        {k: v for k, v in kwargs.items() if k in names},
        {k: v for k, v in kwargs.items() if k not in names},
    )
