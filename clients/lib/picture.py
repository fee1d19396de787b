"""The service's picture as NumPy columns: every `frame` decoded once (`Frame`), the
frames of several instances merged into one picture per display instant (`merge.Merge`),
the latest kept, and a bounded queue that drops the oldest picture for a slow reader."""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from types import TracebackType
from typing import TYPE_CHECKING, Any

import zenoh

from zenoh_track.clients.lib.frames import Frame
from zenoh_track.clients.lib.merge import HOLD, STALE, Merge

if TYPE_CHECKING:
    from zenoh_track.clients.lib.session import Client


# s: the longest a late joiner waits for every instance's latest frame. The wait ends when
# every instance has answered its query, or as soon as every instance whose token is up
# has a frame, by its reply or by its next frame on `frame` (a reply lost or late on the
# way holds nothing up while the instance's frames flow). A busy instance answers behind
# the inputs before the query, and 2 s was seen to leave one out on two loaded cores.
JOIN_WAIT = 5.0

class Picture:
    """Subscribes `<ns>/frame` and the instances' liveliness tokens, and asks every
    instance for its latest frame at once: one picture per display instant, whatever
    the number of instances (`merge.Merge`: `hold`, `stale`).

    `latest()`: the newest picture; `next(timeout)` and iteration: the pictures in
    order, at most `maxlen` of them queued (the oldest dropped and counted in
    `dropped`); `wait_for(condition)`: the first picture for which `condition(frame)`
    holds; `on_frame(frame)`, if given, is called with each picture under the Picture's
    lock (keep it short). `alive`: the instances whose tokens are up; `serving`: those
    in the latest picture."""

    def __init__(self, client: Client, maxlen: int = 64,
                 on_frame: Callable[[Frame], Any] | None = None, hold: float | None = HOLD,
                 stale: float | None = STALE) -> None:
        self.keys = client.keys
        self.queue: deque[Frame] = deque(maxlen=maxlen)
        self.dropped = 0  # pictures dropped from the queue for a slow reader
        self.bad = 0  # payloads on `frame` that were not frames
        self.received = 0  # frames received (of every instance)
        self.merge = Merge(hold, stale)
        self.alive: set[str] = set()
        self.on_frame = on_frame
        self._latest: Frame | None = None
        self._closed = False
        self._joining, self._answered = True, False  # until the first picture
        lock = threading.RLock()
        self._cond = threading.Condition(lock)  # readers wait on it for pictures
        self._wake = threading.Condition(lock)  # the hold's thread waits on it
        threading.Thread(target=self._hold, name="picture-hold", daemon=True).start()
        session = client.session
        # the tokens first (their history: the instances alive now), then a late
        # joiner's picture: every instance's latest frame, by the replies to one query
        # and by the frames that come meanwhile, held undrawn (JOIN_WAIT); the pictures
        # then start from each instance's newest
        self._subs = [session.liveliness().declare_subscriber(
            self.keys.alive("*"), self._on_token, history=True),
            session.declare_subscriber(self.keys.frame, self._on_frame)]
        session.get(self.keys.frame, zenoh.handlers.Callback(
            self._on_reply, self._on_answered, indirect=False),
            target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
            timeout=JOIN_WAIT)
        with self._cond:
            self._cond.wait_for(lambda: self._answered or (
                self.alive and self.alive <= set(self.merge.instances)), JOIN_WAIT)
            self._joining = False
            self._emit(self.merge.join(time.monotonic()))

    @property
    def serving(self) -> tuple[str, ...]:
        """The instances whose tracks the latest picture holds."""
        with self._cond:
            return () if self._latest is None else self._latest.instances

    def _on_token(self, sample: Any) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(name)
                self.merge.alive(name)
            else:
                self.alive.discard(name)
                self._emit(self.merge.gone(name, time.monotonic(), not self._joining))
            self._cond.notify_all()  # a joiner waits for the live instances' frames

    def _on_reply(self, reply: Any) -> None:
        if reply.ok is not None:
            self._on_frame(reply.ok)

    def _on_answered(self) -> None:
        with self._cond:
            self._answered = True
            self._cond.notify_all()

    def _on_frame(self, sample: Any) -> None:
        try:
            frame = Frame.from_payload(sample.payload.to_bytes())
        except ValueError:
            with self._cond:
                self.bad += 1
            return
        with self._cond:
            self.received += 1
            if self._joining:  # held for the first picture
                self.merge.add(frame, time.monotonic(), draw=False)
                self._cond.notify_all()
            else:
                self._emit(self.merge.add(frame, time.monotonic()))

    def _hold(self) -> None:
        """Draw an instant whose hold has ended while no frame came to draw it."""
        with self._cond:
            while not self._closed:
                now = time.monotonic()
                due = None if self._joining else self.merge.deadline(now)
                if due is None:
                    self._wake.wait()
                elif due > now:
                    self._wake.wait(due - now + 1e-3)
                else:
                    pictures = self.merge.ready(now)
                    self._emit(pictures)
                    if not pictures:  # nothing to draw after all: look again later
                        self._wake.wait(self.merge.hold or 0.1)

    def _emit(self, pictures: list[Frame]) -> None:
        """Queue the pictures drawn (under the lock), and wake the hold's thread."""
        for frame in pictures:
            if len(self.queue) == self.queue.maxlen:
                self.dropped += 1
            self.queue.append(frame)
            self._latest = frame
            if self.on_frame is not None:
                self.on_frame(frame)
        if pictures:
            self._cond.notify_all()
        self._wake.notify()  # an instant may wait for its hold now

    def latest(self) -> Frame | None:
        """The newest picture, None before the first."""
        with self._cond:
            return self._latest

    def next(self, timeout: float | None = None) -> Frame:
        """The oldest queued picture, waiting up to `timeout` s (None: for ever) for one;
        TimeoutError after that, StopIteration once closed."""
        with self._cond:
            if not self._cond.wait_for(lambda: self.queue or self._closed, timeout):
                raise TimeoutError(f"no frame on {self.keys.frame} within {timeout:g} s")
            if not self.queue:
                raise StopIteration
            return self.queue.popleft()

    def __iter__(self) -> Iterator[Frame]:
        while True:
            try:
                yield self.next()
            except StopIteration:
                return

    def wait_for(self, condition: Callable[[Frame], Any], timeout: float = 30.0) -> Frame:
        """The latest picture once `condition(frame)` is true of it, waiting for new
        pictures (never polling on a timer); TimeoutError with the last picture's time
        after `timeout` s."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                frame = self._latest
                if frame is not None and condition(frame):
                    return frame
                left = deadline - time.monotonic()
                if left <= 0 or self._closed:
                    last = "no frame" if frame is None else f"last frame t={frame.t:g}, " \
                        f"{len(frame)} tracks"
                    raise TimeoutError(f"condition not met within {timeout:g} s ({last})")
                def moved(seen: Frame | None = frame) -> bool:
                    return self._latest is not seen or self._closed

                self._cond.wait_for(moved, left)

    def close(self) -> None:
        if not self._closed:
            for sub in self._subs:
                sub.undeclare()
            with self._cond:
                self._closed = True
                self._cond.notify_all()
                self._wake.notify_all()

    def __enter__(self) -> Picture:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
