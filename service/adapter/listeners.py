"""Which per-target keys somebody listens to, so that the service puts only those.

Putting a message costs the worker about 4 us even when no subscriber wants it (Zenoh
routes every put), so 10,000 tracks' `display/<id>` at 30 Hz would take more than a core
whether or not anybody listens. A `Listeners` watches one per-target key space
(`<ns>/display/*` or `<ns>/tracks/*`) with the one question Zenoh answers locally, at
once and without a round trip: a publisher's matching status, whether any subscriber's
key expression intersects the publisher's. Probes are publishers never put on:

1. `<space>/**`: nobody listens to the key space: no put, no encoding (every step);
2. `<space>/~`, a key no track takes: somebody listens to every key (`display/**`,
   `display/*`): every track wanted;
3. otherwise a descent over the ids' prefixes, a probe on `<space>/<prefix>$*` each: a
   prefix no subscriber intersects rules out every id that starts with it; a matched
   one is split by the next character, down to the ids themselves (`display/x7`: the ids
   that start with x, then x7; `display/interceptor-$*`: the ids that start with i,
   ...). At most PROBES probes stay declared; an id left undecided is wanted.

The probes that ruled ids out stay declared and are looked at again every `refresh`
seconds (0: every step, as a replay must), with the second one: a newcomer among the
subscribers starts the descent afresh. So does the passing of `defaults.LISTENERS_RESET`
seconds, so that a subscriber who left stops costing puts.

The session's admin space, which lists the subscribers' key expressions, is not read:
Zenoh's admin-space handler replies while it holds its routing tables' read lock, and a
declaration arriving in between wedges the whole session for good (frames, queries and
puts stop while its liveliness token stays up; eclipse-zenoh/zenoh pull request 2619).

Declaring a publisher per track instead would cost O(declared) per declaration in
Zenoh (about 7 ms each at 10,000 declared, docs/performance.md).
"""

from __future__ import annotations

import os
import time
from bisect import bisect_left
from typing import Any

import numpy as np
import zenoh

from .. import defaults

PROBES = 64  # probes a key space keeps declared at most (each ~16 us to look at)
EVERY = "~"  # a key no track takes: a subscriber that intersects it takes every key


class Listeners:
    """The subscribers of one per-target key space `<prefix>/<id>`."""

    def __init__(self, session: zenoh.Session, prefix: str, refresh: float,
                 reset: float = defaults.LISTENERS_RESET) -> None:
        self.session, self.prefix = session, prefix.rstrip("/")
        self.refresh, self.reset = refresh, reset
        self.anyone = session.declare_publisher(f"{self.prefix}/**")
        self.every = session.declare_publisher(f"{self.prefix}/{EVERY}")
        self.none, self.everything = True, False
        self.version = 0  # changes whenever the wanted set may change
        self.looked = self.started = -np.inf  # monotonic times: probes looked at, descent
        self._forget()

    def _forget(self) -> None:
        """Start the descent afresh (undeclaring the probes that ruled ids out)."""
        for probe in getattr(self, "held", {}).values():
            probe.undeclare()
        self.held: dict[str, Any] = {}  # probe key -> publisher, matched by nobody
        self.out: tuple[str, ...] = ()  # prefixes of ids nobody wants
        self.wide: tuple[str, ...] = ()  # prefixes left undecided: their ids wanted
        self.leaves: dict[str, bool] = {}  # ids probed one by one
        self.memo: dict[str, bool] = {}
        self.mask: tuple[Any, int, np.ndarray] = (None, -1, np.zeros(0, np.intp))

    def close(self) -> None:
        self._forget()
        self.anyone.undeclare()
        self.every.undeclare()

    # ------------------------------------------------------------ state
    def look(self, now: float | None = None) -> bool:
        """Bring the subscribers up to date (cheap unless due); whether anyone listens."""
        now = time.monotonic() if now is None else now
        anyone = self.anyone.matching_status.matching
        if not anyone:
            if not self.none:
                self._start(now, none=True, everything=False)
            return False
        if self.none or now - self.looked >= self.refresh:
            self.looked = now
            everything = self.every.matching_status.matching
            newcomer = any(p.matching_status.matching for p in self.held.values())
            if self.none or everything != self.everything or newcomer or \
                    now - self.started >= self.reset:
                self._start(now, none=False, everything=everything)
        return True

    def _start(self, now: float, none: bool, everything: bool) -> None:
        self._forget()
        self.none, self.everything, self.started = none, everything, now
        self.version += 1

    # ------------------------------------------------------------ queries
    def select(self, ids: list[str]) -> np.ndarray | None:
        """Indices of the wanted ids (None: all of them), cached while the same list
        object and the same subscribers come back (a frame's ids change only when
        tracks come or go)."""
        if self.everything:
            return None
        if self.none:
            return np.zeros(0, np.intp)
        held, version, rows = self.mask
        if held is ids and version == self.version:
            return rows
        verdict = self._verdict
        unknown = [i for i in ids if verdict(i) is None]
        if unknown:
            self._descend(sorted(set(unknown)))
        rows = np.flatnonzero([verdict(i) is not False for i in ids]).astype(np.intp)
        self.mask = (ids, self.version, rows)
        return rows

    def _verdict(self, track_id: str) -> bool | None:
        """Whether `track_id` is wanted, as far as the probes so far tell (None: unknown)."""
        got = self.memo.get(track_id)
        if got is not None:
            return got
        got = self.leaves.get(track_id)
        if got is None:
            if track_id.startswith(self.out):
                got = False
            elif track_id.startswith(self.wide):
                got = True
            else:
                return None
        self.memo[track_id] = got
        return got

    # ------------------------------------------------------------ the descent
    def _descend(self, ids: list[str]) -> None:
        """Probe the prefixes of these sorted ids, the common prefix of each range of
        them first, split by the next character while matched."""
        out, wide = list(self.out), list(self.wide)
        ranges = [(0, len(ids))]
        while ranges:
            lo, hi = ranges.pop()
            if hi - lo == 1:
                self.leaves[ids[lo]] = self._probe(ids[lo]) is not False
                continue
            stem = os.path.commonprefix([ids[lo], ids[hi - 1]])  # sorted: of them all
            matched = self._probe(stem + "$*") if stem else True
            if matched is False:
                out.append(stem)
            elif matched is None:
                wide.append(stem)
            else:
                ranges.extend(split(ids, lo, hi, len(stem)))
        self.out, self.wide = tuple(out), tuple(wide)

    def _probe(self, key: str) -> bool | None:
        """Whether a subscriber intersects `<prefix>/<key>` (None: no probe left, or the
        key is not a valid key expression); a probe matched by nobody stays declared."""
        if len(self.held) >= PROBES:
            return None
        try:
            probe = self.session.declare_publisher(f"{self.prefix}/{key}")
        except zenoh.ZError:  # an id Zenoh does not take as a chunk
            return None
        if probe.matching_status.matching:
            probe.undeclare()
            return True
        self.held[key] = probe
        return False


def split(ids: list[str], lo: int, hi: int, at: int) -> list[tuple[int, int]]:
    """The ranges of sorted ids[lo:hi], which share their first `at` characters, by the
    character that follows (an id of just those characters alone, first)."""
    out = []
    while lo < hi:
        if len(ids[lo]) == at:
            end = lo + 1
        else:
            c = ids[lo][at]
            end = bisect_left(ids, ids[lo][:at] + chr(ord(c) + 1), lo, hi)
        out.append((lo, end))
        lo = end
    return out
