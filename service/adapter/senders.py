"""The senders of the service's frames and `tracks/` states. A realtime service puts them
from threads of their own, so that the worker never waits on Zenoh: `FrameSender` (the
30 Hz `frame`) and `TrackSender` (`tracks/<id>` and the deletions of the tracks' keys);
a lockstep one puts them in line (`InlineFrameSender`, `InlineTrackSender`).

A put with congestion control BLOCK waits as long as the slowest subscriber takes to read
what is queued (a Python subscriber of `tracks/**` reads about 100,000 messages a second):
the worker encodes the bodies and hands them over in order, and the sender puts them
with the GIL released while Zenoh waits. After each step the worker waits for the sender
for up to `schedule.DRAIN` s while it keeps putting, publishing the frames that fall due
meanwhile (`TrackService._drain`, with `TrackSender.drain`): the states go out before
more input is taken, and the two threads do not pass the GIL to and fro at every put
(bench/put_gil.py). Nothing is dropped: beyond `defaults.TRACKS_QUEUE` messages waiting,
the worker waits too.
docs/performance.md gives the figures.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from typing import Any

import zenoh

from .. import defaults

log = logging.getLogger("track-service")


class FrameSender:
    """Puts realtime frames from a thread of its own, so the worker does not wait while
    Zenoh copies a large frame out (7 MB at 100,000 tracks; the put releases the GIL).
    A frame still waiting when the next one comes is replaced by it and counted in
    `replaced` (what congestion control DROP does with a stale frame)."""

    def __init__(self, pub: zenoh.Publisher) -> None:
        self.pub = pub
        self.cond = threading.Condition()
        self.pending: bytes | None = None
        self.closed = False
        self.replaced = 0
        self.thread = threading.Thread(target=self._run, name="frame-sender", daemon=True)
        self.thread.start()

    def put(self, body: bytes) -> None:
        with self.cond:
            if self.pending is not None:
                self.replaced += 1
            self.pending = body
            self.cond.notify()

    def _run(self) -> None:
        while True:
            with self.cond:
                while self.pending is None and not self.closed:
                    self.cond.wait()
                if self.pending is None:
                    return  # closed, and everything handed over put
                body, self.pending = self.pending, None
            try:
                self.pub.put(body)
            except Exception:  # a closed session: nothing more to send
                log.exception("frame put failed")

    def close(self) -> None:
        """Put the frame still waiting, then stop."""
        with self.cond:
            self.closed = True
            self.cond.notify()
        self.thread.join(timeout=5)


class TrackSender:
    """Puts `tracks/<id>` bodies and deletes tracks' keys from a thread of its own, in the
    order handed over (a deletion never overtakes a state of the same track). `limit`:
    messages waiting beyond which `put` waits for the sender (never dropped)."""

    SLICE = 256  # puts between two looks at the queue's lock (a `put` waiting for room wakes)

    def __init__(self, session: zenoh.Session, encoding: zenoh.Encoding,
                 limit: int = defaults.TRACKS_QUEUE) -> None:
        self.session, self.encoding, self.limit = session, encoding, limit
        self.cond = threading.Condition()
        self.jobs: deque[tuple[list[Any], list[bytes] | None]] = deque()
        self.waiting = 0  # messages handed over, not yet put
        self.blocked = 0  # threads waiting in `put` for room
        self.closed = False
        self.thread = threading.Thread(target=self._run, name="track-sender", daemon=True)
        self.thread.start()

    def put(self, keys: list[Any], bodies: list[bytes]) -> None:
        """Put body i on key i (in order, after everything handed over before)."""
        self._add(keys, bodies)

    def delete(self, keys: list[Any]) -> None:
        """Delete these keys (after everything handed over before)."""
        self._add(keys, None)

    def _add(self, keys: list[Any], bodies: list[bytes] | None) -> None:
        if not keys:
            return
        with self.cond:
            while self.waiting >= self.limit and not self.closed and self.thread.is_alive():
                self.blocked += 1  # the subscribers are that far behind: BLOCK here
                self.cond.wait(0.1)
                self.blocked -= 1
            self.jobs.append((keys, bodies))
            self.waiting += len(keys)
            self.cond.notify_all()

    def _run(self) -> None:
        block, enc = zenoh.CongestionControl.BLOCK, self.encoding
        put, delete = self.session.put, self.session.delete
        while True:
            with self.cond:
                while not self.jobs and not self.closed:
                    self.cond.wait()
                if not self.jobs:
                    return  # closed, and everything handed over put
                keys, bodies = self.jobs[0]
            n, done = len(keys), 0
            try:
                while done < n:
                    end = min(n, done + self.SLICE)
                    if bodies is None:
                        for k in keys[done:end]:
                            delete(k, congestion_control=block)
                    else:
                        for k, b in zip(keys[done:end], bodies[done:end], strict=True):
                            put(k, b, congestion_control=block, encoding=enc)
                    with self.cond:
                        self.waiting -= end - done
                        if self.blocked:  # room for them (a drain waits for the job)
                            self.cond.notify_all()
                    done = end
            except Exception:  # a closed session: nothing more to send
                log.exception("tracks/ put failed")
                with self.cond:
                    self.waiting -= n - done
            with self.cond:
                self.jobs.popleft()
                self.cond.notify_all()

    def idle(self) -> bool:
        """Nothing waits to be put."""
        with self.cond:
            return not self.jobs

    def drain(self, timeout: float) -> bool:
        """Wait up to `timeout` s for everything handed over to be put (True: it was). The
        worker does so after each step: its puts then hold the GIL uncontended, while
        beside a busy worker each put, which releases the GIL, takes it back only when the
        worker lets go."""
        with self.cond:
            return self.cond.wait_for(lambda: not self.jobs or self.closed
                                      or not self.thread.is_alive(), timeout)

    def close(self, timeout: float = 10.0) -> None:
        """Put what waits, then stop."""
        with self.cond:
            self.closed = True
            self.cond.notify_all()
        self.thread.join(timeout=timeout)


class InlineTrackSender:
    """`TrackSender`'s puts and deletions made at once, on the caller's thread: a lockstep
    service's outputs, in line with everything else it puts (a function of its inputs)."""

    waiting = 0  # nothing waits

    def __init__(self, session: zenoh.Session, encoding: zenoh.Encoding) -> None:
        self.session, self.encoding = session, encoding

    def put(self, keys: list[Any], bodies: list[bytes]) -> None:
        block, enc, put = zenoh.CongestionControl.BLOCK, self.encoding, self.session.put
        for k, b in zip(keys, bodies, strict=True):
            put(k, b, congestion_control=block, encoding=enc)

    def delete(self, keys: list[Any]) -> None:
        block, delete = zenoh.CongestionControl.BLOCK, self.session.delete
        for k in keys:
            delete(k, congestion_control=block)

    def idle(self) -> bool:
        return True

    def drain(self, timeout: float) -> bool:
        """Nothing waits."""
        return True

    def close(self) -> None:
        """Nothing waits."""


class InlineFrameSender:
    """`FrameSender`'s put made at once, on the caller's thread: a lockstep service's
    frames, in line with everything else it puts (none is ever replaced)."""

    replaced = 0

    def __init__(self, pub: zenoh.Publisher) -> None:
        self.pub = pub

    def put(self, body: bytes) -> None:
        self.pub.put(body)

    def close(self) -> None:
        """Nothing waits."""
