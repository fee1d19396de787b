"""Outcome of interceptions (no Zenoh): the true target's trajectory (`Truth`), one result
row per target (`result_row`), the run's summary (`summarize`) and their text lines
(`line`, `summary_line`) as track-intercept and track-eval print them.
"""

from __future__ import annotations

import bisect
import math
from typing import Any

import numpy as np

from zenoh_track.clients.feeds.scenarios import interpolate
from zenoh_track.clients.intercept.guidance import EPS_T, Interceptor, Law, earliest_reach


class Truth:
    """True states of one target at scan instants, interpolated with constant acceleration
    (the sample's `acc`, else the velocity difference to the next sample, else 0) by
    zenoh_track.clients.feeds.scenarios.interpolate."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []

    @staticmethod
    def _vec(x: Any) -> np.ndarray:
        out = np.zeros(3)
        vals = [float(a) for a in x][:3]
        out[:len(vals)] = vals
        return out

    def add(self, msg: dict[str, Any]) -> None:
        t = float(msg["t"])
        row = (self._vec(msg["pos"]), self._vec(msg.get("vel", [0.0])),
               self._vec(msg["acc"]) if msg.get("acc") is not None else None)
        k = bisect.bisect_left(self.t, t)
        if k < len(self.t) and abs(self.t[k] - t) < EPS_T:
            self.rows[k] = row
        else:
            self.t.insert(k, t)
            self.rows.insert(k, row)

    def __bool__(self) -> bool:
        return bool(self.t)

    def acc(self, k: int) -> np.ndarray:
        p, v, a = self.rows[k]
        if a is not None:
            return a
        if k + 1 < len(self.t):
            return (self.rows[k + 1][1] - v) / (self.t[k + 1] - self.t[k])
        return np.zeros(3)

    def pos(self, t: float | np.ndarray) -> np.ndarray:
        """True position(s) at t: (3,) for a float, (n, 3) for an array."""
        P = np.stack([r[0] for r in self.rows])
        V = np.stack([r[1] for r in self.rows])
        A = np.stack([self.acc(i) for i in range(len(self.t))])
        out = interpolate(np.asarray(self.t), P, V, A, t, eps=EPS_T)[0]
        return out if np.ndim(t) else out[0]


# ---------------------------------------------------------------- results
def percentile(values: list[float], q: float) -> float | None:
    """The q-th percentile of `values`, None for none."""
    return float(np.percentile(values, q)) if values else None


def result_row(tid: str, name: str, law: Law, pl: Interceptor,
               tr: Truth | None) -> dict[str, Any]:
    """The outcome for target `tid` of interceptor `pl` (display id `name-tid`): times s,
    distances m, None where unknown; the true-target figures need its truth `tr`."""
    row: dict[str, Any] = {
        "target": tid, "id": f"{name}-{tid}", "guidance": law.guidance,
        "launch_t": pl.t_launch, "last_t": pl.t, "frames": pl.frames,
        "captured": pl.capture_t is not None, "capture_t": pl.capture_t,
        "capture_dist": pl.capture_dist, "closest_t": pl.closest_t,
        "closest_dist": pl.closest_dist if pl.closest_t is not None else None,
        "pos": [pl.x, pl.y, pl.z], "capture_true_dist": None,
        "closest_true_dist": None, "earliest_reach_t": None}
    if tr is not None:
        if pl.capture_t is not None and pl.capture_pos is not None:
            row["capture_true_dist"] = float(np.linalg.norm(
                tr.pos(pl.capture_t) - np.array(pl.capture_pos)))
        if pl.closest_t is not None and pl.closest_pos is not None:
            row["closest_true_dist"] = float(np.linalg.norm(
                tr.pos(pl.closest_t) - np.array(pl.closest_pos)))
        if pl.t_launch is not None:
            row["earliest_reach_t"] = earliest_reach(
                tr.pos, law.start, law.speed, pl.t_launch,
                max(tr.t[-1], pl.t or tr.t[-1]), step=1e-2)
    return row


def summarize(law: Law, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Capture fraction, times and true-target distances over the rows of one law."""
    cap = [r for r in rows if r["captured"]]
    times = [r["capture_t"] for r in cap]
    true_cap = [r["capture_true_dist"] for r in cap if r["capture_true_dist"] is not None]
    true_ca = [r["closest_true_dist"] for r in rows if r["closest_true_dist"] is not None]
    early = [r["earliest_reach_t"] for r in rows if r["earliest_reach_t"] is not None]
    return {
        "guidance": law.guidance, "speed": law.speed, "start": list(law.start),
        "capture_radius": law.capture, "hold": law.hold,
        "nav": law.nav, "max_turn_deg_s": math.degrees(law.max_turn),
        "pn_form": law.pn_form,
        "targets": len(rows), "captured": len(cap),
        "capture_fraction": len(cap) / len(rows) if rows else None,
        "mean_capture_t": float(np.mean(times)) if times else None,
        "median_capture_t": percentile(times, 50),
        "mean_earliest_reach_t": float(np.mean(early)) if early else None,
        "true_dist_at_capture_median": percentile(true_cap, 50),
        "true_dist_at_capture_p90": percentile(true_cap, 90),
        "true_dist_at_closest_median": percentile(true_ca, 50),
        "true_dist_at_closest_p90": percentile(true_ca, 90),
        "median_closest_dist": percentile(
            [r["closest_dist"] for r in rows if r["closest_dist"] is not None], 50),
    }


# ---------------------------------------------------------------- text output
def _f(x: float | None, fmt: str = ".2f", unit: str = "") -> str:
    return "-" if x is None else f"{x:{fmt}}{unit}"


def line(r: dict[str, Any]) -> str:
    """One target's outcome (a `result_row`) as a line of text."""
    head = f"{r['target']:<16} {r['guidance']:<9}"
    if r["captured"]:
        s = (f"{head} captured at t={_f(r['capture_t'])} s, {_f(r['capture_dist'], '.3f')} m "
             f"from the track, {_f(r['capture_true_dist'])} m from the true target")
    else:
        s = (f"{head} not captured: closest {_f(r['closest_dist'])} m at "
             f"t={_f(r['closest_t'])} s, {_f(r['closest_true_dist'])} m from the true target")
    if r["earliest_reach_t"] is not None:
        s += f"; earliest feasible t={r['earliest_reach_t']:.2f} s"
    return s


def summary_line(s: dict[str, Any]) -> str:
    """The summary of a run (`summarize`) as one line of text."""
    if not s["targets"]:
        return f"track-intercept: {s['guidance']}: no target seen"
    out = (f"track-intercept: {s['guidance']}: {s['captured']}/{s['targets']} captured "
           f"({100 * s['capture_fraction']:.0f} %) within {s['capture_radius']} m of the track, "
           f"mean capture t={_f(s['mean_capture_t'])} s")
    if s["mean_earliest_reach_t"] is not None:
        out += f" (earliest feasible {s['mean_earliest_reach_t']:.2f} s)"
    if s["true_dist_at_capture_median"] is not None:
        out += (f"; true-target distance at capture: median "
                f"{s['true_dist_at_capture_median']:.2f} m, p90 "
                f"{s['true_dist_at_capture_p90']:.2f} m")
    elif s["true_dist_at_closest_median"] is not None:
        out += (f"; true-target distance at closest approach: median "
                f"{s['true_dist_at_closest_median']:.2f} m, p90 "
                f"{s['true_dist_at_closest_p90']:.2f} m")
    return out
