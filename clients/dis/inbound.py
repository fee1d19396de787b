"""DIS in: Entity State PDUs received on UDP become `scan/<sensor>` messages (protocol
1.1), one per short window: positions in the deployment's ENU frame, exact unless a sigma
is configured, one row per entity (several PDUs of one entity in a window go in
successive messages, its newest PER_WINDOW at most). Everything else that arrives is
counted under a reason; nothing that arrives can stop the loop.

Each datagram is read into a slot of one preallocated buffer (the only per-PDU Python
work is `recv_into`); a window's datagrams are then checked and converted as arrays."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from zenoh_track.clients.dis import pdu, standard
from zenoh_track.clients.dis.geodesy import EnuFrame

SLOT = 1536  # bytes read per datagram: a PDU within the standard's 1400-octet MTU fits
BATCH = 4096  # datagrams at most in one window (a full buffer closes the window early)
PER_WINDOW = 4  # an entity's PDUs taken from one window (its newest)
# geocentric distances that no entity of a simulation has: inside the Earth by more than
# ~80 km (0, 0, 0 is the usual "not set") or beyond twice the geostationary radius
MIN_RADIUS, MAX_RADIUS = 6.275e6, 8.5e7
# why an input was not taken: the codes counted in `status` and reported on errors/
REASONS = {
    "truncated": "datagram shorter than its PDU",
    "version": "not DIS version 7",
    "pdu_type": "a PDU type the gateway does not take (only Entity State and Remove Entity)",
    "exercise": "another exercise id",
    "filtered": "a site:application outside --accept",
    "absurd": "position or velocity not finite or not near the Earth",
    "time": "timestamp more than --time-window from the arrival",
    "superseded": f"more than {PER_WINDOW} PDUs of the entity in one window (the newest taken)",
    "entities": "more entities than --max-entities",
}
NOT_ERRORS = ("own", "exercise", "superseded")  # counted, not reported: normal on a network


@dataclass
class InConfig:
    """What the in side takes and how (docs/gateways.md)."""

    exercise: int = standard.EXERCISE
    accept: frozenset[tuple[int, int]] | None = None  # site:application taken (None: all)
    own: tuple[int, int] = (standard.OWN_SITE, standard.OWN_APPLICATION)  # never taken
    sigma: float = 0.0  # m, per axis: 0 is exact, a simulation's own truth
    clock: str = "pdu"  # "pdu": the PDU's timestamp, "arrival": the arrival time
    time_window: float = standard.TIMESTAMP_WINDOW  # s, absolute timestamps; 0: no check
    window: float = 0.02  # s: one scan/ message per window at most
    timeout: float = standard.TIMEOUT  # s without a PDU: the entity is gone
    max_entities: int = 1_000_000


@dataclass
class InCounts:
    """What came in, by outcome (every datagram counted once)."""

    datagrams: int = 0
    accepted: int = 0  # rows sent to the service
    scans: int = 0  # scan/ messages sent
    ended: int = 0  # PDUs that end entities: Remove Entity, or the deactivated bit set
    removed: int = 0  # entities ended by a Remove Entity PDU or the deactivated bit
    timed_out: int = 0  # entities silent for --timeout
    own: int = 0  # the gateway's own PDUs, read back (loop protection)
    rejected: dict[str, int] = field(default_factory=dict)

    def add(self, reason: str, n: int) -> None:
        if n:
            if reason == "own":
                self.own += n
            else:
                self.rejected[reason] = self.rejected.get(reason, 0) + n


def open_socket(bind: str, port: int, group: str | None) -> socket.socket:
    """The UDP socket of the in side: bound to `bind`:`port` (broadcasts to that port
    reach it), joined to the multicast `group` on the interface of `bind` if given.
    OSError when the port is taken or the address is not this host's."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    if group:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((group if group else bind, port))
    if group:
        iface = socket.inet_aton(bind if bind not in ("", "0.0.0.0") else "0.0.0.0")
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                        socket.inet_aton(group) + iface)
    sock.settimeout(0.005)
    return sock


def kernel_drops(sock: socket.socket) -> int:
    """Datagrams the kernel dropped for this socket (its buffer full): the `drops`
    column of /proc/net/udp for its inode; 0 where that is not readable."""
    import os

    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        with open("/proc/net/udp") as f:
            for line in f.readlines()[1:]:
                cols = line.split()
                if len(cols) > 12 and cols[9] == inode:
                    return int(cols[12])
    except (OSError, ValueError):
        pass
    return 0


