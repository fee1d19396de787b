"""Unlabelled radar scans (`<ns>/plots/<sensor>`) of synthetic scenarios, for tests and
benchmarks of data association.

Each scenario is deterministic from its seed and is iterated as scans
`Scan(t, sensor, sensor_pos, dets, truth)`: `dets` a (K, d) array of the scan's detections
in shuffled order (targets detected with probability `pd`, plus clutter), `truth` a dict
target id -> (pos, vel) of every target at `t`. The clutter of a scan is Poisson with mean
`clutter`, uniform over the surveillance region, the square |x|, |y| <= `half_width`
(its density, `Scenario.clutter_density`, is `clutter / area`), which holds every
trajectory. The standard model of the literature (Bar-Shalom, Willett & Tian, "Tracking
and Data Fusion", 2011, ch. 2: Poisson clutter, uniform in the surveillance volume).

- `crossing`: N straight flyers whose lines pass within `miss` m of the origin around the
  middle scan; Cartesian 2-D detections with Gaussian noise `sigma` per axis.
- `multisensor`: the crossing targets seen by 2-3 radars at different positions, each with
  its own scan phase; polar 2-D detections (range, azimuth from North clockwise,
  x = r sin az, y = r cos az relative to the radar), noise `sr`, `saz`.
- `swarm_plots`: thousands of straight flyers plus clutter, Cartesian, for load tests.

`payload` turns one scan into the MessagePack payload of `<ns>/plots/<sensor>`
(docs/protocol.md §3.2), as a list of maps (`dets`) or in columnar form (bins of
little-endian float64); `zenoh_track.wire.parse_plots` reads both.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from zenoh_track.wire import pack

Truth = dict[str, tuple[np.ndarray, np.ndarray]]


class Scan(NamedTuple):
    """One scan of one sensor: its time, name, position, detections and the truth."""

    t: float
    sensor: str
    sensor_pos: tuple[float, float, float]
    dets: np.ndarray  # (K, 2): [x, y] (Cartesian) or [r, az] (polar)
    truth: Truth  # target id -> (pos (2,), vel (2,)) at t


@dataclass(frozen=True)
class Flyers:
    """Straight constant-velocity trajectories: position p0 + v (t - t0)."""

    ids: list[str]
    p0: np.ndarray  # (N, 2) m, at t0
    v: np.ndarray  # (N, 2) m/s
    t0: float = 0.0

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.p0 + self.v * (t - self.t0), self.v

    def truth(self, t: float) -> Truth:
        pos, vel = self.at(t)
        return {k: (pos[i], vel[i]) for i, k in enumerate(self.ids)}


@dataclass(frozen=True)
class Radar:
    """One sensor: name, position, the time of its first scan (its phase), and whether it
    measures (r, az) (polar) or (x, y)."""

    name: str
    pos: tuple[float, float, float]
    phase: float = 0.0
    polar: bool = False


@dataclass
class Scenario:
    """A generated scenario: iterate it for its scans (the same ones every time);
    `labelled()` also gives the origin of each detection (target index, -1 clutter)."""

    flyers: Flyers
    radars: list[Radar]
    scans: int  # per radar
    dt: float  # s: the scan period of every radar
    pd: float
    clutter: float  # mean number of false detections per scan of one radar
    half_width: float  # m: the surveillance region is |x|, |y| <= half_width
    sigma: float = 25.0  # m: Cartesian noise per axis
    sr: float = 25.0  # m: polar range noise
    saz: float = 0.002  # rad: polar azimuth noise
    seed: int = 0

    @property
    def area(self) -> float:
        """m^2 of the surveillance region."""
        return (2 * self.half_width) ** 2

    @property
    def clutter_density(self) -> float:
        """The true clutter density, false detections per m^2 per scan of one radar."""
        return self.clutter / self.area

    def __iter__(self) -> Iterator[Scan]:
        for scan, _ in self.labelled():
            yield scan

    def labelled(self) -> Iterator[tuple[Scan, np.ndarray]]:
        """Each scan and the origin of each of its detections: the index of the target
        (into `flyers.ids`) or -1 for clutter."""
        rng = np.random.default_rng(self.seed + 7919)  # the flyers used the seed itself
        times = [(r.phase + k * self.dt, n) for k in range(self.scans)
                 for n, r in enumerate(self.radars)]
        for t, n in sorted(times):
            radar = self.radars[n]
            pos, _ = self.flyers.at(t)
            seen = np.flatnonzero(rng.random(len(pos)) < self.pd)
            false = rng.uniform(-self.half_width, self.half_width,
                                (rng.poisson(self.clutter), 2))
            points = np.vstack([pos[seen], false])
            origin = np.concatenate([seen, np.full(len(false), -1)])
            dets = measure(rng, points, origin >= 0, radar, self.sigma, self.sr, self.saz)
            order = rng.permutation(len(dets))
            yield (Scan(t, radar.name, radar.pos, dets[order], self.flyers.truth(t)),
                   origin[order])

    def payload(self, scan: Scan, columnar: bool = False) -> bytes:
        """The scan as the MessagePack payload of `<ns>/plots/<sensor>`, with this
        scenario's noise."""
        radar = next(r for r in self.radars if r.name == scan.sensor)
        if radar.polar:
            return payload(scan, columnar, sr=self.sr, saz=self.saz)
        return payload(scan, columnar, sigma=self.sigma)


