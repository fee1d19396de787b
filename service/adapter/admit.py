"""The second stage: which inputs the picture takes, and when (docs/protocol.md §6).

The time policy (`timeline.Timeline`: an input far from the picture's time, the clock's
`picture`, is refused unless a new timeline is confirmed), unlabelled scans held back
until the other sensors' older ones came (`reorder.ReorderBuffer`), and the gaps in
each sensor's `seq` (measurements lost on the way). It decides; the worker acts on the
decisions (reports a refusal, starts the new timeline, applies what is released).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .reorder import ReorderBuffer
from .schedule import Clock
from .timeline import Timeline


class Admit:
    """The picture's admission state: the timeline, the reorder buffer of unlabelled
    scans (items (key, wire.PlotScan)), each sensor's highest `seq`."""

    def __init__(self, clock: Clock, max_jump: float, reorder: float) -> None:
        self.clock = clock
        self.timeline = Timeline(max_jump)
        self.reorder: ReorderBuffer[tuple[str, Any]] = ReorderBuffer(reorder)
        self.last_seq: dict[str, int] = {}
        self.newest: float | None = None  # the newest input time taken

    # ------------------------------------------------------------ the time policy
    def time(self, t: float, wall: float, tracks: int) -> tuple[str | None, bool, float | None]:
        """(reason, jump, now) for an input of time t received at `wall`, `tracks` being
        held: why it is refused (None: taken), whether it starts a new timeline, and the
        picture's time it was judged against. Taken, call `taken(t)` (after the new
        timeline, if any, has started)."""
        now = self.picture(wall)
        reason, jump = self.timeline.admit(t, now, tracks)
        return reason, jump, now

    def picture(self, wall: float) -> float | None:
        """The picture's time for an input arriving at `wall` (the clock's)."""
        return self.clock.picture(wall, self.newest)

    def taken(self, t: float) -> None:
        """An input of time t was admitted."""
        if self.newest is None or t > self.newest:
            self.newest = t

    def restart(self, t: float) -> None:
        """A new timeline at time t: the picture there, the clock started afresh."""
        self.newest = t
        self.clock.restart(t)

    def near(self, t: np.ndarray, walls: list[float]) -> bool:
        """Whether inputs of times t received at `walls` are all within --max-jump of the
        picture's time and of each other (then the time policy takes each of them)."""
        lo, hi = float(t.min()), float(t.max())
        first = self.picture(min(walls))
        if first is not None:
            lo, hi = min(lo, first), max(hi, self.picture(max(walls)))  # type: ignore[arg-type]
        return hi - lo <= self.timeline.max_jump

    def all_near(self, t: np.ndarray, wall: float) -> bool:
        """Whether the rows of times t of one input received at `wall` are all within
        --max-jump of the picture's time (then one admission, at the newest, takes all)."""
        now = self.picture(wall)
        lo, hi = float(t.min()), float(t.max())
        return now is not None and max(abs(lo - now), abs(hi - now)) <= self.timeline.max_jump

    # ------------------------------------------------------------ seq
    def lost(self, sensors: list[str], seqs: list[int | None]) -> int:
        """The measurements lost before these (gaps in each sensor's `seq`, in message
        order); each sensor's highest seq kept."""
        last_seq = self.last_seq
        lost = 0
        if len(seqs) >= 16 and None not in seqs and sensors.count(sensors[0]) == len(seqs):
            # one sensor, every message numbered (a feed's burst): as columns
            s = np.array(seqs, dtype=np.int64)
            run = np.maximum.accumulate(s)
            last = last_seq.get(sensors[0])
            before = np.empty_like(s)  # the highest seq before each message
            before[1:] = run[:-1]
            before[0] = s[0] - 1 if last is None else last
            if last is not None:
                np.maximum(before, last, out=before)
            gaps = s - before - 1
            top = int(run[-1])
            last_seq[sensors[0]] = top if last is None else max(last, top)
            return int(gaps[gaps > 0].sum())
        for sensor, seq in zip(sensors, seqs, strict=True):
            if seq is not None:
                last = last_seq.get(sensor)
                if last is not None and seq > last + 1:
                    lost += seq - last - 1
                last_seq[sensor] = seq if last is None else max(last, seq)
        return lost

    # ------------------------------------------------------------ unlabelled scans
    def late(self, t: float, sensor: str) -> str | None:
        """Why an unlabelled scan of time t is too late for the picture (None: it is not)."""
        return self.reorder.late(t, sensor)

    def hold(self, sensor: str, t: float, item: tuple[str, Any]) -> list[tuple[str, Any]]:
        """Hold a scan; the scans it releases, in time order."""
        return [it for _, it in self.reorder.push(sensor, t, item)]

    def release(self, t: float, flush: bool = False) -> list[tuple[str, Any]]:
        """The scans input time t releases (`flush`: every one older than t)."""
        return [it for _, it in self.reorder.advance(t, flush)]

    def release_all(self) -> list[tuple[str, Any]]:
        """Every scan held, the buffer then emptied of its times (a new timeline)."""
        out = self.release(math.inf, flush=True)
        self.reorder.reset()
        return out

    def held(self) -> float | None:
        """Time of the oldest scan held back (the frames wait for it)."""
        return self.reorder.oldest()

    def __len__(self) -> int:
        return len(self.reorder)
