"""Guidance laws and the kinematics of one interceptor (pure maths, no Zenoh).

`Law` holds the parameters of a run, `Interceptor` flies one interceptor at one displayed
target, one display frame at a time (pure pursuit, proportional navigation or predicted
intercept point; the laws are described in zenoh_track.clients.intercept.intercept);
`intercept_time` and
`earliest_reach` are the collision-course and feasibility geometry.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

GUIDANCE = ("pure", "pn", "intercept")
PN_FORMS = ("true", "pure")
DEFAULT_START = (7000.0, 6000.0)
DEFAULT_SPEED = 20.0
DEFAULT_CAPTURE = 2.55  # m: the paper's capture distance (docs/scenarios.md, C)
EPS_T = 1e-6


# ---------------------------------------------------------------- guidance geometry
def intercept_time(r: tuple[float, float], v: tuple[float, float], s: float) -> float | None:
    """Least positive tau with |r + v tau| = s tau (r = target - interceptor, v = target
    velocity, s = interceptor speed), or None when the target cannot be met at speed s."""
    a = v[0] * v[0] + v[1] * v[1] - s * s
    b = 2.0 * (r[0] * v[0] + r[1] * v[1])
    c = r[0] * r[0] + r[1] * r[1]
    if c == 0.0:
        return 0.0
    if abs(a) < 1e-12 * max(s * s, 1.0):  # equal speeds: the equation is linear
        return -c / b if b < 0.0 else None
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        return None
    sq = math.sqrt(disc)
    roots = sorted(((-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)))
    return next((tau for tau in roots if tau > 0.0), None)


def earliest_reach(pos_at: Callable[[np.ndarray], np.ndarray], start: Iterable[float],
                   speed: float, t0: float, t1: float, step: float = 1e-3) -> float | None:
    """Earliest t in [t0, t1] with |pos_at(t) - start| <= speed * (t - t0) in the
    horizontal plane (the physical limit for any guidance), to `step` s; None if never."""
    ts = np.arange(t0, t1 + step / 2, step)
    p = np.asarray(pos_at(ts), dtype=float)[:, :2]
    ok = np.hypot(*(p - np.asarray(list(start)[:2], dtype=float)).T) <= speed * (ts - t0)
    return float(ts[np.argmax(ok)]) if ok.any() else None


# ---------------------------------------------------------------- one interceptor
@dataclass
class Law:
    """Guidance parameters shared by every interceptor of one run."""

    guidance: str = "intercept"
    speed: float = DEFAULT_SPEED
    start: tuple[float, float] = DEFAULT_START
    capture: float = DEFAULT_CAPTURE
    nav: float = 4.0  # PN navigation constant N (3-5 is usual)
    max_turn: float = math.radians(30.0)  # rad/s, PN only
    pn_form: str = "true"  # true: a = N Vc dlambda/dt; pure: a = N V dlambda/dt
    hold: bool = True

    def __post_init__(self) -> None:
        if self.guidance not in GUIDANCE:
            raise ValueError(f"guidance must be one of {GUIDANCE}, not {self.guidance!r}")
        if not self.speed > 0:
            raise ValueError("speed must be positive")
        if self.pn_form not in PN_FORMS:
            raise ValueError(f"pn_form must be one of {PN_FORMS}, not {self.pn_form!r}")


class Interceptor:
    """One interceptor chasing one displayed target, advanced by `frame()`.

    Pure Python floats (a per-frame step on 2-vectors is cheaper without NumPy)."""

    def __init__(self, target: str, law: Law) -> None:
        self.target, self.law = target, law
        self.x, self.y, self.z = float(law.start[0]), float(law.start[1]), 0.0
        self.hx, self.hy = 0.0, 0.0  # unit heading commanded for the next interval
        self.flying = True
        self.t: float | None = None
        self.t_launch: float | None = None
        self.dt = 0.0
        self.frames = 0
        self.capture_t: float | None = None
        self.capture_pos: tuple[float, float, float] | None = None
        self.capture_dist: float | None = None
        self.closest_t: float | None = None
        self.closest_dist = math.inf
        self.closest_pos: tuple[float, float, float] | None = None

    # -------------------------------------------------------- guidance laws
    def _aim(self, px: float, py: float) -> None:
        dx, dy = px - self.x, py - self.y
        d = math.hypot(dx, dy)
        if d > 0.0:
            self.hx, self.hy = dx / d, dy / d

    def _steer(self, p: list[float], v: list[float], dt: float) -> None:
        law = self.law
        rx, ry = p[0] - self.x, p[1] - self.y
        if law.guidance == "pure" or (self.hx == 0.0 and self.hy == 0.0):
            self._aim(p[0], p[1])  # PN and intercept also launch along the line of sight
            if law.guidance != "intercept":
                return
        if law.guidance == "intercept":
            tau = intercept_time((rx, ry), (v[0], v[1]), law.speed)
            if tau is None:
                self._aim(p[0], p[1])
            else:
                self._aim(p[0] + v[0] * tau, p[1] + v[1] * tau)
            return
        # proportional navigation on the heading angle
        s = law.speed
        vrx, vry = v[0] - s * self.hx, v[1] - s * self.hy
        r2 = rx * rx + ry * ry
        if r2 == 0.0:
            return
        r = math.sqrt(r2)
        closing = -(rx * vrx + ry * vry) / r
        los_rate = (rx * vry - ry * vrx) / r2
        if law.pn_form == "pure":
            rate = law.nav * los_rate
        elif closing > 0.0:
            rate = law.nav * los_rate * closing / s
        else:  # range opening: PN's command has the wrong sign; turn toward the LOS
            err = math.atan2(self.hx * ry - self.hy * rx, self.hx * rx + self.hy * ry)
            rate = math.copysign(law.max_turn, err) if dt > 0 else 0.0
            if dt > 0 and abs(err) < law.max_turn * dt:
                rate = err / dt
        rate = max(-law.max_turn, min(law.max_turn, rate))
        psi = math.atan2(self.hy, self.hx) + rate * dt
        self.hx, self.hy = math.cos(psi), math.sin(psi)

    # -------------------------------------------------------- one display frame
    def frame(self, t: float, p: list[float], v: list[float]) -> bool:
        """Advance to the display instant t of the target shown at p with velocity v.
        Returns False (and changes nothing) for a frame not after the previous one."""
        if self.t is None:
            self.t_launch, dt = t, 0.0
        else:
            dt = t - self.t
            if dt <= EPS_T:
                return False
            if self.flying:
                self.x += self.law.speed * self.hx * dt
                self.y += self.law.speed * self.hy * dt
        self.t, self.dt = t, dt
        self.frames += 1
        self.z = float(p[2]) if len(p) > 2 else 0.0
        d = math.hypot(p[0] - self.x, p[1] - self.y)
        if self.flying:
            if d < self.closest_dist:
                self.closest_t, self.closest_dist = t, d
                self.closest_pos = (self.x, self.y, self.z)
            if self.capture_t is None and d < self.law.capture:
                self.capture_t, self.capture_dist = t, d
                self.capture_pos = (self.x, self.y, self.z)
                if self.law.hold:
                    self.flying = False
                    self.hx = self.hy = 0.0
        if self.flying:
            self._steer(p, v, dt)
        return True

    def display(self, name: str) -> dict[str, Any]:
        """Its state as a display entity with id `name-<target>`."""
        s = self.law.speed if self.flying else 0.0
        return {"t": self.t, "id": f"{name}-{self.target}", "pos": [self.x, self.y, self.z],
                "vel": [s * self.hx, s * self.hy, 0.0], "sigma": 0.0, "status": "confirmed",
                "age": 0.0, "target": self.target, "captured": self.capture_t is not None}
