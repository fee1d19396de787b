"""One picture from the frames of several track-service instances (a sharded deployment:
each instance publishes on `<ns>/frame` the tracks it holds, its name in `instance`).

The rule, for every client (docs/protocol.md §12; docs/howto-shard.md):

- Each instance's frames are held apart. Display instant t is drawn once every
  instance taking part holds a frame at t or later (an instance that skipped t, having
  been late, does not hold the picture up), or `hold` seconds after t's first frame came
  (an instance that is slow or paused does not stop the picture either).
- The picture at t is the union of one frame per instance: its frame at t, else its
  newest before t, its positions moved on to t by its velocities (`pos + vel (t - t_i)`,
  the prediction a frame period needs). Every instance's tracks are in every picture,
  so the count of tracks never flickers between instances' counts.
- Taking part: an instance whose frames have come, whose liveliness token has not gone,
  and which has not fallen behind the others for more than `stale` seconds. An instance
  whose token goes leaves at once: the picture of the latest instant is drawn again
  without it. Its frames still on their way are ignored until its token comes back.
- An instance's first frame of the instant last drawn draws it again with its tracks
  (a client that starts while the instances' first frames come in).
- One instance: each frame is the picture as it came, with no wait and no copy.

Times are the caller's (`wall`, seconds of any monotonic clock), so recordings are merged
on their receive times as a live client merges on its own clock.
"""

from __future__ import annotations

import math
import sys
from collections import deque

import numpy as np

from zenoh_track.clients.lib.frames import Frame

# s: how long an instant waits for a slow instance's frame. Realtime instances draw the
# same instants n / rate on clocks that agree to a few ms; 0.25 s is 7 frame periods of
# 30 Hz, past any scheduling jitter, short enough that a stalled instance's tracks keep
# moving (predicted) on screen.
HOLD = 0.25
# s: an instance behind the others this long (alive, its frames stopped: a stopped
# process, a cut link) leaves the picture until its frames come back; Zenoh removes its
# token later, at the end of the session lease (10 s by default). Longer than a busy
# machine's pauses of one realtime instance among several (2 s was seen to drop one
# for a moment on two loaded cores): a dead instance leaves by its token at once anyway.
STALE = 5.0
KEEP = 256  # frames held per instance at most (the oldest then counts as drawn)
NEW_TIMELINE = 1.0  # s: an instance's frames going back this far start a new timeline
SPARE = 4  # blocks of pictures kept for reuse (a viewer holds one or two pictures)


