"""The two display clocks (`schedule.Clock`). `Lockstep` follows the simulation time of
the inputs (a replay: the same frames whatever the machine's speed); `Realtime` follows
the wall clock, with simulation time = wall time + an offset learned from the inputs.
Each owns its frame policy (when frames fall due, how a pass makes room for them) and
its sender policy (`schedule.Publishing`); `make_clock` picks one from `--clock`.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import zenoh

from .. import defaults
from ..tracking.batches import Labelled, StepOutcome
from ..wire import PlotScan
from .plan import Plan
from .schedule import MAX_GAP_FRAMES, TOL, Clock, Frames, Pass, Publishing, Report
from .senders import FrameSender, InlineFrameSender, InlineTrackSender, TrackSender

if TYPE_CHECKING:
    from .admit import Admit


def make_clock(kind: str, rate: float, lag: float = 0.0) -> Clock:
    """The clock of `--clock` (a key of `CLOCKS`), at `rate` Hz, `lag` s behind."""
    if kind not in CLOCKS:
        raise ValueError(f"unknown clock {kind!r}")
    return CLOCKS[kind](rate, lag=lag)


class Lockstep:
    """The input-driven clock: before an input at time t is applied, every instant strictly
    before t - lag not yet published is due; the first input sets the start. The picture
    is the newest input taken; frames and states go out in line, in order, waiting for
    every subscriber (a replay gives the same outputs whatever the machine's speed)."""

    name = "lockstep"
    missed = 0  # never: a frame is due before an input, not on the wall clock
    publishing = Publishing(zenoh.CongestionControl.BLOCK, InlineFrameSender,
                            InlineTrackSender, 0.0)

    def __init__(self, rate: float, lag: float = 0.0) -> None:
        self.rate, self.lag = rate, lag
        self.next_n: int | None = None
        self.skipped = 0

    # ------------------------------------------------------------ the worker's clock
    def picture(self, wall: float, newest: float | None) -> float | None:
        return newest

    def timeout(self, wall: float, poll: float) -> float:
        return poll

    def rows(self, plan: Plan, rows: Labelled, walls: list[float], held: float | None
             ) -> None:
        """The frames due before the rows, and between two of them where one falls due."""
        t = rows.batch.t
        self._frames(plan, float(t[0]), held)
        start = 0
        while (i := self.first_due(t, start + 1, held)) is not None:
            plan.wait(rows.rows(start, i))
            start = i
            self._frames(plan, float(t[i]), held)
        plan.wait(rows.rows(start, len(t)) if start else rows)

    def scan(self, plan: Plan, t: float, wall: float, released: list[tuple[str, PlotScan]],
             held: float | None) -> None:
        self.released(plan, released, held)

    def clock_message(self, plan: Plan, t: float, wall: float, held: float | None) -> None:
        """The frames its time makes due (they show the rows received before it)."""
        self._frames(plan, t, held)

    def released(self, plan: Plan, scans: list[tuple[str, PlotScan]], held: float | None
                 ) -> None:
        """Each scan after the frames due before it."""
        for key, scan in scans:
            self._frames(plan, scan.t, held)
            plan.scan(key, scan)

    def apply(self, rows: Labelled, frames: Frames, run: Pass, report: Report) -> None:
        """One pass over the rows, whole."""
        report(rows, run(rows, None))

    def end(self, plan: Plan, wall: float, admit: Admit, frames: Frames) -> None:
        """The rows waiting applied (what comes next may be long in coming)."""
        plan.apply()

    def _frames(self, plan: Plan, t: float, held: float | None) -> None:
        """The instants due before an input of time t (or the oldest scan held back, if
        older: the frames wait for it)."""
        for instant in self.due_before(t if held is None else min(t, held)):
            plan.frame(instant)

    # ------------------------------------------------------------ its instants
    def due_before(self, t: float) -> list[float]:
        t -= self.lag
        if self.next_n is None:
            self.next_n = math.ceil((t - TOL) * self.rate)
            return []
        last = math.ceil((t - TOL) * self.rate) - 1  # largest n with n/rate < t - TOL
        if last < self.next_n:
            return []
        if last - self.next_n >= MAX_GAP_FRAMES:
            self.skipped += last - self.next_n + 1 - MAX_GAP_FRAMES
            self.next_n = last + 1 - MAX_GAP_FRAMES
        due = [n / self.rate for n in range(self.next_n, last + 1)]
        self.next_n = last + 1
        return due

    def due_soon(self, t: float) -> bool:
        """Whether `due_before(t)` would give an instant (without taking it)."""
        return (self.next_n is not None
                and math.ceil((t - self.lag - TOL) * self.rate) - 1 >= self.next_n)

    def first_due(self, t: np.ndarray, start: int, held: float | None) -> int | None:
        for i, x in enumerate(t[start:].tolist(), start):
            if self.due_soon(x if held is None else min(x, held)):
                return i
        return None

    def restart(self, t: float) -> None:
        """The next input starts the frames again as the first one did; the instants of
        a gap forward are skipped."""
        if self.next_n is not None:
            self.skipped += max(0, math.ceil((t - TOL) * self.rate) - self.next_n)
        self.next_n = None

    def save(self) -> dict[str, Any]:
        return {"kind": self.name, "next_n": self.next_n}

    def load(self, saved: dict[str, Any], wall: float) -> str:
        if saved.get("kind") != self.name:
            return ""
        n, t = saved.get("next_n"), saved.get("picture_t")
        if isinstance(n, int):
            self.next_n = n
        return f"; lockstep picture at t={t:.3f}" if isinstance(t, int | float) else ""


class Realtime:
    """Frames on a wall-clock schedule at the display rate.

    The offset is the largest (t_input - t_wall_received) seen over the last `window`
    seconds: transport latency only ever makes an input look older, so the maximum is
    the best estimate of the feed's clock. A jump larger than `jump` seconds (a new
    replay) resets it. Deadlines are absolute (instant - offset), so frames neither
    drift nor bunch up: when the service falls behind it skips to the newest due
    instant and counts the ones it missed. Frames may fall due at any moment, within a
    step too: what waits is applied before the clock learns a new time, a long update
    pauses for them, a pass takes at most `defaults.PASS_ROWS` rows, a stale frame may
    be dropped (congestion control DROP), and frames and states go out from threads of
    their own (`senders`).
    """

    name = "realtime"
    skipped = 0  # never: the wall clock skips by missing (`missed`)
    publishing = Publishing(zenoh.CongestionControl.DROP, FrameSender, TrackSender,
                            defaults.LISTENERS_REFRESH)

    def __init__(self, rate: float, window: float = 10.0, jump: float = 2.0,
                 lag: float = 0.0) -> None:
        self.rate, self.window, self.jump, self.lag = rate, window, jump, lag
        self.samples: deque[tuple[float, float]] = deque()
        self.offset: float | None = None
        self.last_n: int | None = None
        self.missed = 0
        self.unswept: float | None = None  # a frame put within a step, not yet swept

    # ------------------------------------------------------------ the worker's clock
    def picture(self, wall: float, newest: float | None) -> float | None:
        return self.sim_time(wall)

    def sim_time(self, wall: float) -> float | None:
        """The simulation time the wall clock has reached (None: no input yet)."""
        return None if self.offset is None else wall + self.offset

    def timeout(self, wall: float, poll: float) -> float:
        """Until the next instant's deadline, at most `poll`."""
        deadline = self.next_deadline(wall)
        return poll if deadline is None else min(max(deadline - wall, 0.0), poll)

    def restart(self, t: float) -> None:
        """The offsets learned on the old timeline are forgotten (the next input's sets
        the new one)."""
        self.samples.clear()

    def rows(self, plan: Plan, rows: Labelled, walls: list[float], held: float | None
             ) -> None:
        """A pass of at most `PASS_ROWS` rows (the frame due goes out between passes),
        then the clock learns the rows' times."""
        t = rows.batch.t
        if plan.waiting and plan.waiting + len(t) > defaults.PASS_ROWS:
            plan.apply()
        plan.do(self.observe_all, t, walls)
        plan.wait(rows)

    def scan(self, plan: Plan, t: float, wall: float, released: list[tuple[str, PlotScan]],
             held: float | None) -> None:
        plan.do(self.observe, t, wall)
        self.released(plan, released, held)

    def clock_message(self, plan: Plan, t: float, wall: float, held: float | None) -> None:
        """The rows received before it applied, then the clock learns its time (a frame
        may fall due at once: it shows them)."""
        plan.apply()
        plan.do(self.observe, t, wall)

    def released(self, plan: Plan, scans: list[tuple[str, PlotScan]], held: float | None
                 ) -> None:
        for key, scan in scans:
            plan.scan(key, scan)

    def apply(self, rows: Labelled, frames: Frames, run: Pass, report: Report) -> None:
        """The frame due goes out before the pass and after it (a step of a burst spends
        most of its time in the pass), and between parts of a long update, the states of
        the part done before it."""
        def pause(outcome: StepOutcome) -> None:
            frames.out.put_states(outcome.states)
            outcome.states.clear()
            self.between(frames)

        self.between(frames)
        outcome = run(rows, pause)
        self.between(frames)
        report(rows, outcome)

    def end(self, plan: Plan, wall: float, admit: Admit, frames: Frames) -> None:
        """The rows waiting applied, the scans the wall clock releases, then the frame due
        now or the sweep of the one put within the step."""
        plan.apply()
        if len(admit) and (now := self.sim_time(wall)) is not None:
            self.released(plan, admit.release(now), admit.held())
        plan.do(self.settle, frames)

    def between(self, frames: Frames) -> None:
        """Within a step (around a pass, between two parts of an update): the frame due, if
        any, and nothing else (no deletion, no held scan: the rows still to come hold their
        tracks); `settle` coasts and deletes at its instant."""
        instant = self._due_now(frames)
        if instant is not None:
            frames.show(instant)
            self.unswept = instant

    def settle(self, frames: Frames) -> None:
        """At the end of a step: the frame due now, or the coast and delete of the frame
        put within the step."""
        instant = self._due_now(frames)
        if instant is not None:
            frames.publish(instant)
            self.unswept = None
        elif self.unswept is not None:
            frames.sweep(self.unswept)
            self.unswept = None

    def _due_now(self, frames: Frames) -> float | None:
        """The display instant due now, if any (the listeners looked at and the instants
        missed counted first)."""
        instant = self.due(time.time())
        if instant is not None:
            frames.out.look()
            frames.out.count.frames_missed = self.missed + frames.out.replaced
        return instant

    # ------------------------------------------------------------ its instants

    def observe(self, t: float, wall: float) -> None:
        off = t - wall
        if self.offset is not None and abs(off - self.offset) > self.jump:
            self.samples.clear()  # a new timeline: forget the old offset and schedule
            self.last_n = None
        while self.samples and self.samples[-1][1] <= off:
            self.samples.pop()  # monotonic deque: offsets decrease from the front
        self.samples.append((wall, off))
        while self.samples[0][0] < wall - self.window:
            self.samples.popleft()
        self.offset = self.samples[0][1]

    def observe_all(self, t: np.ndarray, walls: list[float]) -> None:
        """The newest time of each arrival stamp observed (what observing each would
        leave)."""
        if walls[0] == walls[-1] and len(set(walls)) == 1:  # one arrival stamp (usual)
            self.observe(float(t.max()), walls[0])
            return
        newest: dict[float, float] = {}
        for x, w in zip(t.tolist(), walls, strict=True):
            if x > newest.get(w, -math.inf):
                newest[w] = x
        for w, x in newest.items():
            self.observe(x, w)

    def next_deadline(self, wall: float) -> float | None:
        """Wall time of the next display instant, None before the first input."""
        if self.offset is None:
            return None
        n = self.last_n + 1 if self.last_n is not None else \
            math.floor((wall + self.offset) * self.rate) + 1
        return n / self.rate - self.offset

    def due(self, wall: float) -> float | None:
        """The display instant to publish at wall time `wall` (less the lag), if any."""
        if self.offset is None:
            return None
        n = math.floor((wall - self.lag + self.offset) * self.rate + TOL)
        if self.last_n is not None:
            if n <= self.last_n:
                return None
            self.missed += n - self.last_n - 1
        self.last_n = n
        return n / self.rate

    def save(self) -> dict[str, Any]:
        return {"kind": self.name, "offset": self.offset}

    def load(self, saved: dict[str, Any], wall: float) -> str:
        """Frames go on at once, the offset of simulation time to wall time kept."""
        off = saved.get("offset")
        if saved.get("kind") != self.name or not isinstance(off, int | float) \
                or abs(off) >= 1e12:
            return ""
        self.observe(wall + off, wall)
        return f"; realtime frames resume at t={wall + off:.3f}"


CLOCKS: dict[str, Callable[..., Clock]] = {"lockstep": Lockstep, "realtime": Realtime}
