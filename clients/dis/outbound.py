"""DIS out: the service's tracks as Entity State PDUs, sent the way IEEE 1278.1 sends
them. At every frame the gateway dead-reckons each entity from the last PDU it sent, as
a receiver would, and sends a new PDU only for an entity whose dead-reckoned position is
off by more than DRA_POS_THRSH, whose orientation is off by more than
DRA_ORIENT_THRSH, or whose last PDU is a heartbeat (HBT_ESPDU) old. A track that leaves
the picture goes out as a last PDU with the deactivated appearance bit, then a Remove
Entity PDU (docs/gateways.md)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from zenoh_track.clients.dis import pdu, standard
from zenoh_track.clients.dis.geodesy import (
    EnuFrame,
    angle_between,
    body_matrix,
    euler_of,
    local_axes,
    rotation_of,
    turn_rate,
)
from zenoh_track.clients.lib import Frame
from zenoh_track.wire import STATUSES

F64 = npt.NDArray[np.float64]
MAX_NUMBER = 0xFFFE  # entity numbers 1..0xFFFE (0 and 0xFFFF are reserved)
MARKING = 11  # characters
CAUSES = ("new", "position", "orientation", "heartbeat")


@dataclass
class OutConfig:
    """How the gateway's entities look and when they are sent (docs/gateways.md)."""

    exercise: int = standard.EXERCISE
    site: int = standard.OWN_SITE
    application: int = standard.OWN_APPLICATION
    entity_type: tuple[int, ...] = pdu.parse_entity_type(standard.ENTITY_TYPE)
    force: int = standard.FORCE
    dr: str = "fvw"
    pos_threshold: float = standard.DRA_POS_THRSH
    orient_threshold: float = standard.DRA_ORIENT_THRSH
    heartbeat: float = standard.HBT_ESPDU
    absolute: bool = True  # timestamps: the service's time is UTC (a realtime service)
    statuses: tuple[str, ...] = ("confirmed", "coasting")


@dataclass
class OutCounts:
    frames: int = 0
    sent: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CAUSES, 0))
    removed: int = 0
    no_number: int = 0  # tracks left out: every entity number in use


def marking(track_id: str, number: int) -> str:
    """The track id, or for an id longer than 11 characters its first 5, '~' and the
    entity number on 5 digits: unique among the gateway's entities as the number is."""
    return track_id if len(track_id) <= MARKING else f"{track_id[:5]}~{number:05d}"


class Table:
    """The gateway's entities: the track id of each row, its entity number, and the
    state its last PDU stated (what every receiver dead-reckons from)."""

    def __init__(self) -> None:
        self.index: dict[str, int] = {}
        self.ids: list[str] = []
        self.free: list[int] = []  # rows free for reuse
        self.number = np.zeros(0, np.int64)
        self.t0 = np.zeros(0)
        self.pos0 = np.zeros((0, 3))
        self.vel0 = np.zeros((0, 3))
        self.acc0 = np.zeros((0, 3))
        self.axes0 = np.zeros((0, 3, 3))  # body-to-ECEF matrix as stated
        self.omega0 = np.zeros((0, 3))
        # local North and Up where the last PDU was (an entity moves a few km between
        # PDUs: its Up turns by hundredths of a degree, far below the 3 deg threshold)
        self.north0 = np.zeros((0, 3))
        self.up0 = np.zeros((0, 3))
        self.acc = np.zeros((0, 3))  # the track's acceleration, ENU (from `states`)
        self.fresh = np.zeros(0, bool)  # no PDU sent yet
        self.next_number = 1

    def rows(self, ids: list[str]) -> npt.NDArray[np.int64]:
        """Each id's row, -1 for an id without one."""
        get = self.index.get
        return np.array([get(i, -1) for i in ids], np.int64)

    def add(self, track_id: str) -> int:
        """A row and an entity number for a new track (-1: every number is in use)."""
        if len(self.index) >= MAX_NUMBER:
            return -1
        in_use = set(self.number[list(self.index.values())].tolist()) if self.index else set()
        while self.next_number in in_use:
            self.next_number = self.next_number % MAX_NUMBER + 1
        if self.free:
            row = self.free.pop()
            self.ids[row] = track_id
        else:
            row = len(self.ids)
            self.ids.append(track_id)
            self._grow(row + 1)
        self.number[row] = self.next_number
        self.next_number = self.next_number % MAX_NUMBER + 1
        self.acc[row], self.axes0[row], self.fresh[row] = 0.0, np.eye(3), True
        self.index[track_id] = row
        return row

    def _grow(self, n: int) -> None:
        if n <= len(self.number):
            return
        size = max(n, 2 * len(self.number), 64)
        for name in ("number", "t0", "pos0", "vel0", "acc0", "axes0", "omega0", "north0",
                     "up0", "acc", "fresh"):
            old = getattr(self, name)
            new = np.zeros((size, *old.shape[1:]), old.dtype)
            new[:len(old)] = old
            setattr(self, name, new)

    def drop(self, track_id: str) -> int:
        row = self.index.pop(track_id)
        self.free.append(row)
        return row


