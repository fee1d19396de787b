"""Each sensor's stated noise checked against what its measurements show (pure: columns
in, reports out, no Zenoh).

A feed that states its positions exact (`sigma` 0) or gives no sigma (the service's
default, 1 m) may jitter by tens of metres: recorded tracks, simulations that quantise or
correct their dead reckoning. Two statistics per sensor over a window of its latest
Cartesian measurements (docs/accuracy.md, "Exact positions"; docs/protocol.md, §4.3):

- the normalised innovation squared (NIS) of the updates, per axis: about 1 when the
  stated noise is right (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2);
- the jitter the positions themselves show, model-free: each track's new position
  against the quadratic through its previous three (for equal intervals the third
  difference, of variance 20 sigma^2 for white noise of sigma per axis; any intervals:
  (1 + sum of the squared Lagrange weights) sigma^2), robust to manoeuvres and jumps
  by taking the median (median of chi-square(1) = 0.455).

The residual is also split along the track (the direction of the velocity at the new
position, of the quadratic through the last two and the new one) and across it: a time
stamp that is not quite the position's own moves it along the track (`estimation.timing`),
so an along-track jitter beyond the across-track one is time noise, sigma_t^2 = (along -
across) / speed^2 (docs/timing.md). Its mean is winsorised, not a median: the heavy tails
of the time noise are most of its error, and only values far beyond them (a jump, a lost
track) are clipped. A sensor whose along-track jitter exceeds `ratio` x the position
noise in effect + `floor` and whose time noise so measured exceeds `ratio` x its stated
`sigma_t` (by the along-track metres it moves) + `floor` is reported likewise, and its
measurements are used with the measured `sigma_t` (and the across-track position noise)
until it states better; below that its timing is taken as stated (none: exact).

A sensor whose measured jitter exceeds `ratio` x its stated sigma + `floor` is reported
(`due`, at most once per `every` s of wall time, and in `status`) and, until it states
better, its Cartesian measurements are used with the measured sigma (`adjust`): the
track stays stable and smooths the jitter.
A sensor whose stated sigma exceeds `ratio` x the measured one + `floor` with a NIS per
axis below `nis_low` is reported in `status` only (too pessimistic: its tracks are merely
slower than they could be), its measurements used as stated.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .. import defaults
from ..estimation import models
from ..estimation.measurements import MeasurementBatch

CHI2_1_MEDIAN = 0.454936  # median of the chi-square distribution with one degree of freedom
# median of chi-square(k) / k: the across-track residual per axis of a d-D position (k = d - 1)
CHI2_MEDIAN_PER_DOF = {1: CHI2_1_MEDIAN, 2: 0.693147}
# the along-track mean clipped at WINSOR x its median-based variance (20 sigma of a
# Gaussian): a jump or a lost track bounded, the tails of the time noise kept. On the
# generated feed of docs/timing.md (Student t, 3 degrees of freedom, and repeats) 25 (5
# sigma) measured 0.10 s of its 0.15 s and left the display at 0.92 x linear
# extrapolation's error, 100 at 0.86 x, 400 at 0.83 x (bench/timing.py)
WINSOR = 400.0
MIN_SPEED = 10.0  # m/s: slower positions tell nothing of their time
# the store rows sampled for the statistics (a window of 300 needs few): all below
# FULL_ROWS, and one in STRIDE above, so that 100,000 tracks cost about 2,600 rows a pass
FULL_ROWS, STRIDE = 1024, 64


@functools.lru_cache(maxsize=256)
def hidden_error(order: int, dt: float, updates: int) -> np.ndarray:
    """Per axis and unit measurement variance, the error covariance (order, order) of a
    track of `order` started from one position and updated `updates` times, at the
    interval dt, taking its positions as exact (the gains at zero measurement variance,
    from the initiator's prior; whatever the process noise's density) while they have
    unit variance: e <- A e A' + K K', A = (I - K H) F (Bar-Shalom, Li & Kirubarajan
    2001, sec. 5.2). What such a track has in error beyond its covariance."""
    one = np.array([dt])
    f = models.transition(one, order, 1)[0]
    q = models.process_noise(one, order, 1, 1.0)[0]
    prior = [0.0, defaults.INIT_SPEED ** 2, defaults.INIT_ACCEL ** 2][:order]
    p = np.diag(prior)  # the filter's belief: the first position exact
    e = np.diag([1.0, *prior[1:]])  # the error: the first position's noise
    for _ in range(updates - 1):
        pp = f @ p @ f.T + q
        k = pp[:, :1] / (pp[0, 0] + 1e-300)
        p = pp - k @ pp[:1]
        a = f - k @ f[:1]  # (I - K H) F
        e = a @ e @ a.T + k @ k.T
    return e


@dataclass(frozen=True)
class NoiseReport:
    """One sensor whose stated noise is far from what its measurements show."""

    sensor: str
    stated: float  # m: stated sigma per axis (median over the window)
    measured: float  # m: the jitter its positions show, per axis
    nis: float  # mean NIS per axis over the window (1 when the stated noise is right)
    count: int  # position residuals in the window (one per axis and measurement)
    # time noise: stated sigma_t (median, 0 when none), measured (s; 0 unless `timing`),
    # the residual's RMS along the track and per axis across it (m)
    stated_t: float = 0.0
    measured_t: float = 0.0
    along: float = 0.0
    across: float = 0.0
    timing: bool = False  # the time noise is far beyond the stated one (and used)

    @property
    def too_small(self) -> bool:
        return self.timing or self.measured > self.stated

    def reason(self) -> str:
        used = " (used meanwhile)" if self.too_small else ""
        out = (f"stated sigma {self.stated:.3g} m, but its positions jitter by about "
               f"{self.measured:.3g} m per axis{used}: mean NIS per axis {self.nis:.3g} "
               f"over {self.count} residuals (1 if the stated sigma were right)")
        if self.timing:
            out += (f"; along the track they jitter by {self.along:.3g} m RMS against "
                    f"{self.across:.3g} m across it: their times are off by about "
                    f"{self.measured_t:.3g} s RMS (stated sigma_t {self.stated_t:.3g} s; "
                    f"used meanwhile)")
        return out

    def body(self) -> dict[str, float | int | str]:
        out: dict[str, float | int | str] = {
            "stated": self.stated, "measured": self.measured, "nis": self.nis,
            "count": self.count, "direction": "too small" if self.too_small else "too large"}
        if self.timing:
            out |= {"stated_t": self.stated_t, "measured_t": self.measured_t,
                    "along": self.along, "across": self.across}
        return out


@dataclass
class _Sensor:
    """A sensor's window: residuals (sigma^2 estimates per axis), NIS per axis, stated;
    per measurement the residual along the track and per axis across it (m^2), the
    squared speed and the stated sigma_t (NaN: none)."""

    window: int
    res: deque = field(init=False)
    nis: deque = field(init=False)
    stated: deque = field(init=False)
    along: deque = field(init=False)
    across: deque = field(init=False)
    speed2: deque = field(init=False)
    stated_t: deque = field(init=False)
    report: NoiseReport | None = None
    next_put: float = -math.inf  # wall time before which no new report goes out

    def __post_init__(self) -> None:
        self.res, self.nis, self.stated, self.along, self.across, self.speed2, \
            self.stated_t = (deque(maxlen=self.window) for _ in range(7))


class NoiseCheck:
    """Per-sensor NIS and measured jitter over a window of measurements (`observe`); the
    sensors far off (`status`, `due`) and the noise used for them (`adjust`)."""

    def __init__(self, window: int = defaults.NOISE_WINDOW,
                 min_count: int = defaults.NOISE_MIN_COUNT, ratio: float = defaults.NOISE_RATIO,
                 floor: float = defaults.NOISE_FLOOR,
                 nis_low: float = defaults.NOISE_NIS_LOW, every: float = defaults.NOISE_EVERY
                 ) -> None:
        self.window, self.min_count, self.ratio, self.floor = window, min_count, ratio, floor
        self.nis_low, self.every = nis_low, every
        self.sensors: dict[str, _Sensor] = {}
        # per layout (dimension): the last three Cartesian positions of each store row,
        # with the track id they belong to (a row is reused after a deletion)
        self.hist: dict[int, tuple[np.ndarray, ...]] = {}
        # per layout: the rows whose covariance took the measured noise in, and for which
        # track (`adjust`)
        self.inflated: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------ the filter's side
    def adjust(self, sensors: str | list[str], batch: MeasurementBatch, rows: np.ndarray,
               dt: np.ndarray, order: int, ids: list[str | None], updates: np.ndarray
               ) -> tuple[MeasurementBatch, np.ndarray, np.ndarray]:
        """`batch` with the measured sigma in place of a smaller stated one for the
        Cartesian rows of the sensors reported too small, and the measured sigma_t in
        place of a smaller (or no) stated one for every row of the sensors whose time
        noise is reported (the batch itself otherwise); and, for the store rows `rows`
        (of a state of `order`, dt since their last update; `ids`: the store's track id
        of every row) that get the measured sigma for the first time, which of them
        (index) and the covariance (k, n, n) to add to theirs: what the stated noise hid
        from them, sigma^2 x `hidden_error` per axis (`updates`: each row's updates so
        far)."""
        none = (batch, np.zeros(0, int), np.zeros((0, 0, 0)))
        reports = {s: r for s, r in self._reports().items() if r.too_small}
        if not reports or (isinstance(sensors, str) and sensors not in reports):
            return none
        names = [sensors] * len(batch) if isinstance(sensors, str) else sensors
        floor = np.array([reports[s].measured if s in reports else 0.0 for s in names])
        time = np.array([reports[s].measured_t if s in reports and reports[s].timing
                         else 0.0 for s in names])
        floor[batch.polar] = 0.0
        sig = np.maximum(batch.sigmas, floor[:, None])
        sigma_t = batch.sigma_t
        if time.any():
            sigma_t = np.fmax(time, np.nan if sigma_t is None else sigma_t)
            sigma_t[time == 0.0] = np.nan if batch.sigma_t is None else \
                batch.sigma_t[time == 0.0]
        out = dataclasses.replace(batch, sigmas=np.asfortranarray(sig), point=None,
                                  point_of=None, sigma_t=sigma_t)
        d = batch.dim
        cand = np.flatnonzero(floor > 0)
        done = self.inflated.get(d, np.zeros(0, object))  # row -> the track id inflated
        if len(ids) > len(done):
            done = self.inflated[d] = np.concatenate(
                [done, np.full(len(ids) - len(done), None, object)])
        now = np.array(ids, dtype=object)[rows[cand]]
        grow = cand[done[rows[cand]] != now]
        done[rows[grow]] = now[done[rows[cand]] != now]
        n = order * d
        dp = np.zeros((len(grow), n, n))
        for i, (v, h, u) in enumerate(zip((floor[grow] ** 2).tolist(), dt[grow].tolist(),
                                          updates[grow].tolist(), strict=True)):
            dp[i] = v * np.kron(hidden_error(order, round(max(abs(h), 1e-3), 6),
                                             int(min(max(u, 1), 60))), np.eye(d))
        return out, grow, dp

    def observe(self, sensors: str | list[str], ids: list[str | None], rows: np.ndarray,
                batch: MeasurementBatch, nis: np.ndarray, ok: np.ndarray) -> None:
        """Take in the updates of store rows `rows` of one layout (`ids`: the store's
        track id of every row) with the measurements `batch` (as stated) and their NIS
        (`ok`: the rows updated); the rows sampled (`FULL_ROWS`, `STRIDE`) only."""
        d, w = batch.dim, self.window
        pick = np.flatnonzero(~batch.polar & ok & ((rows < FULL_ROWS) | (rows % STRIDE == 0)))
        if not len(pick):
            return
        sub = rows[pick]
        res, along, across, speed2 = self._residuals(
            d, sub, [ids[r] for r in sub.tolist()], batch.t[pick], batch.values[pick])
        nis_d, stated = nis[pick] / d, batch.sigmas[pick].mean(1)
        stated_t = (np.full(len(pick), np.nan) if batch.sigma_t is None
                    else batch.sigma_t[pick])
        if isinstance(sensors, str):
            groups = [(sensors, slice(None))]
        else:
            names = np.array(sensors, dtype=object)[pick]
            groups = [(k, names == k) for k in sorted(set(names.tolist()))]
        for name, m in groups:
            s = self.sensors.get(name)
            if s is None:
                s = self.sensors[name] = _Sensor(w)
            s.nis.extend(nis_d[m][-w:].tolist())
            s.stated.extend(stated[m][-w:].tolist())
            r = res[m].ravel()
            s.res.extend(r[np.isfinite(r)][-w:].tolist())
            fin = np.isfinite(along[m])
            for q, col in ((s.along, along), (s.across, across), (s.speed2, speed2),
                           (s.stated_t, stated_t)):
                q.extend(col[m][fin][-w:].tolist())
            s.report = self._judge(name, s, d)

    def _residuals(self, d: int, rows: np.ndarray, ids: list[str | None], t: np.ndarray,
                   z: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per row and axis: the position z (k, d) at t against the quadratic through the
        row's previous three, squared, over (1 + the squared Lagrange weights) (NaN
        without three); per row the same residual's square along the track and per axis
        across it, and the squared speed (`_along`); the history moved on by the rows'
        new positions."""
        cap = int(rows.max()) + 1
        t_h, z_h, n_h, id_h = self.hist.get(d, (np.zeros((0, 3)), np.zeros((0, 3, d)),
                                               np.zeros(0, int), np.zeros(0, object)))
        if cap > len(n_h):  # grow (doubling)
            size, old = max(cap, 2 * len(n_h), 64), len(n_h)
            t_h = np.concatenate([t_h, np.zeros((size - old, 3))])
            z_h = np.concatenate([z_h, np.zeros((size - old, 3, d))])
            id_h = np.concatenate([id_h, np.full(size - old, None, object)])
            n_h = np.concatenate([n_h, np.zeros(size - old, int)])
            self.hist[d] = t_h, z_h, n_h, id_h
        name = np.array(ids, dtype=object)
        same = id_h[rows] == name
        n_h[rows] = np.where(same, n_h[rows], 0)
        out = np.full((len(rows), d), np.nan)
        along, across, speed2 = (np.full(len(rows), np.nan) for _ in range(3))
        full = n_h[rows] >= 3
        if full.any():
            tt, zz, t0 = t_h[rows[full]], z_h[rows[full]], t[full]
            lag = np.ones((len(t0), 3))  # Lagrange weights at t0 of the three points
            for i in range(3):
                for j in range(3):
                    if i != j:
                        den = tt[:, i] - tt[:, j]
                        lag[:, i] *= np.where(den != 0, (t0 - tt[:, j])
                                              / np.where(den != 0, den, 1.0), np.nan)
            pred = np.einsum("ni,nid->nd", lag, zz)
            gain = 1.0 + (lag ** 2).sum(1)
            err = (z[full] - pred) / np.sqrt(gain)[:, None]
            out[full] = err ** 2
            along[full], across[full], speed2[full] = _along(err, tt, zz, t0, z[full])
        # shift: the oldest out, the new position in
        t_h[rows, :2], z_h[rows, :2] = t_h[rows, 1:], z_h[rows, 1:]
        t_h[rows, 2], z_h[rows, 2] = t, z
        n_h[rows] += 1
        id_h[rows] = name
        return out, along, across, speed2

    def _judge(self, name: str, s: _Sensor, d: int) -> NoiseReport | None:
        """The sensor's report if its stated noise (or timing) is far off, None otherwise."""
        if len(s.res) < self.min_count:
            return None
        measured = math.sqrt(float(np.median(np.fromiter(s.res, float))) / CHI2_1_MEDIAN)
        stated = float(np.median(np.fromiter(s.stated, float)))
        nis = float(np.mean(np.fromiter(s.nis, float)))
        report = NoiseReport(name, stated, measured, nis, len(s.res))
        timed = self._timing(s, d, stated)
        if timed is not None:  # the position noise is the across-track one
            report = dataclasses.replace(report, measured=timed[3], stated_t=timed[0],
                                         measured_t=timed[1], along=timed[2],
                                         across=timed[3], timing=True)
            return report
        # too small: the jitter alone decides. The NIS cannot: an adaptive filter (the
        # IMM's manoeuvre modes) takes jitter for manoeuvres and widens its prediction
        # until the NIS is about 1 (docs/accuracy.md, "Exact positions"), and once the
        # measured sigma is used the NIS falls back toward 1 anyway
        if measured > self.ratio * stated + self.floor:
            return report
        if stated > self.ratio * measured + self.floor and nis < self.nis_low:
            return report
        return None

    def _timing(self, s: _Sensor, d: int, stated: float
                ) -> tuple[float, float, float, float] | None:
        """(stated sigma_t, measured sigma_t, along-track RMS, across-track RMS per axis)
        of a sensor whose along-track jitter is far beyond its position noise and whose
        time noise is far beyond the stated one (module docstring); None otherwise."""
        if len(s.along) < self.min_count // d:
            return None
        along, across = np.fromiter(s.along, float), np.fromiter(s.across, float)
        speed2 = np.fromiter(s.speed2, float)
        across_ms = float(np.median(across)) / CHI2_MEDIAN_PER_DOF[d - 1]
        along_ms = float(np.mean(_winsorised(along)))
        position2 = max(across_ms, stated ** 2)
        if math.sqrt(along_ms) <= self.ratio * math.sqrt(position2) + self.floor:
            return None
        fast = speed2 >= MIN_SPEED ** 2
        if not fast.any():
            return None
        # the time noise: (along - position noise) / speed^2, per measurement
        time2 = _winsorised(along[fast] / speed2[fast]) - position2 / speed2[fast]
        sigma_t = math.sqrt(max(float(np.mean(time2)), 0.0))
        stated_t = float(np.median(np.nan_to_num(np.fromiter(s.stated_t, float), nan=0.0)))
        speed = math.sqrt(float(np.mean(speed2[fast])))
        if sigma_t * speed <= self.ratio * stated_t * speed + self.floor:
            return None
        return stated_t, sigma_t, math.sqrt(along_ms), math.sqrt(across_ms)

    # ------------------------------------------------------------ the adapter's side
    def _reports(self) -> dict[str, NoiseReport]:
        return {k: s.report for k, s in self.sensors.items() if s.report is not None}

    def status(self) -> dict[str, dict]:
        """The sensors whose stated noise is far off (the `status` field `sensor_noise`)."""
        return {k: r.body() for k, r in sorted(self._reports().items())}

    def due(self, wall: float) -> list[NoiseReport]:
        """The reports to publish now (wall-clock time `wall`): each sensor whose stated
        noise is far too small (the claim that harms its tracks; one far too large is in
        `status` only), at most once per `every` s."""
        out = []
        for s in self.sensors.values():
            if s.report is not None and s.report.too_small and wall >= s.next_put:
                s.next_put = wall + self.every
                out.append(s.report)
        return out


