"""The three reference problems of docs/scenarios.md (its "Sources" name the papers) as
measurement generators (client side).

Each scenario yields scans: (t, [(target, measurement map)], [(target, truth map)]).
Monte Carlo runs are independent targets named `<scenario>-<run>`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

Scan = tuple[float, list[tuple[str, dict]], list[tuple[str, dict]]]


def interpolate(ts: np.ndarray, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray,
                t: float | np.ndarray, eps: float = 1e-6,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration at time(s) t from states sampled at the
    instants ts (ascending, K of them), with constant acceleration from the last sample at
    or before t (`eps` s of tolerance; before ts[0], from the first sample).

    pos, vel, acc: (K, ...) arrays, the sample instant first; returns three arrays of shape
    (len(t), ...) (one row for a float t). Exact for piecewise-constant accelerations that
    change only at sample instants."""
    ts = np.asarray(ts, dtype=float)
    tt = np.atleast_1d(np.asarray(t, dtype=float))
    k = np.clip(np.searchsorted(ts, tt + eps) - 1, 0, len(ts) - 1)
    tau = (tt - ts[k]).reshape(-1, *[1] * (np.ndim(pos) - 1))
    return pos[k] + vel[k] * tau + 0.5 * acc[k] * tau**2, vel[k] + acc[k] * tau, acc[k]


def _truth(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray | None = None) -> dict:
    out = {"pos": [float(v) for v in pos], "vel": [float(v) for v in vel]}
    if acc is not None:
        out["acc"] = [float(v) for v in acc]
    return out