def measure(rng: np.random.Generator, points: np.ndarray, real: np.ndarray, radar: Radar,
            sigma: float, sr: float, saz: float) -> np.ndarray:
    """Noisy detections of Cartesian `points` (N, 2) by `radar`: [x, y] + N(0, sigma^2 I)
    or [r, az] + N(0, diag(sr^2, saz^2)). Clutter (`real` False) is a uniform point taken
    as it is, without noise."""
    if not radar.polar:
        return points + rng.normal(0.0, sigma, points.shape) * real[:, None]
    r, az = to_polar(points, radar.pos)
    noise = rng.normal(0.0, 1.0, (len(points), 2)) * real[:, None] * [sr, saz]
    return np.column_stack([np.abs(r + noise[:, 0]), az + noise[:, 1]])


def to_polar(points: np.ndarray, sensor_pos: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(r, az) of Cartesian points (N, 2) seen from sensor_pos; az from North, clockwise."""
    dx, dy = points[:, 0] - sensor_pos[0], points[:, 1] - sensor_pos[1]
    return np.hypot(dx, dy), np.arctan2(dx, dy)


def to_cartesian(dets: np.ndarray, sensor_pos: tuple[float, ...]) -> np.ndarray:
    """Cartesian points (N, 2) of polar detections [r, az]: x = r sin az, y = r cos az,
    relative to sensor_pos."""
    r, az = dets[:, 0], dets[:, 1]
    return np.column_stack([sensor_pos[0] + r * np.sin(az), sensor_pos[1] + r * np.cos(az)])


# ---------------------------------------------------------------- trajectories
def crossing_flyers(targets: int, scans: int, dt: float, speed: tuple[float, float],
                    miss: float, rng: np.random.Generator) -> Flyers:
    """`targets` straight lines through points within `miss` m of the origin, each
    passing it within a scan of the middle scan, headings uniform, speeds uniform in
    `speed`."""
    heading = rng.uniform(0.0, 2 * math.pi, targets)
    v = rng.uniform(*speed, targets)[:, None] * np.column_stack([np.sin(heading),
                                                                 np.cos(heading)])
    rho, phi = miss * np.sqrt(rng.random(targets)), rng.uniform(0.0, 2 * math.pi, targets)
    closest = rho[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])
    t_cross = dt * (scans // 2 + rng.uniform(-1.0, 1.0, targets))
    return Flyers([f"t{i}" for i in range(targets)], closest - v * t_cross[:, None], v)


def _region(flyers: Flyers, t_end: float, margin: float, half_width: float | None) -> float:
    """The half-width of the surveillance square: the given one, checked to hold every
    trajectory between 0 and t_end plus `margin`, or (None) the smallest multiple of
    500 m that does, at least 10 km."""
    ends = np.vstack([flyers.at(0.0)[0], flyers.at(t_end)[0]])
    need = float(np.abs(ends).max()) + margin if len(ends) else 0.0
    if half_width is None:
        return max(500.0 * math.ceil(need / 500.0), 10_000.0)
    if half_width < need:
        raise ValueError(f"half_width {half_width:.0f} m does not hold the trajectories "
                         f"(they need {need:.0f} m)")
    return half_width


# ---------------------------------------------------------------- the scenarios
def crossing(targets: int = 20, pd: float = 0.9, clutter: float = 20.0, sigma: float = 25.0,
             scans: int = 100, dt: float = 1.0, speed: tuple[float, float] = (100.0, 250.0),
             half_width: float | None = None, miss: float = 200.0, seed: int = 0,
             sensor: str = "radar1") -> Scenario:
    """N targets on straight lines crossing near the origin around the middle scan, seen
    by one Cartesian sensor at the origin. `half_width` None: the smallest square (at
    least 10 km, in steps of 500 m) that holds every trajectory (12.5 km for the
    defaults at 250 m/s); a given one that does not hold them raises ValueError."""
    rng = np.random.default_rng(seed)
    flyers = crossing_flyers(targets, scans, dt, speed, miss, rng)
    hw = _region(flyers, dt * (scans - 1), 3 * sigma, half_width)
    return Scenario(flyers, [Radar(sensor, (0.0, 0.0, 0.0))], scans, dt, pd, clutter, hw,
                    sigma=sigma, seed=seed)


def multisensor(targets: int = 20, radars: int = 3, pd: float = 0.9, clutter: float = 20.0,
                sr: float = 25.0, saz: float = 0.002, scans: int = 100, dt: float = 1.0,
                speed: tuple[float, float] = (100.0, 250.0), half_width: float | None = None,
                miss: float = 200.0, distance: float = 20_000.0, seed: int = 0) -> Scenario:
    """The crossing targets seen by `radars` (2 or 3) polar radars on a circle of radius
    `distance` around the origin (the first to the South-West, the others spread evenly),
    radar k scanning at k dt / radars + n dt (its phase). Clutter per radar, uniform over
    the Cartesian region (the same density for every radar)."""
    if radars not in (2, 3):
        raise ValueError(f"radars must be 2 or 3, got {radars}")
    rng = np.random.default_rng(seed)
    flyers = crossing_flyers(targets, scans, dt, speed, miss, rng)
    hw = _region(flyers, dt * scans, 3 * sr, half_width)
    sites = []
    for k in range(radars):
        bearing = math.radians(225.0) + 2 * math.pi * k / radars
        pos = (distance * math.sin(bearing), distance * math.cos(bearing), 0.0)
        sites.append(Radar(f"radar{k + 1}", pos, phase=k * dt / radars, polar=True))
    return Scenario(flyers, sites, scans, dt, pd, clutter, hw, sr=sr, saz=saz, seed=seed)


def swarm_plots(targets: int = 2000, clutter: float = 2000.0, pd: float = 0.9,
                sigma: float = 25.0, scans: int = 10, dt: float = 1.0,
                speed: tuple[float, float] = (100.0, 250.0), half_width: float = 100_000.0,
                seed: int = 0, sensor: str = "radar1") -> Scenario:
    """Thousands of straight flyers, uniform over the central part of the region (kept
    inside for the whole run), headings uniform, plus clutter: a Cartesian load test."""
    rng = np.random.default_rng(seed)
    inner = half_width - speed[1] * dt * scans - 3 * sigma
    if inner <= 0:
        raise ValueError("half_width too small for the run's length")
    heading = rng.uniform(0.0, 2 * math.pi, targets)
    v = rng.uniform(*speed, targets)[:, None] * np.column_stack([np.sin(heading),
                                                                 np.cos(heading)])
    flyers = Flyers([f"t{i}" for i in range(targets)],
                    rng.uniform(-inner, inner, (targets, 2)), v)
    return Scenario(flyers, [Radar(sensor, (0.0, 0.0, 0.0))], scans, dt, pd, clutter,
                    half_width, sigma=sigma, seed=seed)


# ---------------------------------------------------------------- the wire
def payload(scan: Scan, columnar: bool = False, *, sigma: float | None = None,
            sr: float | None = None, saz: float | None = None) -> bytes:
    """One scan as the `<ns>/plots/<sensor>` MessagePack payload: Cartesian with `sigma`
    (`{t, sensor_pos, sigma, dets: [{pos}]}`, columnar `{..., dim: 2, pos: bin}` of the
    rows), or polar with `sr` and `saz` (`{t, sensor_pos, sr, saz, dets: [{r, az}]}`,
    columnar `r` and `az` bins). Bins are little-endian float64, row-major."""
    polar = sigma is None
    if polar and (sr is None or saz is None):
        raise ValueError("give sigma (Cartesian) or sr and saz (polar)")
    dets = np.ascontiguousarray(scan.dets, dtype="<f8").reshape(-1, 2)
    msg: dict = {"t": float(scan.t), "sensor_pos": [float(v) for v in scan.sensor_pos]}
    if polar:
        msg["sr"], msg["saz"] = float(sr), float(saz)  # type: ignore[arg-type]
        if columnar:
            msg["r"], msg["az"] = dets[:, 0].tobytes(), dets[:, 1].tobytes()
        else:
            msg["dets"] = [{"r": r, "az": az} for r, az in dets.tolist()]
    else:
        msg["sigma"] = float(sigma)  # type: ignore[arg-type]
        if columnar:
            msg["dim"], msg["pos"] = 2, dets.tobytes()
        else:
            msg["dets"] = [{"pos": p} for p in dets.tolist()]
    return pack(msg)
