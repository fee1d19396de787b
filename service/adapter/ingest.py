"""The first stage: Zenoh's channels and callbacks to typed inputs, in the order they came.

Measurements (`meas/`, `scan/`, `plots/`) wait in Zenoh's own FIFO channels (Zenoh's
receive thread never needs the GIL for them, so a busy worker cannot throttle the link);
the worker takes them in batches (`Ingest.next_batch`), straight into its step when
nothing else waits. Clock messages and queries come by callback on Zenoh's receive
thread into the inbox, behind the measurements received before them (moved there first,
under the ingest lock). Each input becomes one of the values below; nothing is decoded
here but the time a merge of several channels orders by (`decode` reads the payloads).
"""

from __future__ import annotations

import heapq
import math
import queue
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from ..wire import Keys, stamp_ns, unpack

MAX_BATCH = 1024  # inputs per worker step: bounds how long a due frame waits
CHANNEL = 1 << 13  # measurements Zenoh holds for the worker before it pushes back (bounds memory)
TRANSIT = 0.1  # s a publication stamp may precede the sample's arrival (`arrival`)


@dataclass(slots=True)
class Single:
    """A single labelled measurement, `<ns>/meas/<sensor>/<target>`, received at `wall`."""

    key: str
    payload: bytes
    wall: float


@dataclass(slots=True)
class Scan:
    """A batched labelled scan, `<ns>/scan/<sensor>` (rows as columns)."""

    key: str
    payload: bytes
    wall: float


@dataclass(slots=True)
class Plots:
    """An unlabelled scan, `<ns>/plots/<sensor>`."""

    key: str
    payload: bytes
    wall: float


@dataclass(slots=True)
class ClockMessage:
    """`<ns>/clock`: the feed's simulation time (nothing older will come)."""

    key: str
    payload: bytes
    wall: float


@dataclass(slots=True)
class Query:
    """A query on `tracks/**`, `status`, `frame` or `display/**` (`what`)."""

    what: str
    query: Any  # zenoh.Query

    @property
    def key(self) -> str:
        return str(getattr(self.query, "key_expr", ""))


@dataclass(slots=True)
class Wake:
    """Nothing: wakes the worker (to stop)."""

    key = ""


Input = Single | Scan | Plots | ClockMessage | Query | Wake
Measurement = Single | Scan | Plots


def arrival(sample: zenoh.Sample, since: float, now: float) -> float:
    """When `sample` reached this session, or was published (Unix s): its Zenoh timestamp
    (stamped by a publisher with timestamping on, a router on the way, or this session on
    arrival), kept within [since - TRANSIT, now]: its channel was found empty at `since`
    and it was taken at `now`, and a publication stamp may precede its arrival by the
    transit (a stamp outside is another clock's error, bounded so); `now` without one."""
    ns = stamp_ns(sample)
    return now if ns is None else min(max(ns / 1e9, since - TRANSIT), now)


def meas_time(item: Measurement) -> float:
    """A measurement's t for ordering (-inf when unreadable: rejected first)."""
    try:
        t = unpack(item.payload).get("t")
        if isinstance(t, bytes) and len(t) >= 8:  # a batched scan's times: its first
            t = struct.unpack_from("<d", t)[0]
        return float(t) if isinstance(t, int | float) and not isinstance(t, bool) else -math.inf
    except (ValueError, AttributeError):
        return -math.inf


