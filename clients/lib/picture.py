"""The service's picture as NumPy columns: every `frame` decoded once (`Frame`), the
latest kept, and a bounded queue that drops the oldest frame for a slow reader."""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from types import TracebackType
from typing import TYPE_CHECKING, Any

from zenoh_track.clients.lib.frames import Frame

if TYPE_CHECKING:
    from zenoh_track.clients.lib.session import Client


class Picture:
    """Subscribes `<ns>/frame` (and asks the service for its latest frame at once).

    `latest()`: the newest frame; `next(timeout)` and iteration: the queued frames in
    order, at most `maxlen` of them (the oldest dropped and counted in `dropped`);
    `wait_for(condition)`: the first frame for which `condition(frame)` holds."""

    def __init__(self, client: Client, maxlen: int = 64) -> None:
        self.keys = client.keys
        self.queue: deque[Frame] = deque(maxlen=maxlen)
        self.dropped = 0  # frames dropped from the queue for a slow reader
        self.bad = 0  # payloads on `frame` that were not frames
        self.received = 0
        self._latest: Frame | None = None
        self._closed = False
        self._cond = threading.Condition()
        # a late joiner's picture: the latest frame at once (before the subscription, so
        # that every frame that follows is newer)
        for reply in client.session.get(self.keys.frame, timeout=2.0):
            if reply.ok is not None:
                self._on_frame(reply.ok)
        self._sub = client.session.declare_subscriber(self.keys.frame, self._on_frame)

    def _on_frame(self, sample: Any) -> None:
        try:
            frame = Frame.from_payload(sample.payload.to_bytes())
        except ValueError:
            with self._cond:
                self.bad += 1
            return
        with self._cond:
            self.received += 1
            if len(self.queue) == self.queue.maxlen:
                self.dropped += 1
            self.queue.append(frame)
            self._latest = frame
            self._cond.notify_all()

    def latest(self) -> Frame | None:
        """The newest frame received, None before the first."""
        with self._cond:
            return self._latest

    def next(self, timeout: float | None = None) -> Frame:
        """The oldest queued frame, waiting up to `timeout` s (None: for ever) for one;
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
        """The latest frame once `condition(frame)` is true of it, waiting for new frames
        (never polling on a timer); TimeoutError with the last frame's time after
        `timeout` s."""
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
            self._sub.undeclare()
            with self._cond:
                self._closed = True
                self._cond.notify_all()

    def __enter__(self) -> Picture:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
