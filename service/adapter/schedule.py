"""The schedule of the display instants n / rate (docs/protocol.md §5): one `Clock`
interface, two clocks. `Lockstep` follows the simulation time of the inputs (a replay:
the same frames whatever the machine's speed); `Realtime` follows the wall clock, with
simulation time = wall time + an offset learned from the inputs. The worker asks the
clock what it needs (the picture's time, the instants due, when to wake) and never which
clock it has (`make_clock` picks it, from `--clock`). `Frames` publishes the instants
it makes due.
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..wire import TIME_TOL

if TYPE_CHECKING:
    from .publish import Publisher
    from .steps import Tracking

TOL = TIME_TOL  # s: "strictly before t" tolerance of the contract
MAX_GAP_FRAMES = 30 * 600  # a lockstep jump longer than this is skipped, not replayed


class Clock(Protocol):
    """When the display instants are due, and the picture's time the inputs are admitted
    against. `lag`: s the display instants trail the clock (`--display-lag`)."""

    name: str  # "lockstep" or "realtime" (`status`)
    # frames may fall due at any moment of the wall clock, within a step too: what waits is
    # applied before the clock learns a new time, a long update pauses for them, a stale
    # frame may be dropped (congestion control DROP) and is put from a thread of its own
    anytime: bool
    skipped: int  # instants skipped, never published (a lockstep jump)
    missed: int  # instants due while the worker was busy, not published

    def picture(self, wall: float) -> float | None:
        """The picture's time now, `wall` being the input's arrival (None: no time yet)."""

    def sim_time(self, wall: float) -> float | None:
        """The simulation time the wall clock has reached (None: the inputs' time leads)."""

    def taken(self, t: float) -> None:
        """An input of time t was admitted."""

    def observe(self, t: float, wall: float) -> None:
        """An input of time t received at `wall` (Unix s)."""

    def observe_all(self, t: np.ndarray, walls: list[float]) -> None:
        """Inputs of times t received at `walls` (each wall's newest time observed)."""

    def restart(self, t: float) -> None:
        """A new timeline at time t (`timeline.Timeline`)."""

    def due_before(self, t: float) -> list[float]:
        """The instants due before an input of time t is applied (taken)."""

    def first_due(self, t: np.ndarray, start: int, held: float | None) -> int | None:
        """The first index i >= start before whose input (time t[i], or `held`, the
        oldest input held back, if older) an instant falls due (None: none)."""

    def next_deadline(self, wall: float) -> float | None:
        """Wall time of the next instant (None: none is due by the wall clock)."""

    def due(self, wall: float) -> float | None:
        """The instant due at wall time `wall`, if any (taken)."""

    def save(self) -> dict[str, Any]:
        """What a checkpoint keeps of the clock."""

    def load(self, saved: dict[str, Any], wall: float) -> str:
        """Resume where `save` left (a clock of the other kind is not taken); a note."""


def make_clock(kind: str, rate: float, lag: float = 0.0) -> Clock:
    """The clock of `--clock` (`lockstep` or `realtime`)."""
    if kind == "lockstep":
        return Lockstep(rate, lag)
    if kind == "realtime":
        return Realtime(rate, lag=lag)
    raise ValueError(f"unknown clock {kind!r}")


class Lockstep:
    """Before an input at time t is applied, every instant strictly before t - lag not yet
    published is due. The first input sets the start."""

    name = "lockstep"
    anytime = False
    missed = 0

    def __init__(self, rate: float, lag: float = 0.0) -> None:
        self.rate, self.lag = rate, lag
        self.next_n: int | None = None
        self.skipped = 0
        self.picture_t: float | None = None  # the newest input time taken

    def picture(self, wall: float) -> float | None:
        return self.picture_t

    def sim_time(self, wall: float) -> float | None:
        return None

    def taken(self, t: float) -> None:
        if self.picture_t is None or t > self.picture_t:
            self.picture_t = t

    def observe(self, t: float, wall: float) -> None:
        pass  # the picture moves when an input is taken

    def observe_all(self, t: np.ndarray, walls: list[float]) -> None:
        pass

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
        self.picture_t = t

    def next_deadline(self, wall: float) -> float | None:
        return None

    def due(self, wall: float) -> float | None:
        return None

    def save(self) -> dict[str, Any]:
        return {"kind": self.name, "next_n": self.next_n, "picture_t": self.picture_t}

    def load(self, saved: dict[str, Any], wall: float) -> str:
        if saved.get("kind") != self.name:
            return ""
        n, t = saved.get("next_n"), saved.get("picture_t")
        if isinstance(n, int):
            self.next_n = n
        if isinstance(t, int | float):
            self.picture_t = float(t)
            return f"; lockstep picture at t={t:.3f}"
        return ""


class Realtime:
    """Frames on a wall-clock schedule at the display rate.

    The offset is the largest (t_input - t_wall_received) seen over the last `window`
    seconds: transport latency only ever makes an input look older, so the maximum is
    the best estimate of the feed's clock. A jump larger than `jump` seconds (a new
    replay) resets it. Deadlines are absolute (instant - offset), so frames neither
    drift nor bunch up: when the service falls behind it skips to the newest due
    instant and counts the ones it missed.
    """

    name = "realtime"
    anytime = True
    skipped = 0

    def __init__(self, rate: float, window: float = 10.0, jump: float = 2.0,
                 lag: float = 0.0) -> None:
        self.rate, self.window, self.jump, self.lag = rate, window, jump, lag
        self.samples: deque[tuple[float, float]] = deque()
        self.offset: float | None = None
        self.last_n: int | None = None
        self.missed = 0

    def picture(self, wall: float) -> float | None:
        return None if self.offset is None else wall + self.offset

    def sim_time(self, wall: float) -> float | None:
        return None if self.offset is None else wall + self.offset

    def taken(self, t: float) -> None:
        pass  # the picture follows the wall clock

    def restart(self, t: float) -> None:
        pass  # `observe` starts the new timeline's schedule itself

    def due_before(self, t: float) -> list[float]:
        return []  # due on the wall clock (`due`), not before an input

    def first_due(self, t: np.ndarray, start: int, held: float | None) -> int | None:
        return None

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


class Frames:
    """The display instants published, each with the tracks at it: an empty step at the
    instant (coast and delete), then its frame."""

    def __init__(self, clock: Clock, tracking: Tracking, out: Publisher) -> None:
        self.clock, self.tracking, self.out = clock, tracking, out
        self.unswept: float | None = None  # a frame published without its deletion

    def publish(self, t: float) -> None:
        self.out.deleted(self.tracking.instant(t))
        self.unswept = None
        self.out.frame(t, self.tracking.snapshot(t))

    def due(self) -> float | None:
        """The display instant due now on the wall clock, if any (the listeners looked at
        and the instants missed counted first)."""
        instant = self.clock.due(time.time())
        if instant is not None:
            self.out.look()
            self.out.count.frames_missed = self.clock.missed + self.out.replaced
        return instant

    def between(self) -> None:
        """Within a step (around a pass, between two parts of an update): the frame due, if
        any, and nothing else (no deletion, no held scan: the rows still to come hold their
        tracks); `settle` coasts and deletes at its instant."""
        instant = self.due()
        if instant is not None:
            self.out.frame(instant, self.tracking.snapshot(instant))
            self.unswept = instant

    def settle(self) -> None:
        """At the end of a step: the frame due now, or the coast and delete of the frame
        put within the step."""
        instant = self.due()
        if instant is not None:
            self.publish(instant)
        elif self.unswept is not None:
            self.out.deleted(self.tracking.instant(self.unswept))
            self.unswept = None
