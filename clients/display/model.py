"""What `track-display` shows, without the terminal: the track table (from the `frame`
key, ages from `tracks/`), sorted, filtered and paged, and the service's health (from
`status` replies and the liveliness tokens), with the numbers formatted for reading."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from zenoh_track.clients.lib.frames import Frame

# column name -> (title, justify); the sort keys are these names
COLUMNS = {
    "id": ("id", "left"), "x": ("x m", "right"), "y": ("y m", "right"),
    "z": ("z m", "right"), "range": ("range km", "right"), "speed": ("speed m/s", "right"),
    "heading": ("hdg °", "right"), "sigma": ("sigma m", "right"),
    "status": ("status", "left"), "age": ("age s", "right"),
}
SORTS = tuple(COLUMNS)


def fmt_int(v: float) -> str:
    """A number of metres or a count for reading: thousands grouped, no decimals."""
    return f"{v:,.0f}" if math.isfinite(v) else "-"


def fmt_t(t: float | None) -> str:
    """Simulation time with millisecond resolution (never 10.466666666666667)."""
    return "-" if t is None else f"{t:,.3f} s"


def fmt_duration(s: float) -> str:
    s = int(s)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else \
        f"{s // 60}:{s % 60:02d}"


@dataclass
class View:
    """One page of the table."""

    rows: list[dict[str, str]]
    total: int  # tracks in the frame
    matched: int  # tracks the filter lets through
    first: int  # 0-based index of the first row shown among the matched
    page: int  # 0-based
    pages: int


@dataclass
class Table:
    """The track table's state: the latest frame, each track's last update time, and
    the user's sort, filter and page."""

    sort: str = "id"
    reverse: bool = False
    filter: str = ""
    page: int = 0
    page_size: int = 40
    frame: Frame | None = None
    updated: dict[str, float] = field(default_factory=dict)  # id -> t of its last update

    def on_frame(self, frame: Frame) -> None:
        if self.frame is None or frame.t >= self.frame.t:
            self.frame = frame
        for tid in set(self.updated) - set(frame.ids.tolist()):
            del self.updated[tid]  # deleted tracks

    def on_update(self, track_id: str, t: float) -> None:
        if t >= self.updated.get(track_id, -math.inf):
            self.updated[track_id] = t

    def cycle_sort(self) -> None:
        self.sort = SORTS[(SORTS.index(self.sort) + 1) % len(SORTS)]
        self.page = 0

    def set_sort(self, name: str) -> None:
        if name == self.sort:
            self.reverse = not self.reverse
        else:
            self.sort, self.reverse = name, False
        self.page = 0

    def set_filter(self, text: str) -> None:
        self.filter, self.page = text.strip(), 0

    def turn(self, pages: int) -> None:
        self.page = max(self.page + pages, 0)  # clamped to the last page by view()

    def view(self) -> View:
        f = self.frame
        if f is None:
            return View([], 0, 0, 0, 0, 1)
        keep = np.arange(len(f.ids))
        if self.filter:
            needle = self.filter.lower()
            keep = np.array([i for i, tid in enumerate(f.ids.tolist())
                             if needle in tid.lower()], dtype=int)
        speed = np.linalg.norm(f.vel, axis=1)
        age = np.array([f.t - self.updated.get(tid, math.nan) for tid in f.ids.tolist()])
        key = {
            "id": f.ids, "x": f.pos[:, 0], "y": f.pos[:, 1], "z": f.pos[:, 2],
            "range": np.linalg.norm(f.pos, axis=1), "speed": speed,
            "heading": np.degrees(np.arctan2(f.vel[:, 0], f.vel[:, 1])) % 360.0,
            "sigma": f.sigma, "status": f.status, "age": age,
        }
        col = key[self.sort][keep]
        if col.dtype.kind == "f":  # unknown values (NaN) last either way
            col = np.where(np.isnan(col), -np.inf if self.reverse else np.inf, col)
        order = keep[np.argsort(col, kind="stable")]
        if self.reverse:
            order = order[::-1]
        pages = max(1, math.ceil(len(order) / self.page_size))
        self.page = min(self.page, pages - 1)
        first = self.page * self.page_size
        rows = [self._row(f, i, speed[i], key["heading"][i], key["range"][i], age[i])
                for i in order[first:first + self.page_size].tolist()]
        return View(rows, len(f.ids), len(order), first, self.page, pages)

    @staticmethod
    def _row(f: Frame, i: int, speed: float, heading: float, rng: float, age: float
             ) -> dict[str, str]:
        x, y, z = f.pos[i]
        return {"id": str(f.ids[i]), "x": fmt_int(x), "y": fmt_int(y), "z": fmt_int(z),
                "range": f"{rng / 1000:,.2f}", "speed": f"{speed:,.1f}",
                "heading": f"{heading:.0f}" if speed > 0 else "-",
                "sigma": f"{f.sigma[i]:,.1f}", "status": str(f.status[i]),
                "age": "-" if math.isnan(age) else f"{max(age, 0.0):.1f}"}


