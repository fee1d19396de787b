"""The worker's inputs, in the order they came: single measurements (taken together,
checked as columns), batched labelled scans, unlabelled scans (through the reorder
buffer), clock messages and queries; the time policy (`tracking.timeline`), the clock,
and the measurements waiting (`pending`) until they are applied in one pass (`_flush`).

A part of `node.TrackService` (its base class): the methods use the service's tracker,
clock, reorder buffer, timeline and publisher, and its frame methods
(`_frames_before`, `_frame_between`) and query answers (`_answer`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from .estimation.measurements import MeasurementBatch
from .layouts import by_layout
from .tracking.bulk import BatchOutcome, Rows, track_columns
from .wire import (
    PlotScan,
    Rejected,
    parse_clock,
    parse_plots,
    parse_scan_columns,
    parse_singles,
)

KEYS_HELD = 1 << 20  # measurement keys whose chunks are remembered (`Inputs._meas_key`)

if TYPE_CHECKING:
    from .outputs import Counters, Publisher
    from .tracking.clock import Lockstep, Realtime
    from .tracking.reorder import ReorderBuffer
    from .tracking.timeline import Timeline
    from .tracking.tracker import Tracker
    from .wire import Keys


class Inputs:
    """How the worker takes its inputs (see the module's docstring)."""

    tracker: Tracker
    keys: Keys
    out: Publisher
    count: Counters
    clock: Lockstep | Realtime
    realtime: bool
    reorder: ReorderBuffer
    timeline: Timeline
    noise: tuple[float, float, float, float]
    last_seq: dict[str, int]
    meas_key_parts: dict[str, tuple[str, ...]]  # `_meas_key`
    picture_t: float | None

    def _frames_before(self, t: float, pending: list[Rows]) -> None:
        raise NotImplementedError  # node.TrackService

    def _frame_between(self) -> None:
        raise NotImplementedError  # node.TrackService

    def _answer(self, kind: str, query: Any) -> None:
        raise NotImplementedError  # node.TrackService

    def _take(self, item: tuple, pending: list[Rows]) -> None:
        """One input of the worker's batch other than a single measurement."""
        kind = item[0]
        if kind == "clock":
            try:
                t = parse_clock(item[2])
            except Rejected as exc:
                self.out.reject(item[1], "clock", str(exc))
                return
            if not self._admit(t, item[3], item[1], "clock", pending):
                return
            if len(self.reorder):  # nothing older will come: the held scans go
                self._flush(pending)
                for _, (key, scan) in self.reorder.advance(t, flush=True):
                    self._apply_scan(key, scan)
            if self.realtime:  # the measurements received before it go first: the frames
                self._flush(pending)  # its time makes due must show them
                self.clock.observe(t, item[3])
            else:
                self._frames_before(t, pending)
        elif kind == "scan":
            self._take_labelled(item[1], item[2], item[3], pending)
        elif kind == "plots":
            self._flush(pending)  # the labelled ones received before it go first
            self._take_scan(item[1], item[2], item[3])
        elif kind in ("tracks", "status", "frame", "display"):
            self._flush(pending)
            self._answer(kind, item[1])

    def _take_singles(self, items: list[tuple], pending: list[Rows]) -> None:
        """Single measurements taken together, in order, as each alone would be: checked
        as columns (`layouts.by_layout`, else `wire.parse_singles`; a bad one reported on
        its own key), their `seq` counted, the time policy and the clock applied, and the
        good ones left waiting in `pending` (a lockstep frame due before one goes out before it)."""
        n = len(items)
        keys_all = [it[1] for it in items]
        cache = self.meas_key_parts
        split = list(map(cache.get, keys_all))
        if None in split:  # keys not seen before (a feed's keys repeat every scan)
            split = [self._meas_key(k) if c is None else c for k, c in zip(keys_all, split,
                                                                            strict=True)]
        if sum(map(len, split)) == 2 * n:  # every key good (the usual case)
            fine: list[int] | range = range(n)
            keys, walls = keys_all, [it[3] for it in items]
            sensors, targets = (list(c) for c in zip(*split, strict=True))
            payloads = [it[2] for it in items]
        else:
            fine = [i for i, chunks in enumerate(split) if len(chunks) == 2]
            keys = [keys_all[i] for i in fine]
            sensors, targets = [split[i][0] for i in fine], [split[i][1] for i in fine]
            walls = [items[i][3] for i in fine]
            payloads = [items[i][2] for i in fine]
        got = by_layout(sensors, targets, payloads) or parse_singles(sensors, targets,
                                                                    payloads, self.noise)
        # the bad ones, reported in message order: bad keys, then what parse_singles found
        bad_keys = [] if len(fine) == n else [
            (i, keys_all[i], split[i][0], "measurement key must be <ns>/meas/<sensor>/<target>")
            for i in range(n) if len(split[i]) != 2]
        bad = iter(sorted(bad_keys + [(fine[i], keys[i], sensors[i], why)
                                      for i, why in got.rejected]))
        later = next(bad, None)

        def reject_before(upto: float) -> None:  # message index upto (in `fine`) and after
            nonlocal later
            at = fine[int(upto)] if upto < len(fine) else math.inf
            while later is not None and later[0] < at:
                self.out.reject(*later[1:])
                later = next(bad, None)

        self._count_seqs(sensors, got.seqs)
        for index, cols in got.parts:
            if len(index) == len(sensors):  # all of them (the usual case)
                rows = Rows(sensors, cols.ids, MeasurementBatch.of_scan(cols))
                at, near = keys, walls
            else:
                rows = Rows([sensors[i] for i in index], cols.ids,
                            MeasurementBatch.of_scan(cols))
                at, near = [keys[i] for i in index], [walls[i] for i in index]
            if self._near(rows.batch.t, near):  # one admission for all: the same outcome
                reject_before(index[-1])
                self._admit(float(rows.batch.t.max()), near[-1], at[-1], rows.sensors[-1],
                            pending)
                self._wait(rows, near, pending)
                continue
            for i, x in enumerate(rows.batch.t.tolist()):  # else each in turn, as alone
                reject_before(index[i])
                if self._admit(x, near[i], at[i], rows.sensors[i], pending):
                    self._wait(rows.rows(i, i + 1), near[i:i + 1], pending)
        reject_before(math.inf)

    def _meas_key(self, key: str) -> tuple[str, ...]:
        """(sensor, target) of a `<ns>/meas/<sensor>/<target>` key, or (the sensor to
        report it under,) for a bad one; remembered (a feed's keys repeat every scan;
        the memory is emptied when it holds `KEYS_HELD` keys)."""
        prefix = f"{self.keys.ns}/meas/"
        chunks = key[len(prefix):].split("/") if key.startswith(prefix) else []
        parts = tuple(chunks) if len(chunks) == 2 else (chunks[0] if chunks and chunks[0]
                                                        else "unknown",)
        if len(self.meas_key_parts) >= KEYS_HELD:
            self.meas_key_parts.clear()
        self.meas_key_parts[key] = parts
        return parts

    def _count_seqs(self, sensors: list[str], seqs: list[int | None]) -> None:
        """Count the measurements lost (gaps in each sensor's `seq`, in message order) and
        keep each sensor's highest seq."""
        last_seq = self.last_seq
        if len(seqs) >= 16 and None not in seqs and sensors.count(sensors[0]) == len(seqs):
            # one sensor, every message numbered (a feed's burst): as columns
            s = np.array(seqs, dtype=np.int64)
            run = np.maximum.accumulate(s)
            last = last_seq.get(sensors[0])
            before = np.empty_like(s)  # the highest seq before each message
            before[1:] = run[:-1]
            before[0] = s[0] - 1 if last is None else last
            if last is not None:
                np.maximum(before, last, out=before)
            gaps = s - before - 1
            self.count.meas_lost += int(gaps[gaps > 0].sum())
            top = int(run[-1])
            last_seq[sensors[0]] = top if last is None else max(last, top)
            return
        for sensor, seq in zip(sensors, seqs, strict=True):
            if seq is not None:
                last = last_seq.get(sensor)
                if last is not None and seq > last + 1:
                    self.count.meas_lost += seq - last - 1
                last_seq[sensor] = seq if last is None else max(last, seq)

    def _near(self, t: np.ndarray, walls: list[float]) -> bool:
        """Whether inputs of times t received at `walls` are all within --max-jump of the
        picture's time and of each other (then the time policy takes each of them)."""
        lo, hi = float(t.min()), float(t.max())
        if self.realtime:
            off = self.clock.offset
            if off is not None:
                lo, hi = min(lo, min(walls) + off), max(hi, max(walls) + off)
        elif self.picture_t is not None:
            lo, hi = min(lo, self.picture_t), max(hi, self.picture_t)
        return hi - lo <= self.timeline.max_jump

    def _wait(self, rows: Rows, walls: list[float], pending: list[Rows]) -> None:
        """Taken measurements wait in `pending`; the realtime clock learns from them, a
        lockstep frame due before one goes out before it."""
        if self.realtime:
            self._observe(rows.batch.t, walls)
            pending.append(rows)
        else:
            self._wait_lockstep(rows, pending)

    def _observe(self, t: np.ndarray, walls: list[float]) -> None:
        """The realtime clock learns from inputs of times t received at `walls` (the
        newest time of each arrival stamp: what observing each would leave)."""
        if walls[0] == walls[-1] and len(set(walls)) == 1:  # one arrival stamp (usual)
            self.clock.observe(float(t.max()), walls[0])
            return
        newest: dict[float, float] = {}
        for x, w in zip(t.tolist(), walls, strict=True):
            if x > newest.get(w, -math.inf):
                newest[w] = x
        for w, x in newest.items():
            self.clock.observe(x, w)

    def _wait_lockstep(self, rows: Rows, pending: list[Rows]) -> None:
        """Lockstep: the frames due before each measurement go out before it (and after
        those before it): `rows` wait in `pending` in pieces cut where frames fall due."""
        t = rows.batch.t.tolist()
        start = 0
        for i, x in enumerate(t):
            if i == 0 or self._frame_due(x):
                if i > start:
                    pending.append(rows.rows(start, i))
                    start = i
                self._frames_before(x, pending)
        pending.append(rows.rows(start, len(t)) if start else rows)

    def _frame_due(self, t: float) -> bool:
        """Whether a lockstep frame is due before an input of time t."""
        held = self.reorder.oldest()
        x = t if held is None else min(t, held)
        return self.clock.due_soon(x - self.tracker.config.display.lag)

    def _parsed(self, key: str, kind: str, what: str, parse: Any, payload: bytes
                ) -> tuple[str, Any]:
        """The sensor of a `<ns>/<kind>/<sensor>` key and its payload parsed by `parse`,
        or the sensor and None once a rejection is reported."""
        chunks = self.keys.chunks_after(key, kind)
        sensor = chunks[0] if chunks and chunks[0] else "unknown"
        try:
            if len(chunks) != 1:
                raise Rejected(f"{what} key must be <ns>/{kind}/<sensor>")
            return sensor, parse(chunks[0], payload, self.noise)
        except Rejected as exc:
            self.out.reject(key, sensor, str(exc))
            return sensor, None

    def _take_labelled(self, key: str, payload: bytes, wall: float,
                       pending: list[Rows]) -> None:
        """A batched labelled scan (`scan/<sensor>`): its rows mean what single messages
        would (each bad row reported alone, the time policy per row's time) and wait with
        them, to be applied in one pass over the columns (`_flush`)."""
        sensor, scan = self._parsed(key, "scan", "batched scan", parse_scan_columns, payload)
        if scan is None:
            return
        for _, reason in scan.rejected:
            self.out.reject(key, sensor, reason)
        if not scan.good:
            return
        batch = MeasurementBatch.of_scan(scan)
        ids = scan.ids
        keep = self._admit_rows(batch.t, wall, key, sensor, pending)
        if keep is not None:
            if not keep.any():
                return
            batch = batch.take(np.flatnonzero(keep))
            ids = [i for i, k in zip(ids, keep.tolist(), strict=True) if k]
        self._wait(Rows([sensor] * len(ids), ids, batch), [wall] * len(ids), pending)

    def _admit_rows(self, t: np.ndarray, wall: float, key: str, sensor: str,
                    pending: list[Rows]) -> np.ndarray | None:
        """The time policy for the rows of a batched scan, times t: None when every row
        is taken (all within --max-jump of the picture's time: one admission for all),
        else the mask of the rows taken (the policy once per distinct time, in time
        order, as single messages; a refusal reported once per time, every row counted)."""
        lo, hi = float(t.min()), float(t.max())
        if self.realtime:
            off = self.clock.offset
            now = None if off is None else wall + off
        else:
            now = self.picture_t
        if now is not None and max(abs(lo - now), abs(hi - now)) <= self.timeline.max_jump:
            self._admit(hi, wall, key, sensor, pending)  # taken: the picture moves to hi
            return None
        times = np.unique(t)
        refused = [x for x in times.tolist() if not self._admit(x, wall, key, sensor, pending)]
        if not refused:
            return None
        keep = ~np.isin(t, refused)
        extra = int((~keep).sum()) - len(refused)
        self.out.count.meas_rejected += extra
        by = self.out.count.by_reason  # counted by code like the one reported
        by["time_far"] = by.get("time_far", 0) + extra
        return keep

    def _take_scan(self, key: str, payload: bytes, wall: float) -> None:
        """Check an unlabelled scan, report its bad detections, and let it wait in the
        reorder buffer; apply the scans it releases."""
        sensor, scan = self._parsed(key, "plots", "scan", parse_plots, payload)
        if scan is None:
            return
        if not self._admit(scan.t, wall, key, sensor, []):
            return  # far from the picture's time (before `late`: the worse fault)
        late = self.reorder.late(scan.t, sensor)
        if late:
            self.out.reject(key, sensor, late)
            return
        for _, reason in scan.rejected:
            self.out.reject(key, sensor, reason)
        if self.realtime:
            self.clock.observe(scan.t, wall)
        for _, (k, s) in self.reorder.push(sensor, scan.t, (key, scan)):
            self._apply_scan(k, s)

    def _admit(self, t: float, wall: float, key: str, sensor: str,
               pending: list[Rows]) -> bool:
        """The time policy (`tracking.timeline`, docs/protocol.md §6.1) for an input of
        time t received at `wall`: False when it was refused (and reported)."""
        if self.realtime:
            off = self.clock.offset
            now = None if off is None else wall + off
        else:
            now = self.picture_t
        # measurements waiting in `pending` count as tracks: they are about to be applied
        reason, jump = self.timeline.admit(t, now, len(self.tracker) or len(pending))
        if reason is not None:
            self.out.reject(key, sensor, reason)
            return False
        if jump:
            self._new_timeline(t, now, pending)  # realtime: its clock starts one itself
        if not self.realtime and (self.picture_t is None or t > self.picture_t):
            self.picture_t = t
        return True

    def _new_timeline(self, t: float, now: float | None, pending: list[Rows]) -> None:
        """Move the picture to time t: the old timeline's inputs go first, the lockstep
        clock starts afresh (no frames for the gap); forward, the tracks stale at t are
        deleted, backward, the tracks of the abandoned later timeline (they would never
        age out)."""
        self._flush(pending)
        for _, (k, s) in self.reorder.advance(math.inf, flush=True):
            self._apply_scan(k, s)
        self.reorder.reset()
        if not self.realtime:
            self.clock.restart(t)
            self.picture_t = t
        if now is not None and t < now:
            self.out.deleted(self.tracker.drop_newer(t))
        else:  # the tracks stale at the new time go before its first input
            self.out.deleted(self.tracker.delete(t))

    def _apply_scan(self, key: str, scan: PlotScan) -> None:
        if not self.realtime:
            self._frames_before(scan.t, [])
        outcomes, deleted = self.tracker.track_scan(scan)
        self.out.deleted(deleted)
        self.count.scans_applied += 1
        self.out.states(outcomes, key)
        self.out.noise(self.tracker.noise)

    def _flush(self, pending: list[Rows]) -> None:
        """Apply the measurements waiting, in order, in one pass over their columns
        (`tracking.bulk`, as a batched scan's rows; one pass per dimension when they mix
        2-D and 3-D). Realtime, the frame due goes out before the pass and after it,
        before the states (a step of a burst spends most of its time in the pass)."""
        if not pending:
            return
        want = self.out.wanted if self.out.wants_states else None
        pause = self._between_parts if self.realtime else None
        for rows in Rows.joined(pending):
            if pause:
                self._frame_between()
            outcome = track_columns(self.tracker, rows.ids, rows.sensors, rows.batch, want,
                                    pause)
            self.out.deleted(outcome.deleted)
            if pause:
                self._frame_between()
            self.out.batch(rows.sensors, rows.ids, outcome)
        pending.clear()
        self.out.noise(self.tracker.noise)  # stated noise far off

    def _between_parts(self, outcome: BatchOutcome) -> None:
        """Realtime, between parts of an update: the states of the tracks updated so far
        go out, then the frame due, if any."""
        self.out.put_states(outcome.states)
        outcome.states.clear()
        self._frame_between()
