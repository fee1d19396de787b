"""Display clocks: which display instants n / rate to publish, and when (docs/protocol.md).

`Lockstep` follows the simulation time of the inputs; `Realtime` follows the wall clock,
with simulation time = wall time + an offset learned from the inputs.
"""

from __future__ import annotations

import math
from collections import deque

TOL = 1e-6  # s: "strictly before t" tolerance of the contract
MAX_GAP_FRAMES = 30 * 600  # a lockstep jump longer than this is skipped, not replayed


class Lockstep:
    """Before an input at time t is applied, every instant strictly before t not yet
    published is due. The first input sets the start."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.next_n: int | None = None
        self.skipped = 0

    def due_before(self, t: float) -> list[float]:
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
        return self.next_n is not None and math.ceil((t - TOL) * self.rate) - 1 >= self.next_n

    def restart(self, t: float) -> None:
        """A new timeline at time t (`timeline.Timeline`): the next input starts the
        frames again as the first one did; the instants of a gap forward are skipped."""
        if self.next_n is not None:
            self.skipped += max(0, math.ceil((t - TOL) * self.rate) - self.next_n)
        self.next_n = None


class Realtime:
    """Frames on a wall-clock schedule at the display rate.

    The offset is the largest (t_input - t_wall_received) seen over the last `window`
    seconds: transport latency only ever makes an input look older, so the maximum is
    the best estimate of the feed's clock. A jump larger than `jump` seconds (a new
    replay) resets it. Deadlines are absolute (instant - offset), so frames neither
    drift nor bunch up: when the service falls behind it skips to the newest due
    instant and counts the ones it missed.
    """

    def __init__(self, rate: float, window: float = 10.0, jump: float = 2.0) -> None:
        self.rate, self.window, self.jump = rate, window, jump
        self.samples: deque[tuple[float, float]] = deque()
        self.offset: float | None = None
        self.last_n: int | None = None
        self.missed = 0

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

    def next_deadline(self, wall: float) -> float | None:
        """Wall time of the next display instant, None before the first input."""
        if self.offset is None:
            return None
        n = self.last_n + 1 if self.last_n is not None else \
            math.floor((wall + self.offset) * self.rate) + 1
        return n / self.rate - self.offset

    def due(self, wall: float) -> float | None:
        """The display instant to publish at wall time `wall`, if any."""
        if self.offset is None:
            return None
        n = math.floor((wall + self.offset) * self.rate + TOL)
        if self.last_n is not None:
            if n <= self.last_n:
                return None
            self.missed += n - self.last_n - 1
        self.last_n = n
        return n / self.rate
