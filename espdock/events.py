"""What running a plan reports, step by step: the runner emits these, the terminal UI renders them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum


class Outcome(StrEnum):
    BUILT = "built"
    CACHED = "cached"
    PULLED = "pulled"  # from the cache registry, instead of building
    FAILED = "failed"


@dataclass(frozen=True)
class StepStarted:
    step: str


@dataclass(frozen=True)
class StepOutput:
    step: str
    line: str
    # Progress lines (image builds) are shown as status; the rest is streamed.
    progress: bool = False
    # A terminal's status line only (a count of what is done): never printed as a line, in a log
    # or with --verbose, where the tool's own lines say it.
    status: bool = False


@dataclass(frozen=True)
class StepNote:
    step: str
    text: str


@dataclass(frozen=True)
class StepFinished:
    step: str
    outcome: Outcome
    seconds: float
    detail: str = ""


Event = StepStarted | StepOutput | StepNote | StepFinished
Emit = Callable[[Event], None]
