"""A bounded reorder buffer for unlabelled scans from several sensors.

Scans of different sensors reach the service out of time order (different scan phases,
links and processing delays), but a track can only be updated forward in time. Each
sensor's own scans arrive in order (Zenoh keeps the order of one publisher), so a scan
of time t waits here only until every other sensor heard from has sent a scan of time
t or later (the watermark), and at most until input time reaches `t + lag` (a sensor
that fell silent holds nobody back longer), or a clock message promises that everything
before it was sent. The watermark counts once input time has run `lag` past the first
scan (until then the sensors present may not all have spoken); after that, with one
sensor nothing waits, and a sensor that appears later must not be older than the
picture. Released scans come out in time
order. A scan older than one already
released is too late for the picture and is refused (`late`), with its reason; it is
never applied out of order. The lag is simulation time (`--reorder`, default
`defaults.REORDER`); it delays the tracks of unlabelled scans by at most that much, not
the display frames of a realtime service (they predict).
"""

from __future__ import annotations

import heapq
import itertools
from typing import Generic, TypeVar

T = TypeVar("T")


class ReorderBuffer(Generic[T]):
    """Holds items with a time `t` for up to `lag` seconds of input time."""

    def __init__(self, lag: float) -> None:
        self.lag = lag
        self.sensors: dict[str, float] = {}  # newest time of each sensor
        self.heap: list[tuple[float, int, T]] = []
        self.count = itertools.count()
        self.released = -float("inf")  # time of the newest item released
        self.newest = -float("inf")  # newest input time seen
        self.first: float | None = None  # time of the first item

    def __len__(self) -> int:
        return len(self.heap)

    def reset(self) -> None:
        """Forget every sensor and time (a new timeline; hold nothing when called)."""
        self.sensors.clear()
        self.released = self.newest = -float("inf")
        self.first = None

    def late(self, t: float, sensor: str | None = None) -> str | None:
        """Why an item of time t (of `sensor`) cannot be taken any more (None: it can):
        older than one already released, or not newer than the sensor's last one (a
        sensor's own scans come in order, so that is a duplicate)."""
        if t < self.released:
            return (f"late scan: t={t:.6f} is before t={self.released:.6f}, already applied "
                    f"(scans may arrive up to --reorder {self.lag:g} s out of order)")
        last = self.sensors.get(sensor) if sensor is not None else None
        if last is not None and t <= last:
            return (f"duplicate or out-of-order scan: t={t:.6f} is not after this sensor's "
                    f"last scan at t={last:.6f}")
        return None

    def push(self, sensor: str, t: float, item: T) -> list[tuple[float, T]]:
        """Take an item of `sensor` (check `late` first); returns the items now
        released."""
        self.sensors[sensor] = max(self.sensors.get(sensor, t), t)
        if self.first is None:
            self.first = t
        heapq.heappush(self.heap, (t, next(self.count), item))
        return self.advance(t)

    def advance(self, t: float, flush: bool = False) -> list[tuple[float, T]]:
        """Input time has reached t: release, in order, the items no older scan can
        precede any more (with `flush`, every item of time < t: a clock message says
        nothing older will come)."""
        self.newest = max(self.newest, t)
        warm = self.first is not None and self.newest >= self.first + self.lag
        watermark = min(self.sensors.values()) if warm and self.sensors else -float("inf")
        limit = t if flush else max(watermark, self.newest - self.lag)
        out = []
        while self.heap and (self.heap[0][0] < limit if flush else self.heap[0][0] <= limit):
            when, _, item = heapq.heappop(self.heap)
            self.released = max(self.released, when)
            out.append((when, item))
        return out

    def oldest(self) -> float | None:
        """Time of the oldest item held."""
        return self.heap[0][0] if self.heap else None
