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
3. otherwise a descent over groups of ids, a probe on `<space>/<prefix>$*<suffix>` each,
   the keys growing a character at a time: a group nobody's key expression intersects
   rules out every id in it (and every id to come that shares its key); a matched one
   is split by the character before its suffix (or after its prefix), on the same side
   while a split there rules ids out, else on the other, down to the ids themselves
   (`display/swarm-$*0`: the ids by their last character, ten probes;
   `display/interceptor-$*`: by their last, then their first; `display/x7`: those that
   end in 7, then x7). At most PROBES probes a descent, and as many held; an id left
   undecided is wanted.

The probes that ruled ids out stay declared and are looked at again every `refresh`
seconds (0: every step, as a replay must), with the second one: a newcomer among the
subscribers starts the descent afresh (about 0.1 s at 100,000 ids, 9 ms at 10,000; an
id the probes have ruled on costs a dictionary look-up). Every `defaults.LISTENERS_RESET`
seconds the ids wanted are probed again, and only they, so that a subscriber who left
stops costing puts without the whole descent's cost.

The session's admin space, which lists the subscribers' key expressions, is not read:
Zenoh's admin-space handler replies while it holds its routing tables' read lock, and a
declaration arriving in between wedges the whole session for good (frames, queries and
puts stop while its liveliness token stays up; eclipse-zenoh/zenoh pull request 2619).

Declaring a publisher per track instead would cost O(declared) per declaration in
Zenoh (about 7 ms each at 10,000 declared, docs/performance.md).
"""

from __future__ import annotations

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
        self.held: dict[str, Any] = {}  # probe key -> publisher, matched by nobody
        self._forget()

    def _forget(self) -> None:
        """Start the descent afresh (undeclaring the probes that ruled ids out)."""
        for probe in self.held.values():
            probe.undeclare()
        self.held = {}
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
            if self.none or everything != self.everything or newcomer:
                self._start(now, none=False, everything=everything)
            elif now - self.started >= self.reset:
                self._recheck(now)
        return True

    def _recheck(self, now: float) -> None:
        """The ids wanted probed again, so that a subscriber who left stops costing puts:
        only those, since an id ruled out stays so until a held probe sees a newcomer
        (a few milliseconds for the 1,000 wanted of 100,000 ids, where starting afresh
        takes a tenth of a second)."""
        self.started = now
        memo = self.memo
        wanted = [track_id for track_id, got in memo.items() if got]
        for track_id in wanted:
            del memo[track_id]
        self.wide = []
        if wanted:
            self._descend(wanted)
        self.version += 1

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
            unknown = [i for i in unknown if self._ruled(i) is None]
            if unknown:
                self._descend(list(dict.fromkeys(unknown)))
            got = list(map(self.memo.get, ids))
        rows = np.flatnonzero(np.array(got, dtype=bool))
        self.mask = (ids, self.version, rows)
        return rows

    def _ruled(self, track_id: str) -> bool | None:
        """Whether an id the probes have not met is among those they ruled on, wanted or
        not (None: neither)."""
        if any(within(track_id, p, s) for p, s in self.out):
            got = False
        elif any(within(track_id, p, s) for p, s in self.wide):
            got = True
        else:
            return None
        self.memo[track_id] = got
        return got

    # ------------------------------------------------------------ the descent
    def _descend(self, ids: list[str]) -> None:
        """Probe `*`, then split the ids matched by the character that precedes what
        they were matched for at the end (or follows it at the start) and probe each part,
        `<prefix>$*<suffix>`: on the same side while a split there rules some out, else
        on the other. The keys grow a character at a time, so that a key ruled out rules
        out the ids to come that share it too."""
        self.budget = PROBES
        groups = [(ids, "", "", True)] if self._rule(ids, "", "") else []
        while groups:
            ids, p, s, by_suffix = groups.pop()
            parts = split(ids, p, s, by_suffix) if len(ids) > 1 else [(ids, ids[0], "")]
            ruled = [self._rule(g, gp, gs) for g, gp, gs in parts]
            side = by_suffix if False in ruled else not by_suffix
            groups.extend((g, gp, gs, side) for (g, gp, gs), r in zip(parts, ruled,
                                                                     strict=True) if r)

    def _rule(self, ids: list[str], p: str, s: str) -> bool | None:
        """Probe a group of ids, all `<p>$*<s>`: False, nobody wants them; True, matched,
        to be split; None, wanted (an id matched, or no probe left)."""
        memo = self.memo
        if self.budget <= 0 or len(self.held) >= PROBES:  # no probe left: wanted
            memo.update(dict.fromkeys(ids, True))
            return None
        self.budget -= 1
        if len(ids) == 1 and len(ids[0]) == len(p) + len(s):  # the id itself
            matched = self._probe(ids[0])
            memo[ids[0]] = matched is not False
            return None if matched is not False else False
        matched = self._probe(f"{p}$*{s}" if p or s else "*")
        if matched:
            return True
        (self.wide if matched is None else self.out).append((p, s))
        memo.update(dict.fromkeys(ids, matched is None))
        return matched

    def _probe(self, key: str) -> bool | None:
        """Whether a subscriber intersects `<prefix>/<key>` (None: the key is not a valid
        key expression); a probe matched by nobody stays declared."""
        if key in self.held:
            return False
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


def split(ids: list[str], p: str, s: str, by_suffix: bool
          ) -> list[tuple[list[str], str, str]]:
    """These ids, all `<p>$*<s>`, by the character before `s` (or after `p`), each
    part with its grown suffix (or prefix); an id of just `p` and `s`, alone."""
    groups: dict[str, list[str]] = {}
    at, end = len(p), len(s)
    for i in ids:
        if len(i) == at + end:
            key = "\0" + i
        else:
            key = i[-end - 1] if by_suffix else i[at]
        groups.setdefault(key, []).append(i)
    return [(g, p, s) if k[0] == "\0" else (g, p, k + s) if by_suffix else (g, p + k, s)
            for k, g in groups.items()]