@dataclass
class Health:
    """The service as the display sees it: liveliness tokens, the instances whose tracks
    the picture holds (`serving`), the latest `status` reply of each instance (rates from
    consecutive ones) and the frames arriving."""

    alive: set[str] = field(default_factory=set)  # instance names
    serving: tuple[str, ...] = ()  # the instances in the latest picture
    statuses: dict[str, dict[str, Any]] = field(default_factory=dict)  # by instance
    walls: dict[str, float] = field(default_factory=dict)
    rates: dict[str, tuple[float, float]] = field(default_factory=dict)  # rejects, frames /s
    frame_walls: list[float] = field(default_factory=list)

    @property
    def status(self) -> dict[str, Any] | None:
        """One instance's status (the first by name), None before any."""
        return self.statuses[min(self.statuses)] if self.statuses else None

    @property
    def rejects_per_s(self) -> float | None:
        return sum(r[0] for r in self.rates.values()) if self.rates else None

    def on_status(self, status: dict[str, Any], wall: float | None = None) -> None:
        """One instance's reply (its rates from its previous reply)."""
        wall = time.monotonic() if wall is None else wall
        name = str(status.get("instance", ""))
        prev, prev_wall = self.statuses.get(name), self.walls.get(name)
        if prev is not None and prev_wall is not None and wall > prev_wall:
            dt = wall - prev_wall
            self.rates[name] = (
                max(status.get("meas_rejected", 0) - prev.get("meas_rejected", 0), 0) / dt,
                max(status.get("frames_published", 0) - prev.get("frames_published", 0), 0)
                / dt)
        self.statuses[name], self.walls[name] = status, wall

    def on_statuses(self, statuses: list[dict[str, Any]], wall: float | None = None) -> None:
        """Every instance's reply to one query: instances that no longer answer are
        forgotten."""
        for st in statuses:
            self.on_status(st, wall)
        names = {str(st.get("instance", "")) for st in statuses}
        for gone in set(self.statuses) - names:
            self.statuses.pop(gone)
            self.walls.pop(gone, None)
            self.rates.pop(gone, None)

    def line(self, ns: str) -> tuple[str, bool]:
        """The health line, and whether all is well (a tracker alive, and every
        instance alive in the picture once the picture holds any)."""
        if not self.alive:
            return f"no tracker alive on '{ns}'", False
        names = ", ".join(sorted(self.alive))
        if len(self.alive) == 1 and len(self.serving) <= 1:
            parts = [f"tracker {names} alive"]
        else:
            parts = [f"{len(self.serving)} of {len(self.alive)} instances serve the "
                     f"picture ({names} alive)"]
        ok = not self.serving or set(self.alive) <= set(self.serving)
        if self.statuses:
            all_ = list(self.statuses.values())
            first = self.status or {}
            total = {k: sum(st.get(k, 0) for st in all_) for k in (
                "meas_accepted", "meas_rejected", "frames_published", "queue")}
            frames = [r[1] for r in self.rates.values()]
            parts += [f"{first.get('clock', '?')} {first.get('rate', 0):g} Hz",
                      f"up {fmt_duration(max(st.get('uptime_s', 0.0) for st in all_))}",
                      f"accepted {fmt_int(total['meas_accepted'])}",
                      f"rejected {fmt_int(total['meas_rejected'])}"
                      + (f" ({self.rejects_per_s:,.1f}/s)" if self.rates else ""),
                      f"frames {fmt_int(total['frames_published'])}"
                      + (f" ({' · '.join(f'{f:,.1f}' for f in frames)}/s)" if frames
                         else ""),
                      f"queue {fmt_int(total['queue'])}"]
        return " · ".join(parts), ok