class Ingest:
    """The service's subscriptions and queryables, and the worker's next batch of inputs."""

    def __init__(self, session: zenoh.Session, keys: Keys, meas_keys: list[str] | None,
                 plot_keys: list[str] | None, scan_keys: list[str] | None) -> None:
        self.inbox: queue.SimpleQueue[Input] = queue.SimpleQueue()
        self.lock = threading.Lock()  # held while measurements move into the inbox
        put = self.inbox.put

        def direct(fn: Callable[[Any], None]) -> zenoh.handlers.Callback:
            # run on Zenoh's receive thread: inputs keep their order across keys (an
            # indirect callback has a thread per subscriber, so a clock message could
            # overtake the measurements sent before it)
            return zenoh.handlers.Callback(fn, indirect=False)

        def control(item: Input) -> None:
            # a clock message or query: the measurements received before it go first (the
            # lock held until it is in the inbox: see `next_batch`)
            with self.lock:
                self._move(None)
                put(item)

        def clock(s: zenoh.Sample) -> None:
            control(ClockMessage(str(s.key_expr), s.payload.to_bytes(), time.time()))

        def query(what: str) -> zenoh.handlers.Callback:
            return direct(lambda q: control(Query(what, q)))

        fifo = zenoh.handlers.FifoChannel
        self.channels: list[tuple[type[Measurement], Any]] = [
            *((Single, session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (meas_keys or [keys.space("meas")])),
            *((Plots, session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (plot_keys or [keys.plots("*")])),
            *((Scan, session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (scan_keys or [keys.scan("*")]))]
        self.empty_at = [-math.inf] * len(self.channels)  # when each was last found empty
        self.subs = [
            *(sub for _, sub in self.channels),
            session.declare_subscriber(keys.clock, direct(clock)),
            session.declare_queryable(keys.space("tracks"), query("tracks")),
            session.declare_queryable(keys.status, query("status")),
            # late joiners: the latest instant published, at once (docs/operations.md)
            session.declare_queryable(keys.frame, query("frame")),
            session.declare_queryable(keys.space("display"), query("display")),
        ]

    def wake(self) -> None:
        self.inbox.put(Wake())

    def idle(self) -> bool:
        """Whether nothing waits in the inbox."""
        return self.inbox.empty()

    def waiting(self) -> int:
        return self.inbox.qsize()

    def next_batch(self, timeout: float) -> list[Input]:
        """The worker's next inputs in order, at most MAX_BATCH (waiting up to `timeout`
        s for one). When the inbox is empty the measurements go from Zenoh's channels
        straight into the batch (no round trip through the inbox): a clock message or
        query puts the measurements received before it, then itself, into the inbox under
        the lock, so with the inbox empty under that lock nothing waiting is older than
        what the channels hold."""
        inbox = self.inbox
        with self.lock:
            if inbox.empty():
                got = self._measurements(MAX_BATCH)
                if len(got) <= MAX_BATCH:
                    if got:
                        return got  # type: ignore[return-value]
                else:  # several channels: the rest waits in the inbox, in order
                    for item in got[MAX_BATCH:]:
                        inbox.put(item)
                    return got[:MAX_BATCH]  # type: ignore[return-value]
            else:
                self._move(MAX_BATCH)  # behind the inputs waiting
        batch: list[Input] = []
        try:
            batch.append(inbox.get(timeout=timeout))
            while len(batch) < MAX_BATCH:
                batch.append(inbox.get_nowait())
        except queue.Empty:
            pass
        return batch

    def _move(self, limit: int | None) -> None:
        """`_measurements` into the inbox (the caller holds the lock)."""
        put = self.inbox.put
        for item in self._measurements(limit):
            put(item)

    def _measurements(self, limit: int | None) -> list[Measurement]:
        """What waits in Zenoh's channels, in arrival order (the caller holds the lock).

        With several channels (measurements and scans; a shard's several key expressions)
        the order between them is lost: everything waiting is taken and, when more than one
        channel had something, merged by measurement time (feeds send in time order), so a
        lockstep frame is not released by one channel's later input while another's
        earlier ones still wait. One busy channel is taken as it is (no decoding)."""
        channels = self.channels
        if len(channels) > 1:
            limit = None
        lists = [got for i, (kind, sub) in enumerate(channels)
                 if (got := self._drain(i, kind, sub, limit))]
        if len(lists) <= 1:
            return lists[0] if lists else []
        return list(heapq.merge(*lists, key=meas_time))

    def _drain(self, i: int, kind: type[Measurement], sub: Any, limit: int | None
               ) -> list[Measurement]:
        """Up to `limit` inputs of channel i, each given the time of the last (`arrival`: no
        earlier input arrived later), so a worker busy while they wait does not make them
        look late to the realtime clock."""
        got: list[Any] = []
        while limit is None or len(got) < limit:
            s = sub.try_recv()
            if s is None:
                break
            got.append(s)
        now = time.time()
        since = self.empty_at[i]
        if limit is None or len(got) < limit:
            self.empty_at[i] = now  # nothing older than `now` waits in it
        if not got:
            return []
        wall = arrival(got[-1], since, now)
        return [kind(str(s.key_expr), s.payload.to_bytes(), wall) for s in got]