class Outbound:
    """Turns each frame of the service into the PDUs due (`send(datagram)` each)."""

    def __init__(self, frame: EnuFrame, config: OutConfig, send: Callable[[bytes], object]
                 ) -> None:
        self.frame, self.config, self.send = frame, config, send
        self.algorithm, self.with_acc, self.rotating = standard.DR_ALGORITHMS[config.dr]
        self.table = Table()
        self.counts = OutCounts()
        self.codes = np.array([STATUSES.index(s) for s in config.statuses], np.uint8)
        self.pending_acc: list[tuple[list[str], F64]] = []  # from `states`, not yet applied
        self._seen: list[str] = []  # the previous frame's ids, and their rows
        self._seen_rows = np.zeros(0, np.int64)

    def accelerations(self, ids: list[str], acc: F64) -> None:
        """The tracks' latest filtered accelerations (ENU), applied at the next frame."""
        self.pending_acc.append((ids, acc))

    def on_frame(self, frame: Frame) -> None:
        """Dead-reckon every entity to the frame's time and send the PDUs due."""
        table = self.table
        self.counts.frames += 1
        shown = np.isin(frame.codes, self.codes)
        ids = [i for i, s in zip(frame.id_list, shown.tolist(), strict=True) if s] \
            if not shown.all() else frame.id_list
        if ids != self._seen:
            self._removals(set(ids))
            rows = table.rows(ids)
            for k in np.flatnonzero(rows < 0).tolist():
                rows[k] = table.add(ids[k])
            self._seen, self._seen_rows = list(ids), rows
        rows = self._seen_rows
        for acc_ids, acc in self.pending_acc:
            got = table.rows(acc_ids)
            table.acc[got[got >= 0]] = acc[got >= 0]
        self.pending_acc.clear()
        numbered = rows >= 0
        shown_rows = np.flatnonzero(shown)
        if not numbered.all():
            self.counts.no_number += int(np.count_nonzero(~numbered))
            rows, shown_rows = rows[numbered], shown_rows[numbered]
        if not len(rows):
            return
        pos = self.frame.to_ecef(frame.pos[shown_rows])
        vel = self.frame.vectors_to_ecef(frame.vel[shown_rows])
        acc = self.frame.vectors_to_ecef(table.acc[rows]) if self.with_acc else \
            np.zeros_like(vel)
        fresh = table.fresh[rows]
        if fresh.any():
            table.north0[rows[fresh]], table.up0[rows[fresh]] = local_axes(pos[fresh])
        axes = body_matrix(vel, table.north0[rows], table.up0[rows])
        due, cause = self._due(rows, frame.t, pos, axes)
        if due.any():
            self._send(rows[due], frame.t, pos[due], vel[due], acc[due],
                       np.zeros(0, bool))
            for k, name in enumerate(CAUSES):
                self.counts.sent[name] += int(np.count_nonzero(cause[due] == k))

    def _due(self, rows: npt.NDArray[np.int64], t: float, pos: F64, axes: F64
             ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64]]:
        """Which entities to send now, and why (an index into CAUSES)."""
        cfg, tb = self.config, self.table
        dt = (t - tb.t0[rows])[:, None]
        guess = tb.pos0[rows] + tb.vel0[rows] * dt
        if self.with_acc:
            guess += 0.5 * tb.acc0[rows] * dt * dt
        new = tb.fresh[rows]
        off = np.linalg.norm(guess - pos, axis=1) > cfg.pos_threshold
        stated = tb.axes0[rows]
        if self.rotating:  # body rates: the stated axes turned by omega dt
            stated = stated @ Rotation.from_rotvec(tb.omega0[rows] * dt).as_matrix()
        turned = angle_between(stated, axes) > cfg.orient_threshold
        beat = dt[:, 0] >= cfg.heartbeat
        cause = np.select([new, off, turned, beat], [0, 1, 2, 3], -1)
        return cause >= 0, cause

    def _send(self, rows: npt.NDArray[np.int64], t: float, pos: F64, vel: F64, acc: F64,
              deactivated: npt.NDArray[np.bool_]) -> None:
        """Encode and send one Entity State PDU per row (its orientation along the
        velocity at its own position); remember what each stated."""
        cfg, tb = self.config, self.table
        n = len(rows)
        north, up = local_axes(pos)
        rot = Rotation.from_matrix(body_matrix(vel, north, up))
        out = pdu.entity_state(n)
        pdu.header(out, pdu.ENTITY_STATE, pdu.FAMILY_ENTITY_INFO, cfg.exercise,
                   pdu.timestamp(np.full(n, t), cfg.absolute))
        out["site"], out["application"], out["entity"] = cfg.site, cfg.application, \
            tb.number[rows]
        out["force"] = cfg.force
        for name, value in zip(("kind", "domain", "country", "category", "subcategory",
                                "specific", "extra"), cfg.entity_type, strict=True):
            out["entity_type"][name] = value
        out["velocity"], out["location"], out["acceleration"] = vel, pos, acc
        out["orientation"] = euler_of(rot)
        out["angular_velocity"] = turn_rate(rot, vel, acc)
        out["dr_algorithm"] = self.algorithm
        if len(deactivated):
            out["appearance"] = np.where(deactivated, pdu.DEACTIVATED, 0)
        out["marking_set"] = pdu.MARKING_ASCII
        out["marking"] = pdu.markings([marking(tb.ids[r], int(tb.number[r]))
                                       for r in rows.tolist()])
        for k in range(n):
            self.send(out[k:k + 1].tobytes())
        # what a receiver holds: the values as sent (float32, the timestamp's unit)
        tb.t0[rows], tb.fresh[rows] = t, False
        tb.pos0[rows] = pos
        tb.vel0[rows] = out["velocity"].astype(float)
        tb.acc0[rows] = out["acceleration"].astype(float)
        tb.axes0[rows] = rotation_of(out["orientation"].astype(float)).as_matrix()
        tb.omega0[rows] = out["angular_velocity"].astype(float)
        tb.north0[rows], tb.up0[rows] = north, up

    def _removals(self, present: set[str]) -> None:
        """Tracks gone from the picture: a last PDU with the deactivated bit, then a
        Remove Entity PDU, and their entity numbers freed."""
        tb = self.table
        gone = [i for i in tb.index if i not in present]
        if not gone:
            return
        rows = np.array([tb.index[i] for i in gone], np.int64)
        rows = rows[~tb.fresh[rows]]  # never sent: nothing to remove
        if len(rows):
            self._remove(rows)
        for i in gone:
            tb.drop(i)
        self.counts.removed += len(rows)

    def _remove(self, rows: npt.NDArray[np.int64]) -> None:
        cfg, tb = self.config, self.table
        t = float(tb.t0[rows].max())
        self._send(rows, t, tb.pos0[rows], tb.vel0[rows], tb.acc0[rows],
                   np.ones(len(rows), bool))
        rm = pdu.remove_entity(len(rows))
        pdu.header(rm, pdu.REMOVE_ENTITY, pdu.FAMILY_SIMULATION_MANAGEMENT, cfg.exercise,
                   pdu.timestamp(np.full(len(rows), t), cfg.absolute))
        for part in ("originating", "receiving"):
            rm[part]["site"], rm[part]["application"] = cfg.site, cfg.application
        rm["receiving"]["entity"] = tb.number[rows]
        rm["request_id"] = tb.number[rows]
        for k in range(len(rows)):
            self.send(rm[k:k + 1].tobytes())


