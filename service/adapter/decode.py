"""Ingest, continued: the typed inputs' keys and payloads read into checked values (the
contract's checks, `zenoh_track.wire`), each bad one with its reason. Nothing is reported or
applied here: the worker reports the reasons in message order, among the time policy's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..wire import Keys, Rejected, parse_clock, parse_plots, parse_scan_columns, parse_singles
from ..wire.scans import ScanColumns
from .ingest import ClockMessage, LabelledScan, Plots, Singles
from .layouts import by_layout

KEYS_HELD = 1 << 20  # measurement keys whose chunks are remembered (`Decoder.meas_key`)
BAD_KEY = "measurement key must be <ns>/meas/<sensor>/<target>"


@dataclass
class SinglesTake:
    """Single messages read together. `fine`: the indices (among the messages) of those
    with a good key, and their `keys`, `sensors` and `walls`; `parts`: the good ones as
    columns, each part's indices into `fine` with its columns; `seqs`: each fine message's
    seq (None: absent or rejected); `bad`: (message index, key, sensor, reason) of the bad
    ones, in message order."""

    fine: list[int] | range
    keys: list[str]
    sensors: list[str]
    walls: list[float]
    parts: list[tuple[list[int], ScanColumns]]
    seqs: list[int | None]
    bad: list[tuple[int, str, str, str]]


class Decoder:
    """Reads inputs of the namespace `keys`; `noise`: the service's default noise for a
    measurement that gives none."""

    def __init__(self, keys: Keys, noise: tuple[float, float, float, float]) -> None:
        self.keys, self.noise = keys, noise
        self.key_parts: dict[str, tuple[str, ...]] = {}  # `meas_key`
        self.meas_prefix = f"{keys.ns}/meas/"

    def singles(self, run: Singles) -> SinglesTake:
        """Single measurements checked together, as each alone would be: as columns
        (`layouts.by_layout`, else `wire.parse_singles`)."""
        n = len(run)
        keys_all = run.keys
        cache = self.key_parts
        split = list(map(cache.get, keys_all))
        if None in split:  # keys not seen before (a feed's keys repeat every scan)
            split = [self.meas_key(k) if c is None else c for k, c in zip(keys_all, split,
                                                                           strict=True)]
        if sum(map(len, split)) == 2 * n:  # every key good (the usual case)
            fine: list[int] | range = range(n)
            keys, walls, payloads = keys_all, run.walls, run.payloads
            sensors, targets = (list(c) for c in zip(*split, strict=True))
        else:
            fine = [i for i, chunks in enumerate(split) if len(chunks) == 2]
            keys = [keys_all[i] for i in fine]
            sensors, targets = [split[i][0] for i in fine], [split[i][1] for i in fine]
            walls = [run.walls[i] for i in fine]
            payloads = [run.payloads[i] for i in fine]
        got = by_layout(sensors, targets, payloads) or parse_singles(sensors, targets,
                                                                    payloads, self.noise)
        bad_keys = [] if len(fine) == n else [
            (i, keys_all[i], split[i][0], BAD_KEY) for i in range(n) if len(split[i]) != 2]
        bad = sorted(bad_keys + [(fine[i], keys[i], sensors[i], why)
                                 for i, why in got.rejected])
        return SinglesTake(fine, keys, sensors, walls, got.parts, got.seqs, bad)

    def meas_key(self, key: str) -> tuple[str, ...]:
        """(sensor, target) of a `<ns>/meas/<sensor>/<target>` key, or (the sensor to
        report it under,) for a bad one; remembered (a feed's keys repeat every scan;
        the memory is emptied when it holds `KEYS_HELD` keys)."""
        prefix = self.meas_prefix
        chunks = key[len(prefix):].split("/") if key.startswith(prefix) else []
        parts = tuple(chunks) if len(chunks) == 2 else (chunks[0] if chunks and chunks[0]
                                                        else "unknown",)
        if len(self.key_parts) >= KEYS_HELD:
            self.key_parts.clear()
        self.key_parts[key] = parts
        return parts

    def scan(self, item: LabelledScan) -> tuple[str, ScanColumns | None, str | None]:
        """A batched labelled scan: (sensor, its rows as columns or None, why not)."""
        return self._parsed(item.key, "scan", "batched scan", parse_scan_columns,
                            item.payload)

    def plots(self, item: Plots) -> tuple[str, Any, str | None]:
        """An unlabelled scan: (sensor, its `wire.PlotScan` or None, why not)."""
        return self._parsed(item.key, "plots", "scan", parse_plots, item.payload)

    @staticmethod
    def clock(item: ClockMessage) -> tuple[float | None, str | None]:
        """A clock message's time, or None and why not."""
        try:
            return parse_clock(item.payload), None
        except Rejected as exc:
            return None, str(exc)

    def _parsed(self, key: str, kind: str, what: str,
                parse: Callable[[str, bytes, Any], Any], payload: bytes
                ) -> tuple[str, Any, str | None]:
        """The sensor of a `<ns>/<kind>/<sensor>` key and its payload parsed by `parse`,
        or the sensor, None and the reason."""
        chunks = self.keys.chunks_after(key, kind)
        sensor = chunks[0] if chunks and chunks[0] else "unknown"
        try:
            if len(chunks) != 1:
                raise Rejected(f"{what} key must be <ns>/{kind}/<sensor>")
            return sensor, parse(chunks[0], payload, self.noise), None
        except Rejected as exc:
            return sensor, None, str(exc)
