"""The `manoeuvres` scenario (client side): aircraft flying the manoeuvres of real air
pictures, seen by one 3-D radar, as unlabelled scans or labelled measurements.

Classes (each aircraft flies straight for 60 s, manoeuvres, then flies straight to the
end, 200 s in all; its heading and first turn's direction are drawn from the seed):

- `straight`: 200 m/s, no manoeuvre;
- `standard-rate`: 200 m/s, 90 deg turns at 3 deg/s (about 1.07 g) right, then left;
- `4g`: 200 m/s, a 180 deg turn at 4 g, 40 s straight, a 90 deg reversal at 4 g;
- `7g-s`: 250 m/s, S-turns at 7 g: 90 deg one way, 180 deg the other, 90 deg back;
- `climbing`: 200 m/s, a 3 s pull-up at 1 g to 30 m/s of climb, a 270 deg turn at
  6 deg/s (2.1 g) climbing, a 3 s push-over.

Slow and tight flyers, on request (`SLOW_CLASSES`, not among the default `CLASSES`):

- `orbit`: 60 m/s, a survey or calibration orbit, 720 deg at 6 deg/s (0.64 g);
- `helicopter`: 40 m/s, 720 deg at 12 deg/s (0.85 g), 20 s straight, 360 deg back;
- `glider`: 30 m/s, thermalling: a 1 s pull-up to 2 m/s of climb, 1,800 deg at
  15 deg/s (0.8 g) climbing, a 1 s push-over.

Turns are coordinated (constant speed, the velocity turning at a constant rate: the
position in closed form). The manoeuvres of Blair et al.'s benchmark for radar tracking
(IEEE TAES 1998) reach 7 g; airliners turn at standard rate. The radar at the origin
measures range (`sr`, 30 m), azimuth from North clockwise and elevation (`sa`, 1.5 mrad
each); each aircraft is detected with probability `pd`; `clutter` false detections a
scan (Poisson) are uniform over the box that holds the trajectories. The aircraft are
placed around the radar at `distance` (36 km), each at its own altitude (800 m apart,
the climbing ones highest).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from zenoh_track.wire import pack

G = 9.80665
CLASSES = ("straight", "standard-rate", "4g", "7g-s", "climbing")
SLOW_CLASSES = ("orbit", "helicopter", "glider")
DURATION, LEAD = 200.0, 60.0  # s: the run, and the straight flight before any manoeuvre
# a leg: duration (s), turn rate (rad/s, + counter-clockwise), vertical acceleration (m/s^2)
Leg = tuple[float, float, float]


def legs(kind: str, sign: float) -> tuple[float, list[Leg]]:
    """Speed (m/s) and legs of a class, the last one straight; `sign` (+-1) the direction
    of its first turn."""
    speed, out = _legs(kind, sign)
    return speed, [*out, (DURATION, 0.0, 0.0)]


def _legs(kind: str, sign: float) -> tuple[float, list[Leg]]:
    rate3 = math.radians(3.0)
    if kind == "straight":
        return 200.0, []
    if kind == "standard-rate":
        return 200.0, [(LEAD, 0.0, 0.0), (30.0, sign * rate3, 0.0), (30.0, 0.0, 0.0),
                       (30.0, -sign * rate3, 0.0)]
    if kind == "4g":
        w = 4 * G / 200.0
        return 200.0, [(LEAD, 0.0, 0.0), (math.pi / w, sign * w, 0.0), (40.0, 0.0, 0.0),
                       (math.pi / 2 / w, -sign * w, 0.0)]
    if kind == "7g-s":
        w = 7 * G / 250.0
        q = math.pi / 2 / w
        return 250.0, [(LEAD, 0.0, 0.0), (q, sign * w, 0.0), (2 * q, -sign * w, 0.0),
                       (q, sign * w, 0.0)]
    if kind == "climbing":
        w = math.radians(6.0)
        return 200.0, [(LEAD, 0.0, 0.0), (3.0, 0.0, 10.0), (1.5 * math.pi / w, sign * w, 0.0),
                       (3.0, 0.0, -10.0)]
    if kind == "orbit":
        return 60.0, [(LEAD, 0.0, 0.0), (120.0, sign * math.radians(6.0), 0.0)]
    if kind == "helicopter":
        w = math.radians(12.0)
        return 40.0, [(LEAD, 0.0, 0.0), (60.0, sign * w, 0.0), (20.0, 0.0, 0.0),
                      (30.0, -sign * w, 0.0)]
    if kind == "glider":
        return 30.0, [(LEAD, 0.0, 0.0), (1.0, 0.0, 2.0), (120.0, sign * math.radians(15.0), 0.0),
                      (1.0, 0.0, -2.0)]
    raise ValueError(f"unknown class {kind!r}; one of {', '.join(CLASSES + SLOW_CLASSES)}")


@dataclass(frozen=True)
class Flight:
    """One aircraft: start position (3,), speed, initial heading (rad, counter-clockwise
    from East) and legs, flown from t = 0 (the last leg is extended to any t)."""

    name: str
    kind: str
    p0: np.ndarray
    speed: float
    heading: float
    legs: list[Leg]
    starts: list[tuple[float, complex, complex, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        t, w, v = 0.0, complex(self.p0[0], self.p0[1]), self.speed * np.exp(1j * self.heading)
        z, vz = float(self.p0[2]), 0.0
        for dur, om, az in self.legs:  # the state at the start of each leg
            self.starts.append((t, w, v, z, vz))
            w, v = _turn(w, v, om, dur)
            z, vz, t = z + vz * dur + 0.5 * az * dur**2, vz + az * dur, t + dur

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at t (exact)."""
        k = max(i for i, s in enumerate(self.starts) if s[0] <= t + 1e-9 or i == 0)
        t0, w, v, z, vz = self.starts[k]
        _, om, az = self.legs[k]
        h = t - t0
        w, v1 = _turn(w, v, om, h)
        a = 1j * om * v1
        return (np.array([w.real, w.imag, z + vz * h + 0.5 * az * h * h]),
                np.array([v1.real, v1.imag, vz + az * h]), np.array([a.real, a.imag, az]))

    def manoeuvring(self, t: float) -> bool:
        """Whether the aircraft accelerates at t (a turn, pull-up or push-over)."""
        return bool(np.any(self.state(t)[2] != 0.0))

    def leg_age(self, t: float) -> float:
        """Seconds since the current leg began (a turn, a reversal or a pull-up: an onset
        when the aircraft manoeuvres at t)."""
        return t - max((s[0] for s in self.starts if s[0] <= t + 1e-9), default=0.0)

    def quiet_for(self, t: float) -> float:
        """Seconds since the aircraft last accelerated (t itself if never)."""
        ends = [s[0] + d for s, (d, om, az) in zip(self.starts, self.legs, strict=True)
                if (om or az) and s[0] + d <= t]
        return t - max(ends) if ends else t