# ---------------------------------------------------------------- A: 30 Hz display
class FlightA:
    """Scenario A's manoeuvring body (docs/scenarios.md, A), integrated on a 1 ms grid.

    Phases: 0-5 s accelerate 2 m/s^2 North from rest; 5-18 s pitch up to 5 deg, hold,
    back to 0; 18-20 s roll in; 20-30 s right turn at 3 deg/s (30 deg); 30-32 s roll out;
    32-52 s accelerate 1 m/s^2; then straight to 56 s.
    """

    duration = 56.0
    phases = (("accelerate", 0.0, 5.0), ("pitch", 5.0, 18.0), ("turn", 18.0, 32.0),
              ("accelerate-2", 32.0, 52.0), ("straight", 52.0, 56.0))
    step = 1e-3

    def __init__(self) -> None:
        t = np.arange(0.0, self.duration + 2 * self.step, self.step)
        speed = np.where(t < 5, 2.0 * t, 10.0) + np.clip(t - 32, 0, 20) * 1.0
        pitch = np.radians(np.interp(t, [5, 10, 13, 18], [0, 5, 5, 0]))
        heading = np.radians(np.interp(t, [20, 30], [0, 30]))
        vel = np.stack([speed * np.cos(pitch) * np.sin(heading),
                        speed * np.cos(pitch) * np.cos(heading), speed * np.sin(pitch)], 1)
        pos = np.concatenate([np.zeros((1, 3)),
                              np.cumsum(0.5 * (vel[1:] + vel[:-1]) * self.step, 0)])
        self.t, self.pos, self.vel = t, pos, vel
        self.acc = np.gradient(vel, self.step, axis=0)

    def state(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at time(s) t, (len(t), 3) each: constant
        acceleration from the grid point at or before t."""
        return interpolate(self.t, self.pos, self.vel, self.acc, t)


def display(runs: int = 1, seed: int = 0) -> Iterator[Scan]:
    """Scenario A: exact 3-D positions at 1 Hz (sigma 0); every run is identical."""
    del seed
    flight = FlightA()
    for k in range(int(flight.duration) + 1):
        p, v, a = (x[0] for x in flight.state(float(k)))
        names = [f"display-{i:03d}" for i in range(runs)]
        yield (float(k), [(n, {"pos": p.tolist(), "sigma": 0.0}) for n in names],
               [(n, _truth(p, v, a)) for n in names])


# ---------------------------------------------------------------- B: 3-D radar CMKF
@dataclass(frozen=True)
class RadarB:
    x0: tuple[float, ...] = (10_000.0, 10_000.0, 10_000.0, -300.0, -300.0, 0.0)
    q: float = 1.0  # m/s^2, piecewise-constant white acceleration per axis
    sr: float = 50.0
    sa: float = math.radians(0.5)
    scans: int = 200
    period: float = 1.0


def radar3d(runs: int = 1, seed: int = 0, cfg: RadarB = RadarB()) -> Iterator[Scan]:
    """Scenario B: 3-D radar at the origin, nearly-constant-velocity target passing
    almost overhead near t = 33 s."""
    rng = np.random.default_rng(seed)
    T = cfg.period
    x = np.tile(np.array(cfg.x0), (runs, 1))
    names = [f"radar3d-{i:03d}" for i in range(runs)]
    for k in range(cfg.scans):
        if k:
            a = cfg.q * rng.standard_normal((runs, 3))
            x[:, :3] += x[:, 3:] * T + 0.5 * a * T**2
            x[:, 3:] += a * T
        p = x[:, :3]
        r = np.linalg.norm(p, axis=1) + cfg.sr * rng.standard_normal(runs)
        az = np.arctan2(p[:, 0], p[:, 1]) + cfg.sa * rng.standard_normal(runs)
        el = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])) + cfg.sa * rng.standard_normal(runs)
        meas = [(n, {"r": float(r[i]), "az": float(az[i]), "el": float(el[i]),
                     "sr": cfg.sr, "saz": cfg.sa, "sel": cfg.sa}) for i, n in enumerate(names)]
        yield k * T, meas, [(n, _truth(x[i, :3], x[i, 3:])) for i, n in enumerate(names)]


# ---------------------------------------------------------------- C: manoeuvring target
class ManeuverC:
    """Scenario C's 2-D trajectory (docs/scenarios.md, C: Xu & Wang, Journal of Xinxiang
    University 27(1), 2010): exact piecewise-constant accelerations."""

    start = (4000.0, 4000.0, -18.0, 0.0)
    # (from t, acceleration x, y)
    legs = ((0.0, 0.0, 0.0), (380.0, 0.075, 0.075), (600.0, 0.0, 0.0),
            (610.0, 0.3, -0.3), (660.0, 0.0, 0.0))
    phases = (("straight", 0.0, 380.0), ("slow turn", 380.0, 600.0),
              ("fast turn", 610.0, 660.0), ("straight-2", 660.0, 800.0))
    duration, period, sigma = 800.0, 2.0, 100.0

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at time t (exact integration)."""
        p, v = np.array(self.start[:2]), np.array(self.start[2:])
        ends = [leg[0] for leg in self.legs[1:]] + [math.inf]
        acc = np.zeros(2)
        for (t0, ax, ay), t1 in zip(self.legs, ends, strict=True):
            if t < t0:
                break
            acc = np.array([ax, ay])
            dt = min(t, t1) - t0
            p, v = p + v * dt + 0.5 * acc * dt**2, v + acc * dt
        return p, v, acc


def maneuver(runs: int = 1, seed: int = 0) -> Iterator[Scan]:
    """Scenario C: x and y measured independently, sigma 100 m, every 2 s to 800 s."""
    rng = np.random.default_rng(seed)
    c = ManeuverC()
    names = [f"maneuver-{i:03d}" for i in range(runs)]
    for k in range(int(c.duration / c.period) + 1):
        t = k * c.period
        p, v, a = c.state(t)
        z = p + c.sigma * rng.standard_normal((runs, 2))
        yield (t, [(n, {"pos": z[i].tolist(), "sigma": c.sigma}) for i, n in enumerate(names)],
               [(n, _truth(p, v, a)) for n in names])


