"""What admission makes of an input: an ordered plan that the worker carries out in one
loop (`worker.TrackService._carry_out`).

Admission (the time policy, the reorder buffer, the clock driver's frames) decides; the
plan records, in the order they must happen, the rejections to report, the labelled rows
to wait for the next pass, the frames, the scans, the answers and the clock's own steps.
A step that must see the rows waiting (a frame, a scan, an answer, `Apply`) has them
applied first, in one pass: the only place a pass is started.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..tracking.batches import Labelled
from ..wire import PlotScan
from .ingest import Query


@dataclass(frozen=True)
class Reject:
    """An input (or a row of one) refused: reported on `errors/`."""

    key: str
    sensor: str
    reason: str


@dataclass(frozen=True)
class Wait:
    """Labelled rows taken: they wait for the next pass."""

    rows: Labelled


@dataclass(frozen=True)
class Apply:
    """The rows waiting applied now."""


@dataclass(frozen=True)
class Frame:
    """A display instant: its coast-and-delete step and its frame."""

    t: float


@dataclass(frozen=True)
class ApplyScan:
    """An unlabelled scan the reorder buffer let go, applied."""

    key: str
    scan: PlotScan


@dataclass(frozen=True)
class Answer:
    """A query answered (after the rows before it)."""

    query: Query


@dataclass(frozen=True)
class Do:
    """A step of the clock driver's own, in its place (the wall clock learning an input's
    time after the rows before it were applied; a frame due at the end of a step)."""

    run: Callable[..., Any]
    args: tuple = ()


Step = Reject | Wait | Apply | Frame | ApplyScan | Answer | Do
SEES_ROWS = (Apply, Frame, ApplyScan, Answer)  # the steps that apply the rows waiting first


class Plan(list[Step]):
    """The steps of one input, in order, and the rows waiting once they are carried out
    as far as the last step (`waiting`: since the last step that applies them;
    `planned`: every row planned and not yet carried out)."""

    def __init__(self, waiting: int = 0) -> None:
        super().__init__()
        self.waiting, self.planned = waiting, 0

    def reject(self, key: str, sensor: str, reason: str) -> None:
        self.append(Reject(key, sensor, reason))

    def wait(self, rows: Labelled) -> None:
        self.append(Wait(rows))
        self.waiting += len(rows)
        self.planned += len(rows)

    def apply(self) -> None:
        self._sees(Apply())

    def frame(self, t: float) -> None:
        self._sees(Frame(t))

    def scan(self, key: str, scan: PlotScan) -> None:
        self._sees(ApplyScan(key, scan))

    def answer(self, query: Query) -> None:
        self._sees(Answer(query))

    def do(self, run: Callable[..., Any], *args: Any) -> None:
        self.append(Do(run, args))

    def _sees(self, step: Step) -> None:
        self.append(step)
        self.waiting = 0

    def carried_out(self, waiting: int) -> None:
        """Every step done (`waiting`: the rows left waiting): the plan starts empty."""
        self.clear()
        self.waiting, self.planned = waiting, 0


class Refusals:
    """The bad messages of a run of single measurements (message index, key, sensor,
    reason), reported into the plan in message order among the good ones (`fine`: the
    good ones' message indices)."""

    def __init__(self, bad: list[tuple], fine: list[int], plan: Plan) -> None:
        self.bad, self.fine, self.plan, self.next = bad, fine, plan, 0

    def before(self, upto: int) -> None:
        """The bad messages before good message `upto` (in `fine`; beyond: all)."""
        at = self.fine[upto] if upto < len(self.fine) else math.inf
        while self.next < len(self.bad) and self.bad[self.next][0] < at:
            self.plan.reject(*self.bad[self.next][1:])
            self.next += 1