class DeadReckoner:
    """A receiver's picture of Entity State PDUs (what a DIS viewer draws): the latest PDU
    of each entity, dead-reckoned to any time by its algorithm (positions; FPW/RPW
    without, RVW/FVW with the acceleration)."""

    def __init__(self) -> None:
        self.latest: dict[tuple[int, int, int], tuple[float, np.void]] = {}
        self.removed: set[tuple[int, int, int]] = set()

    def take(self, t: float, es: np.void) -> None:
        """A PDU, stamped `t` (s): kept when newer than the entity's last."""
        key = (int(es["site"]), int(es["application"]), int(es["entity"]))
        if int(es["appearance"]) & pdu.DEACTIVATED:
            self.latest.pop(key, None)
            self.removed.add(key)
            return
        if key not in self.latest or self.latest[key][0] <= t:
            self.latest[key] = (t, es)

    def position(self, key: tuple[int, int, int], t: float) -> F64 | None:
        """The entity's dead-reckoned ECEF position at `t` (None: unknown)."""
        got = self.latest.get(key)
        if got is None:
            return None
        t0, es = got
        dt = t - t0
        out: F64 = es["location"].astype(float) + es["velocity"].astype(float) * dt
        with_acc = int(es["dr_algorithm"]) in (4, 5, 8, 9)  # RVW, FVW and their body forms
        if with_acc:
            out = out + 0.5 * es["acceleration"].astype(float) * dt * dt
        return out