def _winsorised(x: np.ndarray) -> np.ndarray:
    """x (squared residuals) clipped at `WINSOR` x their median-based variance: the tails
    kept, a jump or a lost track's residual bounded."""
    return np.minimum(x, WINSOR * float(np.median(x)) / CHI2_1_MEDIAN)


def _along(err: np.ndarray, tt: np.ndarray, zz: np.ndarray, t0: np.ndarray, z: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: the residual err (k, d) squared along the track and per axis across it,
    and the squared speed. The direction: the velocity at t0 of the quadratic through
    the last two positions zz[:, 1:] (at tt[:, 1:]) and the new one z (its time errors
    lie along the track and leave the direction); the speed over the four positions'
    span (the least disturbed by them)."""
    t1, t2 = tt[:, 1], tt[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        w1 = (t0 - t2) / ((t1 - t2) * (t1 - t0))
        w2 = (t0 - t1) / ((t2 - t1) * (t2 - t0))
        w0 = (2 * t0 - t1 - t2) / ((t0 - t1) * (t0 - t2))
        vel = w1[:, None] * zz[:, 1] + w2[:, None] * zz[:, 2] + w0[:, None] * z
        u = vel / np.linalg.norm(vel, axis=1, keepdims=True)
        speed2 = np.sum((z - zz[:, 0]) ** 2, 1) / (t0 - tt[:, 0]) ** 2
    along = np.sum(err * u, 1) ** 2
    across = (np.sum(err ** 2, 1) - along) / (err.shape[1] - 1)
    bad = ~(np.isfinite(along) & np.isfinite(speed2))
    along[bad], across[bad], speed2[bad] = np.nan, np.nan, np.nan
    return along, across, speed2
