"""Which per-target keys somebody listens to, so that the service puts only those.

Putting a message costs the worker about 4 us even when no subscriber wants it (Zenoh
routes every put), so 10,000 tracks' `display/<id>` at 30 Hz would take more than a core
whether or not anybody listens. A `Listeners` watches one per-target key space
(`<ns>/display/*` or `<ns>/tracks/*`) in two steps:

1. Zenoh's matching status: a publisher declared on `<space>/**` (never put on) with a
   matching listener says, as a subscriber comes or goes, whether any subscriber
   intersects the key space at all. No subscriber: no put, no encoding.
2. When one does, which keys: the subscribers' key expressions are read from the
   session's admin space (`@/<zid>/*/subscriber/<space>/**`), at once when the matching
   status changes and then every `refresh` seconds (a subscription added while others
   already listen is seen within that period). A track is wanted when its key
   intersects one of them (`display/**` and `display/*`: every track; `display/x7`: x7
   only; `display/swarm-$*0`: the ids ending in 0). Without an admin space (a
   configuration that disables it) every track is wanted while anything matches:
   correct, only slower.

The query waits for the router's answer too (the session's own part comes at once):
0.6 ms on a quiet machine, 0.2 to 0.6 s on two loaded cores, ADMIN_TIMEOUT with the
router stopped. A realtime service (`refresh` > 0) reads by a thread of its own and
takes each answer at its next look, so the worker never waits for one: while the
first answer is on its way every track is wanted, later the last answer holds. A
lockstep service reads at every step and waits for the answer, so that nothing is
missed in a replay.

Declaring a publisher per track instead would cost O(declared) per declaration in
Zenoh (about 7 ms each at 10,000 declared, docs/performance.md).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import zenoh

ADMIN_TIMEOUT = 1.0  # s: the admin-space query normally answers in under 1 ms
UNREAD = object()  # no answer waiting to be taken


class Listeners:
    """The subscribers of one per-target key space `<prefix>/<id>`."""

    def __init__(self, session: zenoh.Session, prefix: str, refresh: float) -> None:
        self.session, self.prefix, self.refresh = session, prefix.rstrip("/"), refresh
        self.probe = session.declare_publisher(f"{self.prefix}/**")
        self.lock = threading.Lock()
        self.matching = False
        self.dirty = True  # read the subscribers' key expressions at the next look
        # indirect: called directly on Zenoh's thread, the callback would wait there for
        # the GIL while `look`, holding it, reads the matching status (a deadlock risk)
        self.listener = self.probe.declare_matching_listener(
            zenoh.handlers.Callback(self._on_matching))
        self.exprs: tuple[str, ...] | None = ()  # None: unknown (every track wanted)
        self.everything = False
        self.compiled: list[zenoh.KeyExpr] = []
        self.version = 0  # changes whenever the wanted set may change
        self.checked = -np.inf  # monotonic time of the last admin-space read
        self.memo: dict[str, bool] = {}
        self.mask: tuple[Any, int, np.ndarray] = (None, -1, np.zeros(0, bool))
        self.admin = f"@/{session.zid()}/*/subscriber/{self.prefix}/**"
        # a realtime service's reader: `changes` counts the matching status's changes,
        # each answer comes with the count it was asked at (an older one is read again)
        self.changes, self.reading, self.closed = 0, False, False
        self.asked_at = 0
        self.answer: Any = UNREAD  # (changes asked at, exprs), under the lock
        self.ask = threading.Event()
        if refresh > 0:
            threading.Thread(target=self._reader, name="listeners", daemon=True).start()

    def _on_matching(self, status: Any) -> None:
        with self.lock:
            self.matching = status.matching
            self.dirty = True

    def close(self) -> None:
        self.closed = True
        self.ask.set()
        self.listener.undeclare()
        self.probe.undeclare()

    # ------------------------------------------------------------ state
    def look(self, now: float | None = None) -> bool:
        """Bring the subscribers up to date (cheap unless due); whether anyone listens."""
        now = time.monotonic() if now is None else now
        # read synchronously too: the listener's callback may come after the samples
        # that the new subscriber's session sent right after subscribing
        matching = self.probe.matching_status.matching
        with self.lock:
            dirty = self.dirty or matching != self.matching
            self.matching, self.dirty = matching, False
            answer, self.answer = self.answer, UNREAD
        if dirty:
            self.changes += 1
        if answer is not UNREAD:
            self.reading = False
        if not matching:
            self._set(())
            return False
        if self.refresh <= 0:  # lockstep: read now, at every step
            self._set(self._subscribers())
            return True
        if answer is not UNREAD and answer[0] == self.changes:  # else asked before the
            self._set(answer[1])  # latest change, which made the next read due at once
            self.checked = now
        if dirty:
            self.checked = -np.inf
            if self.exprs == ():  # somebody listens, to keys not read yet
                self._set(None)
        if not self.reading and now - self.checked >= self.refresh:
            self.reading, self.asked_at = True, self.changes
            self.ask.set()
        return True

    def _reader(self) -> None:
        """A realtime service's reads of the admin space, one at a time, as asked."""
        while True:
            self.ask.wait()
            self.ask.clear()
            if self.closed:
                return
            asked_at = self.asked_at
            exprs = self._subscribers()
            with self.lock:
                self.answer = (asked_at, exprs)

    def _subscribers(self) -> tuple[str, ...] | None:
        """Key expressions of the subscribers of this key space (None: no admin space)."""
        exprs = set()
        try:
            for reply in self.session.get(self.admin, timeout=ADMIN_TIMEOUT):
                if reply.ok is not None:
                    exprs.add(str(reply.ok.key_expr).split("/subscriber/", 1)[1])
        except zenoh.ZError:
            return None
        return tuple(sorted(exprs)) if exprs else None

    def _set(self, exprs: tuple[str, ...] | None) -> None:
        if exprs == self.exprs:
            return
        self.exprs, self.memo = exprs, {}
        self.version += 1
        every = zenoh.KeyExpr(f"{self.prefix}/*")
        self.everything = exprs is None or any(
            zenoh.KeyExpr(e).includes(every) for e in exprs)
        self.compiled = [zenoh.KeyExpr(e) for e in exprs or ()]

    # ------------------------------------------------------------ queries
    @property
    def none(self) -> bool:
        """Nobody listens (as of the last `look`)."""
        return self.exprs == ()

    def wants(self, track_id: str) -> bool:
        """Whether someone listens to `<prefix>/<track_id>`."""
        if self.everything:
            return True
        if self.exprs == ():
            return False
        got = self.memo.get(track_id)
        if got is None:
            key = zenoh.KeyExpr(f"{self.prefix}/{track_id}")
            got = self.memo[track_id] = any(e.intersects(key) for e in self.compiled)
        return got

    def rows(self, ids: list[str]) -> np.ndarray | None:
        """Indices of the wanted ids (None: all of them), cached while the same list
        object and the same subscribers come back (a frame's ids change only when
        tracks come or go)."""
        if self.everything:
            return None
        held, version, rows = self.mask
        if held is ids and version == self.version:
            return rows
        rows = np.flatnonzero([self.wants(i) for i in ids]) if self.exprs else \
            np.zeros(0, dtype=np.intp)
        self.mask = (ids, self.version, rows)
        return rows
