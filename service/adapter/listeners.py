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
3. otherwise a descent over what the ids have in common, a probe on
   `<space>/<prefix>$*<suffix>` each: a group nobody's key expression intersects rules
   out every id in it; a matched one is split by the character before its common
   suffix, then by the one after its common prefix, in turn, down to the ids themselves
   (`display/swarm-$*0`: the ids by their last character, then those ending in 0 by
   their first ...; `display/interceptor-$*`: the ids that start with i; `display/x7`:
   those that end in 7, then start with x). At most PROBES probes a descent, and as many
   declared at once; an id left undecided is wanted.

The probes that ruled ids out stay declared and are looked at again every `refresh`
seconds (0: every step, as a replay must), with the second one: a newcomer among the
subscribers starts the descent afresh (about 100 ms at 100,000 ids, 13 ms at 10,000;
an id the probes have ruled on costs a dictionary look-up). So does the passing of
`defaults.LISTENERS_RESET` seconds, so that a subscriber who left stops costing puts.

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
from typing import Any

import numpy as np
import zenoh

from .. import defaults

PROBES = 64  # probes a descent declares, and a key space keeps, at most (~0.1 ms to
# declare, ~16 us to look at)
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
        self.out: list[tuple[str, str]] = []  # (prefix, suffix) of ids nobody wants
        self.wide: list[tuple[str, str]] = []  # left undecided: their ids wanted
        self.memo: dict[str, bool] = {}  # each id's verdict
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
        got = list(map(self.memo.get, ids))
        if None in got:  # ids the probes have not met
            unknown = [i for i, g in zip(ids, got, strict=True) if g is None]
            unknown = [i for i in unknown if self._verdict(i) is None]
            if unknown:
                self._descend(list(dict.fromkeys(unknown)), by_suffix=True)
            got = list(map(self.memo.get, ids))
        rows = np.flatnonzero(np.array(got, dtype=bool))
        self.mask = (ids, self.version, rows)
        return rows

    def _verdict(self, track_id: str) -> bool | None:
        """Whether `track_id` is wanted, as far as the probes so far tell (None: unknown)."""
        got = self.memo.get(track_id)
        if got is None:  # an id the probes have not met: maybe among those they ruled on
            if any(within(track_id, p, s) for p, s in self.out):
                got = False
            elif any(within(track_id, p, s) for p, s in self.wide):
                got = True
            else:
                return None
            self.memo[track_id] = got
        return got

    # ------------------------------------------------------------ the descent
    def _descend(self, ids: list[str], by_suffix: bool) -> None:
        """Probe what these ids have in common, `<prefix>$*<suffix>`; matched, split them
        by the character that follows the prefix or precedes the suffix, in turn."""
        memo, budget = self.memo, PROBES
        groups = [(ids, by_suffix)]
        while groups:
            ids, by_suffix = groups.pop()
            if budget <= 0 or len(self.held) >= PROBES:  # no probe left: wanted
                memo.update(dict.fromkeys(ids, True))
                continue
            budget -= 1
            if len(ids) == 1:
                memo[ids[0]] = self._probe(ids[0]) is not False
                continue
            p, s = common(ids)
            matched = self._probe(f"{p}$*{s}" if p or s else "*")
            if matched is None:
                self.wide.append((p, s))
            elif not matched:
                self.out.append((p, s))
            else:
                parts = split(ids, p, s, by_suffix)
                if len(parts) == 1:  # nothing parts them on this side
                    parts, by_suffix = split(ids, p, s, not by_suffix), not by_suffix
                groups.extend((g, not by_suffix) for g in parts)
                continue
            memo.update(dict.fromkeys(ids, bool(matched is None)))

    def _probe(self, key: str) -> bool | None:
        """Whether a subscriber intersects `<prefix>/<key>` (None: no probe left, or the
        key is not a valid key expression); a probe matched by nobody stays declared."""
        if key in self.held:
            return False
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


def within(track_id: str, prefix: str, suffix: str) -> bool:
    """Whether `track_id` is one of `<prefix>$*<suffix>`."""
    return (len(track_id) >= len(prefix) + len(suffix) and track_id.startswith(prefix)
            and track_id.endswith(suffix))


def common(ids: list[str]) -> tuple[str, str]:
    """The longest prefix and then the longest suffix all these ids share, not
    overlapping in the shortest."""
    p = os.path.commonprefix([min(ids), max(ids)])
    s = os.path.commonprefix([i[::-1] for i in ids])[::-1]
    room = min(map(len, ids)) - len(p)
    return p, s[len(s) - room:] if len(s) > room else s


def split(ids: list[str], p: str, s: str, by_suffix: bool) -> list[list[str]]:
    """These ids, which all are `<p>$*<s>`, by the character after `p` (or before `s`);
    an id of just `p` and `s` alone."""
    groups: dict[str, list[str]] = {}
    at = len(p)
    for i in ids:
        if len(i) == at + len(s):
            key = "\0" + i
        else:
            key = i[-len(s) - 1] if by_suffix else i[at]
        groups.setdefault(key, []).append(i)
    return list(groups.values())