class Merge:
    """The frames of N instances into one `Frame` per display instant (`add`, `gone`,
    `ready`), each holding the rows of every instance taking part (`instances`)."""

    def __init__(self, hold: float | None = HOLD, stale: float | None = STALE,
                 keep: int = KEEP) -> None:
        self.hold, self.stale, self.keep = hold, stale, keep
        self.held: dict[str, deque[tuple[Frame, float]]] = {}  # (frame, arrival), by t
        self.gone_names: set[str] = set()
        self.t = -math.inf  # the latest instant drawn
        self.last: Frame | None = None  # the latest picture drawn
        self.spare: list[np.ndarray] = []  # the blocks of the latest pictures (`union`)

    def add(self, frame: Frame, wall: float, draw: bool = True) -> list[Frame]:
        """Hold a frame that came at `wall`; the pictures it completes, in order
        (`draw` False: none yet; a late joiner adds every instance's reply and frames,
        then calls `join` once, so that its first picture holds them all)."""
        name = frame.instance
        if name in self.gone_names:
            return []
        q = self.held.setdefault(name, deque())
        if q and frame.t <= q[-1][0].t:
            if frame.t < q[-1][0].t - NEW_TIMELINE:  # a replay again, a new timeline
                self.held = {name: q}
                q.clear()
                self.t = -math.inf
            elif frame.t == q[-1][0].t:
                q[-1] = (frame, wall)  # the same instant again (a query's reply)
                return self.ready(wall) if draw else []
            else:
                return self.ready(wall) if draw else []  # older than what is held
        q.append((frame, wall))
        if len(q) > self.keep:
            q.popleft()
        if not draw:
            return []
        if frame.t == self.t and self.last is not None and name not in self.last.instances:
            # an instance's first frame of the instant just drawn: drawn again with it
            return [self._draw(self.t, self._taking_part(wall)), *self.ready(wall)]
        return self.ready(wall)

    def alive(self, name: str) -> None:
        """An instance's liveliness token came (again): its frames are taken."""
        self.gone_names.discard(name)

    def gone(self, name: str, wall: float, draw: bool = True) -> list[Frame]:
        """An instance's token went: the latest instant drawn again without it (when it
        was in it), then what else is now complete (`draw` False: its frames dropped,
        nothing drawn)."""
        self.gone_names.add(name)
        self.held.pop(name, None)
        if not draw:
            return []
        out = []
        if self.last is not None and name in self.last.instances:
            out.append(self._draw(self.t, self._taking_part(wall)))
        return out + self.ready(wall)

    def join(self, wall: float) -> list[Frame]:
        """A late joiner's first pictures, from what it holds (each instance's reply to
        its query and the frames that came meanwhile, added with `draw` False): each
        instance's newest frame kept, the pictures from them drawn."""
        for q in self.held.values():
            while len(q) > 1:
                q.popleft()
        return self.ready(wall)

    @property
    def instances(self) -> tuple[str, ...]:
        """The instances whose frames are held (the names in the frames)."""
        return tuple(sorted(n for n, q in self.held.items() if q))

    def deadline(self, wall: float) -> float | None:
        """When the next instant's hold ends (the caller's clock), None when nothing
        waits for it; call `ready` then."""
        part = self._taking_part(wall)
        t = self._next(part)
        if self.hold is None or t is None:
            return None
        return min(w for q in part.values() for f, w in q if f.t == t) + self.hold

    def ready(self, wall: float) -> list[Frame]:
        """The pictures complete at `wall` (or held past `hold`), in order."""
        out: list[Frame] = []
        while True:
            part = self._taking_part(wall)
            t = self._next(part)
            if t is None:
                return out
            if any(q[-1][0].t < t for q in part.values()):  # someone has yet to draw t
                first = min(w for q in part.values() for f, w in q if f.t == t)
                if self.hold is None or wall - first < self.hold:
                    return out
            out.append(self._draw(t, part))
            for q in self.held.values():  # keep the newest frame at or before t
                while len(q) > 1 and q[1][0].t <= t:
                    q.popleft()

    def _next(self, part: dict[str, deque[tuple[Frame, float]]]) -> float | None:
        """The first instant after the latest drawn that some instance holds."""
        return min((f.t for q in part.values() for f, _ in q if f.t > self.t), default=None)

    def _taking_part(self, wall: float) -> dict[str, deque[tuple[Frame, float]]]:
        part = {n: q for n, q in self.held.items() if q}
        if self.stale is None or len(part) < 2:
            return part
        ahead = max(q[-1][0].t for q in part.values())
        return {n: q for n, q in part.items()
                if q[-1][0].t >= ahead or wall - q[-1][1] <= self.stale}

    def _draw(self, t: float, part: dict[str, deque[tuple[Frame, float]]]) -> Frame:
        """The picture at t: one frame per instance, moved on to t."""
        self.t = t
        picks = []
        for name in sorted(part):
            q = part[name]
            pick = q[0][0]
            for f, _ in q:
                if f.t > t:
                    break
                pick = f
            picks.append(pick)
        if len(picks) == 1 and picks[0].t == t:
            self.last = picks[0]
            return picks[0]
        self.last = union(t, picks, self.spare)
        return self.last


def _refs(blocks: list[np.ndarray], i: int) -> int:
    """The references to blocks[i] (every array viewing it holds one)."""
    return sys.getrefcount(blocks[i])


_UNSHARED = _refs([np.empty(1)], 0)  # a block that only its list holds, counted the same way


def union(t: float, frames: list[Frame], spare: list[np.ndarray] | None = None) -> Frame:
    """The rows of `frames` (of distinct instances) as one frame at t: each frame's
    positions moved on to t by its velocities (not beyond NEW_TIMELINE: instances that far
    apart are not on one timeline, and their rows are taken as drawn); sigma and status
    as drawn.

    The columns share one block (7 float64 and one status byte a row: 640 kB at 10,000
    tracks), taken from `spare` when one there of the right size is referenced by
    nothing else (CPython's reference count: the pictures that used it are gone), and
    added to it otherwise. A new block of that size every picture made glibc give the
    memory back and fault it in again: a third of the merge's cost."""
    n = sum(len(f) for f in frames)
    blocks = [] if spare is None else spare
    block = None
    for i in range(len(blocks)):
        if blocks[i].size == 57 * n and _refs(blocks, i) == _UNSHARED:
            block = blocks.pop(i)
            break
    if block is None:
        block = np.empty(57 * n, np.uint8)
    blocks.append(block)
    del blocks[:-SPARE]
    floats = block[:56 * n].view(np.float64)
    pos, vel = floats[:3 * n].reshape(n, 3), floats[3 * n:6 * n].reshape(n, 3)
    sigma, codes = floats[6 * n:], block[56 * n:]
    ids: list[str] = []
    start = 0
    for f in frames:
        end = start + len(f)
        if f.t != t and end > start and abs(t - f.t) <= NEW_TIMELINE:
            np.multiply(f.vel, t - f.t, out=pos[start:end])
            pos[start:end] += f.pos
        else:
            pos[start:end] = f.pos
        vel[start:end], sigma[start:end], codes[start:end] = f.vel, f.sigma, f.codes
        ids += f.id_list  # one C-level extend per instance
        start = end
    return Frame(t, ids, pos, vel, sigma, codes, "", tuple(f.instance for f in frames))