# ---------------------------------------------------------------- swarm
def swarm(targets: int = 100, seed: int = 0, duration: float = 60.0,
          period: float = 1.0, sectors: int = 32) -> Iterator[Scan]:
    """Many straight-flying targets seen by a rotating 3-D radar at the origin.

    The beam turns once per `period` from North through East; each target is measured
    when the beam crosses its azimuth (its own `t`), and the reports of each of the
    `sectors` sectors of a turn go out together when the beam leaves the sector, as
    radars report by sector. sectors=1 gives one burst per turn.
    """
    for sent, s in swarm_sectors(targets, seed, duration, period, sectors):
        names, t, r, az, el, q, v = s.names, s.t, s.r, s.az, s.el, s.q, s.v
        sr, sa = s.sr, s.sa
        meas = [(names[i], {"t": float(t[j]), "r": float(r[j]), "az": float(az[j]),
                            "el": float(el[j]), "sr": sr, "saz": sa, "sel": sa})
                for j, i in enumerate(s.idx.tolist())]
        truth = [(names[i], {"t": float(t[j]), **_truth(q[j], v[j])})
                 for j, i in enumerate(s.idx.tolist())]
        yield sent, meas, truth


class Sector(NamedTuple):
    """One sector's reports of `swarm` as columns: target indices (in time order), their
    names, times, polar values, true positions and velocities, and the noise."""

    idx: np.ndarray
    names: list[str]
    t: np.ndarray
    r: np.ndarray
    az: np.ndarray
    el: np.ndarray
    q: np.ndarray
    v: np.ndarray
    sr: float
    sa: float


def swarm_sectors(targets: int = 100, seed: int = 0, duration: float = 60.0,
                  period: float = 1.0, sectors: int = 32) -> Iterator[tuple[float, Sector]]:
    """`swarm` as columns: (time the sector is sent, its reports), without a map per
    report (what a feed of 100,000 targets needs)."""
    rng = np.random.default_rng(seed)
    n = targets
    rho = rng.uniform(5_000, 80_000, n)
    bearing = rng.uniform(0, 2 * np.pi, n)
    p = np.stack([rho * np.sin(bearing), rho * np.cos(bearing), rng.uniform(500, 10_000, n)], 1)
    speed, heading = rng.uniform(50, 300, n), rng.uniform(0, 2 * np.pi, n)
    v = np.stack([speed * np.sin(heading), speed * np.cos(heading), np.zeros(n)], 1)
    sr, sa = 20.0, math.radians(0.2)
    names = [f"swarm-{i:05d}" for i in range(n)]
    width = 2 * np.pi / sectors
    for k in range(int(duration / period) + 1):
        q0 = p + v * (k * period)
        beam = np.mod(np.arctan2(q0[:, 0], q0[:, 1]), 2 * np.pi)  # azimuth at turn start
        sector = np.minimum((beam // width).astype(int), sectors - 1)
        t = k * period + beam / (2 * np.pi) * period  # when the beam crosses the target
        q = p + v * t[:, None]
        r = np.linalg.norm(q, axis=1) + sr * rng.standard_normal(n)
        az = np.arctan2(q[:, 0], q[:, 1]) + sa * rng.standard_normal(n)
        el = np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])) + sa * rng.standard_normal(n)
        order = np.argsort(sector, kind="stable")
        bounds = np.searchsorted(sector[order], np.arange(sectors + 1))
        for j in range(sectors):
            idx = order[bounds[j]:bounds[j + 1]]
            idx = idx[np.argsort(t[idx])]
            yield k * period + (j + 1) * period / sectors, Sector(
                idx, names, t[idx], r[idx], az[idx], el[idx], q[idx], v[idx], sr, sa)


SCENARIOS = {"display": display, "radar3d": radar3d, "maneuver": maneuver}
PERIODS = {"display": 1.0, "radar3d": 1.0, "maneuver": 2.0, "swarm": 1.0}