def _turn(w: complex, v: complex, om: float, h: float) -> tuple[complex, complex]:
    """Position and velocity (complex x + iy) after h s turning at om rad/s."""
    if om == 0.0:
        return w + v * h, v
    rot = np.exp(1j * om * h)
    return w + v * (rot - 1) / (1j * om), v * rot


def flights(seed: int, per_class: int = 2, classes: tuple[str, ...] = CLASSES,
            distance: float = 36_000.0) -> list[Flight]:
    """The aircraft of one run: `per_class` of each class, named `<class>-<k>`, each
    trajectory centred on a point `distance` from the radar (bearings spread evenly)."""
    rng = np.random.default_rng(seed)
    out, n = [], per_class * len(classes)
    order = sorted(classes, key=lambda c: c == "climbing")  # climbing ones highest
    for i in range(n):
        kind = order[i // per_class]
        speed, lg = legs(kind, float(rng.choice([-1.0, 1.0])))
        heading = float(rng.uniform(0, 2 * math.pi))
        probe = Flight("", kind, np.zeros(3), speed, heading, lg)
        path = np.array([probe.state(t)[0] for t in np.linspace(0, DURATION, 41)])
        mid = 0.5 * (path.min(0) + path.max(0))
        bearing = 2 * math.pi * (i + rng.uniform(0, 0.5)) / n
        centre = np.array([distance * math.sin(bearing), distance * math.cos(bearing),
                           2000.0 + 800.0 * i])
        p0 = centre - np.array([mid[0], mid[1], 0.0])
        out.append(Flight(f"{kind}-{i % per_class}", kind, p0, speed, heading, lg))
    return out


class Scan(NamedTuple):
    """One scan: time, sensor, sensor position, detections (K, 3) [r, az, el] shuffled,
    the truth {name: (pos, vel)} and each detection's origin (aircraft index, -1 clutter)."""

    t: float
    sensor: str
    sensor_pos: tuple[float, float, float]
    dets: np.ndarray
    truth: dict[str, tuple[np.ndarray, np.ndarray]]
    origin: np.ndarray


@dataclass
class Manoeuvres:
    """A run of the scenario: iterate it for its scans (the same ones every time)."""

    period: float = 1.0
    pd: float = 0.9
    clutter: float = 10.0
    per_class: int = 2
    seed: int = 0
    sr: float = 30.0
    sa: float = 1.5e-3
    sensor: str = "radar1"
    classes: tuple[str, ...] = CLASSES
    flights: list[Flight] = field(init=False)

    def __post_init__(self) -> None:
        self.flights = flights(self.seed, self.per_class, self.classes)
        pts = np.array([f.state(t)[0] for f in self.flights
                        for t in np.linspace(0, DURATION, 41)])
        self.box = (pts.min(0) - 2000.0, pts.max(0) + 2000.0)
        self.box[0][2] = max(self.box[0][2], 0.0)

    @property
    def dt(self) -> float:  # what track-feed reads of a plots scenario
        return self.period

    @property
    def times(self) -> np.ndarray:
        return np.arange(0.0, DURATION + 1e-9, self.period)

    @property
    def clutter_density(self) -> float:
        """False detections per m^3 per scan."""
        return self.clutter / float(np.prod(self.box[1] - self.box[0]))

    def __iter__(self) -> Iterator[Scan]:
        rng = np.random.default_rng(self.seed + 7919)
        for t in self.times.tolist():
            states = [f.state(t) for f in self.flights]
            pos = np.array([s[0] for s in states])
            seen = np.flatnonzero(rng.random(len(pos)) < self.pd)
            false = rng.uniform(self.box[0], self.box[1], (rng.poisson(self.clutter), 3))
            r, az, el = polar(np.vstack([pos[seen], false]))
            real = np.arange(len(r)) < len(seen)
            r = r + rng.normal(0.0, self.sr, len(r)) * real
            az = az + rng.normal(0.0, self.sa, len(r)) * real
            el = el + rng.normal(0.0, self.sa, len(r)) * real
            origin = np.concatenate([seen, np.full(len(false), -1)])
            order = rng.permutation(len(r))
            yield Scan(t, self.sensor, (0.0, 0.0, 0.0),
                       np.column_stack([r, az, el])[order],
                       {f.name: (s[0], s[1]) for f, s in zip(self.flights, states, strict=True)},
                       origin[order])

    def payload(self, scan: Scan, columnar: bool = False) -> bytes:
        """The scan as the MessagePack payload of `<ns>/plots/<sensor>` (docs/protocol.md
        §3.2): polar 3-D detections with this scenario's noise."""
        msg: dict = {"t": float(scan.t), "sensor_pos": list(scan.sensor_pos), "sr": self.sr,
                     "saz": self.sa, "sel": self.sa}
        dets = np.ascontiguousarray(scan.dets, dtype="<f8").reshape(-1, 3)
        if columnar:
            msg.update(r=dets[:, 0].tobytes(), az=dets[:, 1].tobytes(), el=dets[:, 2].tobytes())
        else:
            msg["dets"] = [{"r": r, "az": a, "el": e} for r, a, e in dets.tolist()]
        return pack(msg)

    def labelled(self) -> Iterator[tuple[float, list[tuple[str, dict]], list[tuple[str, dict]]]]:
        """The same detections of the aircraft as labelled measurements (no clutter), in
        the form of `zenoh_track.clients.feeds.scenarios` (t, [(target, measurement)], [(target,
                                                                                   truth)])."""
        names = [f.name for f in self.flights]
        for s in self:
            meas = [(names[o], {"r": float(d[0]), "az": float(d[1]), "el": float(d[2]),
                                "sr": self.sr, "saz": self.sa, "sel": self.sa})
                    for d, o in zip(s.dets.tolist(), s.origin.tolist(), strict=True) if o >= 0]
            truth = [(k, {"pos": p.tolist(), "vel": v.tolist()}) for k, (p, v) in s.truth.items()]
            yield s.t, meas, truth


def polar(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range, azimuth (from North, clockwise) and elevation of points (N, 3) seen from
    the origin."""
    ground = np.hypot(p[:, 0], p[:, 1])
    return np.hypot(ground, p[:, 2]), np.arctan2(p[:, 0], p[:, 1]), np.arctan2(p[:, 2], ground)
