"""The schedule of the display instants n / rate (docs/protocol.md §5): what the worker
asks of its clock (`Clock`, the two drivers in `clocks`), how the service's outputs go
out under it (`Publishing`), and the frames it publishes (`Frames`). The worker asks the
clock what to do at each point of a step, never which clock it has.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import zenoh

from ..tracking.batches import Labelled, StepOutcome
from ..wire import TIME_TOL, PlotScan
from .plan import Plan

if TYPE_CHECKING:
    from .admit import Admit
    from .publish import Publisher
    from .steps import TrackerCalls

TOL = TIME_TOL  # s: "strictly before t" tolerance of the contract
MAX_GAP_FRAMES = 30 * 600  # a lockstep jump longer than this is skipped, not replayed
POLL = 0.001  # s: an idle worker looks in the measurement channels this often
IDLE_POLL = 0.01  # s: ... and this often once nothing has come for IDLE_AFTER
IDLE_AFTER = 10.0  # s: longer than a radar's scan period (a paused or absent feed)
DRAIN = 0.05  # s: the longest a worker waits for its tracks/ sender after a step (the
# frames falling due meanwhile published)
# a pass over labelled rows (rows, pause between parts of a long update, or None): its
# outcome, the deletions reported; then the outcome reported (`Report`)
Pass = Callable[[Labelled, Callable[[StepOutcome], None] | None], StepOutcome]
Report = Callable[[Labelled, StepOutcome], None]


@dataclass(frozen=True)
class Publishing:
    """How a clock's outputs go out: the congestion control of the display keys, the
    senders of frames and of `tracks/` states (`senders`), and how often the listeners
    of `display/` and `tracks/` are read again (0: at every step)."""

    display_cc: zenoh.CongestionControl
    frame_sender: Callable[[zenoh.Publisher], Any]
    track_sender: Callable[[zenoh.Session, zenoh.Encoding], Any]
    refresh: float


class Clock(Protocol):
    """When the display instants are due and what a step does for them, at each point
    the worker reaches; the picture's time the inputs are admitted against. Plans
    (`plan.Plan`) receive the steps. `lag`: s the display instants trail the clock."""

    name: str  # "lockstep" or "realtime" (`status`)
    skipped: int  # instants skipped, never published (a lockstep jump)
    missed: int  # instants due while the worker was busy, not published
    publishing: Publishing

    def picture(self, wall: float, newest: float | None) -> float | None:
        """The picture's time for an input arriving at `wall` (`newest`: the newest input
        time taken; None: no time yet)."""

    def timeout(self, wall: float, poll: float) -> float:
        """How long the worker may wait for input (at most `poll`)."""

    def restart(self, t: float) -> None:
        """A new timeline at time t (`timeline.Timeline`)."""

    def rows(self, plan: Plan, rows: Labelled, walls: list[float], held: float | None
             ) -> None:
        """Labelled rows taken, received at `walls` (`held`: the oldest scan held back)."""

    def scan(self, plan: Plan, t: float, wall: float, released: list[tuple[str, PlotScan]],
             held: float | None) -> None:
        """An unlabelled scan of time t taken; the scans the reorder buffer released."""

    def clock_message(self, plan: Plan, t: float, wall: float, held: float | None) -> None:
        """A clock message of time t taken (nothing older will come)."""

    def released(self, plan: Plan, scans: list[tuple[str, PlotScan]], held: float | None
                 ) -> None:
        """Scans the reorder buffer let go, to apply in order."""

    def apply(self, rows: Labelled, frames: Frames, run: Pass, report: Report) -> None:
        """One pass over labelled rows (`run`, then `report`), with the frames the clock
        puts around it."""

    def end(self, plan: Plan, wall: float, admit: Admit, frames: Frames) -> None:
        """The end of a step."""

    def save(self) -> dict[str, Any]:
        """What a checkpoint keeps of the clock."""

    def load(self, saved: dict[str, Any], wall: float) -> str:
        """Resume where `save` left (a clock of the other kind is not taken); a note."""


class Frames:
    """The display instants published, each with the tracks at it: an empty step at the
    instant (coast and delete), then its frame."""

    def __init__(self, calls: TrackerCalls, out: Publisher) -> None:
        self.calls, self.out = calls, out

    def publish(self, t: float) -> None:
        self.sweep(t)
        self.show(t)

    def show(self, t: float) -> None:
        """The frame of instant t alone (its coast and delete left for `sweep`)."""
        self.out.frame(t, self.calls.snapshot(t))

    def sweep(self, t: float) -> None:
        """The coast and delete of instant t."""
        self.out.deleted(self.calls.instant(t))
