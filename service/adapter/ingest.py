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
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from ..wire import Keys, stamp_ns, unpack

MAX_BATCH = 1024  # inputs per worker step: bounds how long a due frame waits
CHANNEL = 1 << 13  # measurements Zenoh holds for the worker before it pushes back (bounds memory)
TRANSIT = 0.1  # s a publication stamp may precede the sample's arrival (`arrival`)


@dataclass(slots=True)
class Singles:
    """Single labelled measurements (`<ns>/meas/<sensor>/<target>`) in the order they came:
    each one's key, payload and arrival (`walls`, Unix s). One value per run of them (a
    channel's take, or several taken together), not one per message: a burst is
    thousands of messages."""

    keys: list[str]
    payloads: list[bytes]
    walls: list[float]

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def key(self) -> str:
        return self.keys[0]

    @staticmethod
    def one(key: str, payload: bytes, wall: float) -> Singles:
        return Singles([key], [payload], [wall])

    def each(self) -> list[Singles]:
        """One run per message."""
        return [Singles([k], [p], [w]) for k, p, w in zip(self.keys, self.payloads,
                                                          self.walls, strict=True)]

    def cut(self, n: int) -> tuple[Singles, Singles]:
        """The first n messages and the rest."""
        return (Singles(self.keys[:n], self.payloads[:n], self.walls[:n]),
                Singles(self.keys[n:], self.payloads[n:], self.walls[n:]))

    @staticmethod
    def joined(runs: list[Singles]) -> Singles:
        """Consecutive runs as one."""
        if len(runs) == 1:
            return runs[0]
        return Singles([k for r in runs for k in r.keys], [p for r in runs for p in r.payloads],
                       [w for r in runs for w in r.walls])


@dataclass(slots=True)
class Message:
    """One sample: its key, payload and arrival (`wall`, Unix s)."""

    key: str
    payload: bytes
    wall: float


class LabelledScan(Message):
    """A batched labelled scan, `<ns>/scan/<sensor>` (rows as columns)."""

    __slots__ = ()


class Plots(Message):
    """An unlabelled scan, `<ns>/plots/<sensor>`."""

    __slots__ = ()


class ClockMessage(Message):
    """`<ns>/clock`: the feed's simulation time (nothing older will come)."""

    __slots__ = ()


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


Input = Singles | LabelledScan | Plots | ClockMessage | Query | Wake
Measurement = Singles | LabelledScan | Plots


def size(item: Input) -> int:
    """How many messages an input holds."""
    return len(item) if type(item) is Singles else 1  # type: ignore[arg-type]


def cut(items: list[Input], n: int) -> tuple[list[Input], list[Input]]:
    """The first n messages of `items` and the rest (a run split where n falls)."""
    head: list[Input] = []
    for i, item in enumerate(items):
        k = size(item)
        if k > n:
            if n == 0:
                return head, items[i:]
            first, rest = item.cut(n)  # type: ignore[union-attr]
            return [*head, first], [rest, *items[i + 1:]]
        head.append(item)
        n -= k
    return head, []


def arrival(sample: zenoh.Sample, since: float, now: float) -> float:
    """When `sample` reached this session, or was published (Unix s): its Zenoh timestamp
    (stamped by a publisher with timestamping on, a router on the way, or this session on
    arrival), kept within [since - TRANSIT, now]: its channel was found empty at `since`
    and it was taken at `now`, and a publication stamp may precede its arrival by the
    transit (a stamp outside is another clock's error, bounded so); `now` without one."""
    ns = stamp_ns(sample)
    return now if ns is None else min(max(ns / 1e9, since - TRANSIT), now)


def meas_time(item: Measurement) -> float:
    """A measurement's t for ordering (-inf when unreadable: rejected first); a run of
    singles by its first."""
    try:
        t = unpack(item.payloads[0] if type(item) is Singles else item.payload).get("t")
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
        # taken from the channels or the inbox but not yet handed to the worker (older
        # than anything in the inbox; the worker's alone)
        self.carry: deque[Input] = deque()
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
            *((Singles, session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (meas_keys or [keys.space("meas")])),
            *((Plots, session.declare_subscriber(k, fifo(CHANNEL)))
              for k in (plot_keys or [keys.plots("*")])),
            *((LabelledScan, session.declare_subscriber(k, fifo(CHANNEL)))
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
        return not self.carry and self.inbox.empty()

    def waiting(self) -> int:
        return len(self.carry) + self.inbox.qsize()

    def next_batch(self, timeout: float) -> list[Input]:
        """The worker's next inputs in order, at most MAX_BATCH messages (waiting up to
        `timeout` s for one). When nothing waits in the inbox the measurements go from
        Zenoh's channels straight into the batch (no round trip through the inbox): a clock
        message or query puts the measurements received before it, then itself, into the
        inbox under the lock, so with the inbox empty under that lock nothing waiting is
        older than what the channels hold."""
        inbox, carry = self.inbox, self.carry
        with self.lock:
            if not carry and inbox.empty():
                got, rest = cut(self._measurements(MAX_BATCH), MAX_BATCH)
                carry.extend(rest)  # several channels: the rest waits, in order
                if got:
                    return got
            else:
                self._move(MAX_BATCH)  # behind the inputs waiting
        batch: list[Input] = []
        room = MAX_BATCH
        try:
            while room > 0:
                if carry:
                    item = carry.popleft()
                else:
                    item = inbox.get_nowait() if batch else inbox.get(timeout=timeout)
                k = size(item)
                if k > room:  # a run longer than the room left: the rest comes next
                    item, rest = item.cut(room)  # type: ignore[union-attr]
                    carry.appendleft(rest)
                    k = room
                batch.append(item)
                room -= k
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
        each = [[one for run in got for one in run.each()]  # type: ignore[union-attr]
                if type(got[0]) is Singles else got for got in lists]
        return list(heapq.merge(*each, key=meas_time))

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
        if kind is Singles:  # one run: a burst is thousands of messages
            return [Singles([str(s.key_expr) for s in got], [s.payload.to_bytes() for s in got],
                            [wall] * len(got))]
        return [kind(str(s.key_expr), s.payload.to_bytes(), wall) for s in got]