class Clocks:
    """Times of PDUs (docs/gateways.md, "Time"). Absolute timestamps: the time past the
    hour placed in the hour nearest the arrival. Relative timestamps: each sender's
    (site:application) clock kept continuous from its first PDU, placed as an absolute
    one; no window check (its clock is its own)."""

    def __init__(self) -> None:
        self.base: dict[int, float] = {}  # sender -> start of its current hour, s
        self.last: dict[int, float] = {}  # sender -> its latest time past the hour

    @staticmethod
    def nearest_hour(past: npt.NDArray[np.float64], arrival: npt.NDArray[np.float64]
                     ) -> npt.NDArray[np.float64]:
        hour = np.round((arrival - past) / 3600.0) * 3600.0
        out: npt.NDArray[np.float64] = hour + past
        return out

    def relative(self, sender: npt.NDArray[np.int64], past: npt.NDArray[np.float64],
                 arrival: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        t = np.empty_like(past)
        for s in np.unique(sender).tolist():
            rows = np.flatnonzero(sender == s)
            p = past[rows]
            if s not in self.base:
                self.base[s] = float(self.nearest_hour(p[:1], arrival[rows[:1]])[0] - p[0])
                self.last[s] = float(p[0])
            prev = np.concatenate([[self.last[s]], p[:-1]])
            hours = np.cumsum(p < prev - 1800.0)  # the sender's clock passed an hour
            t[rows] = self.base[s] + 3600.0 * hours + p
            self.base[s] += 3600.0 * float(hours[-1])
            self.last[s] = float(p[-1])
        return t


class Inbound:
    """Reads PDUs from `sock`, sends each window's entities with `send(t, ids, enu)`,
    reports each refused kind with `report(code, text, count)`."""

    def __init__(self, sock: socket.socket, frame: EnuFrame, config: InConfig,
                 send: Callable[[npt.NDArray[np.float64], list[str], npt.NDArray[np.float64]],
                                None],
                 report: Callable[[str, str, int], None]) -> None:
        self.sock, self.frame, self.config = sock, frame, config
        self.send, self.report = send, report
        self.counts = InCounts()
        self.buf = np.zeros((BATCH, SLOT), np.uint8)
        self.views = [memoryview(row) for row in self.buf]  # type: ignore[arg-type]
        self.sizes = np.zeros(BATCH, np.int64)
        self.arrivals = np.zeros(BATCH)
        self.seen: dict[int, float] = {}  # entity uid -> monotonic time of its last PDU
        self.names: dict[int, str] = {}  # entity uid -> target id
        self.clocks = Clocks()
        self.next_sweep = time.monotonic() + 1.0

    # ------------------------------------------------------------ the loop
    def run(self, stopped: Callable[[], bool]) -> None:
        """Read and send until `stopped()`; a window closes after `config.window` s or
        BATCH datagrams."""
        recv, views, sizes, arrivals = self.sock.recv_into, self.views, self.sizes, self.arrivals
        now, wall, window = time.monotonic, time.time, self.config.window
        while not stopped():
            n, deadline = 0, now() + window
            while n < BATCH:
                try:
                    sizes[n] = recv(views[n])
                    arrivals[n] = wall()
                    n += 1
                except TimeoutError:
                    pass
                if now() >= deadline:
                    break
            if n:
                self.take(n)
            if now() >= self.next_sweep:
                self.sweep(now())

    # ------------------------------------------------------------ one window
    def take(self, n: int) -> None:
        """Check, convert and send the window's n datagrams."""
        c = self.counts
        c.datagrams += n
        raw, size, arrival = self.buf[:n], self.sizes[:n], self.arrivals[:n]
        head = np.ascontiguousarray(raw[:, :pdu.HEADER_SIZE]).view(pdu.HEADER).ravel()
        short = size < pdu.HEADER_SIZE
        self._refuse("truncated", short)
        version = ~short & (head["version"] != pdu.VERSION)
        self._refuse("version", version)
        live = ~short & ~version
        other = live & (head["exercise"] != self.config.exercise)
        c.add("exercise", int(other.sum()))
        live &= ~other
        state = live & (head["pdu_type"] == pdu.ENTITY_STATE)
        remove = live & (head["pdu_type"] == pdu.REMOVE_ENTITY)
        self._refuse("pdu_type", live & ~state & ~remove)
        need = np.where(state, pdu.ENTITY_STATE_PDU.itemsize, pdu.REMOVE_ENTITY_PDU.itemsize)
        cut = (state | remove) & ((size < need) | (head["length"] > size))
        self._refuse("truncated", cut)
        if (remove & ~cut).any():
            self._removals(raw[remove & ~cut])
        rows = np.flatnonzero(state & ~cut)
        if len(rows):
            self._states(np.ascontiguousarray(raw[rows, :pdu.ENTITY_STATE_PDU.itemsize])
                         .view(pdu.ENTITY_STATE_PDU).ravel(), arrival[rows])

    def _refuse(self, reason: str, mask: npt.NDArray[np.bool_]) -> None:
        count = int(np.count_nonzero(mask))
        if count:
            self.counts.add(reason, count)
            if reason not in NOT_ERRORS:
                self.report(reason, REASONS[reason], count)

    def _removals(self, raw: npt.NDArray[np.uint8]) -> None:
        rm = np.ascontiguousarray(raw[:, :pdu.REMOVE_ENTITY_PDU.itemsize]) \
            .view(pdu.REMOVE_ENTITY_PDU).ravel()["receiving"]
        for site, app, entity in zip(rm["site"].tolist(), rm["application"].tolist(),
                                     rm["entity"].tolist(), strict=True):
            if (site, app) == self.config.own:
                self.counts.add("own", 1)
                continue
            self.counts.ended += 1
            if entity == standard.ALL_ENTITIES:
                prefix = (site << 32) | (app << 16)
                for uid in [u for u in self.seen if u >> 16 == prefix >> 16]:
                    self._forget(uid)
            else:
                self._forget((site << 32) | (app << 16) | entity)

    def _forget(self, uid: int) -> None:
        self.names.pop(uid, None)
        if self.seen.pop(uid, None) is not None:
            self.counts.removed += 1

    def _states(self, es: npt.NDArray[np.void], arrival: npt.NDArray[np.float64]) -> None:
        cfg, c = self.config, self.counts
        sender = (es["site"].astype(np.int64) << 16) | es["application"].astype(np.int64)
        own = sender == ((cfg.own[0] << 16) | cfg.own[1])
        c.add("own", int(own.sum()))
        keep = ~own
        if cfg.accept is not None:
            allowed = np.array([(s << 16) | a for s, a in cfg.accept], np.int64)
            out = keep & ~np.isin(sender, allowed)
            self._refuse("filtered", out)
            keep &= ~out
        loc = es["location"].astype(float)
        radius = np.sqrt(np.sum(loc * loc, axis=1))
        sane = np.isfinite(radius) & (radius > MIN_RADIUS) & (radius < MAX_RADIUS) \
            & np.isfinite(es["velocity"]).all(axis=1)
        self._refuse("absurd", keep & ~sane)
        keep &= sane
        uid = (sender << 16) | es["entity"].astype(np.int64)
        gone = keep & ((es["appearance"] & pdu.DEACTIVATED) != 0)
        c.ended += int(np.count_nonzero(gone))
        for u in uid[gone].tolist():
            self._forget(u)
        keep &= ~gone
        t = self._times(es["timestamp"], sender, arrival)
        late = keep & ~np.isfinite(t)
        self._refuse("time", late)
        keep &= ~late
        rows = np.flatnonzero(keep)
        if not len(rows):
            return
        # an entity's PDUs of one window go in successive scans (one row each), its
        # newest PER_WINDOW at most: a flooding entity cannot multiply the messages
        order = rows[np.argsort(uid[rows], kind="stable")]
        first = np.r_[True, uid[order][1:] != uid[order][:-1]]
        start = np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))
        end = np.r_[np.flatnonzero(first)[1:], len(order)]
        rank = np.arange(len(order)) - start  # 0 for an entity's first PDU of the window
        count = (end - start[first])[np.cumsum(first) - 1]
        late = rank >= count - PER_WINDOW  # its newest PER_WINDOW
        self._refuse("superseded", ~late)
        order, rank = order[late], rank[late] - (count[late] - np.minimum(count[late],
                                                                          PER_WINDOW))
        now = time.monotonic()
        for r in range(int(rank.max()) + 1 if len(rank) else 0):
            self._send_rows(np.sort(order[rank == r]), uid, t, loc, now)

    def _send_rows(self, rows: npt.NDArray[np.int64], uid: npt.NDArray[np.int64],
                   t: npt.NDArray[np.float64], loc: npt.NDArray[np.float64],
                   now: float) -> None:
        """One scan/ message: the rows (one per entity), their target ids."""
        ids = []
        for u in uid[rows].tolist():
            name = self.names.get(u)
            if name is None:
                if len(self.seen) >= self.config.max_entities:
                    ids.append("")
                    continue
                name = self.names[u] = f"{u >> 32}-{(u >> 16) & 0xFFFF}-{u & 0xFFFF}"
            self.seen[u] = now
            ids.append(name)
        held = np.array([bool(i) for i in ids])
        self._refuse("entities", ~held)
        rows, ids = rows[held], [i for i in ids if i]
        if len(rows):
            self.send(t[rows], ids, self.frame.to_enu(loc[rows]))
            self.counts.accepted += len(rows)
            self.counts.scans += 1

    def _times(self, stamp: npt.NDArray[np.uint32], sender: npt.NDArray[np.int64],
               arrival: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Each PDU's time, s (NaN: refused for its time)."""
        cfg = self.config
        if cfg.clock == "arrival":
            return arrival.copy()
        past = pdu.seconds_past_hour(stamp)
        absolute = (stamp & pdu.ABSOLUTE) != 0
        t = self.clocks.nearest_hour(past, arrival)
        if cfg.time_window > 0:
            t[absolute & (np.abs(t - arrival) > cfg.time_window)] = math.nan
        if (~absolute).any():
            t[~absolute] = self.clocks.relative(sender[~absolute], past[~absolute],
                                                arrival[~absolute])
        return t

    def sweep(self, now: float) -> None:
        """End the entities silent for `timeout` s (the standard's time-out)."""
        self.next_sweep = now + 1.0
        stale = [u for u, seen in self.seen.items() if now - seen > self.config.timeout]
        for u in stale:
            del self.seen[u]
            self.names.pop(u, None)
        self.counts.timed_out += len(stale)
