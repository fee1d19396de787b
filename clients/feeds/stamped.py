"""Positions whose time is not quite theirs: the 1 Hz feed of a surveillance network.

Aircraft at 80-300 m/s fly straight and turn (1.5-3 deg/s, the standard rate), climb,
descend and change speed; each second the feed sends a position stamped with the whole
second, but the position is of another instant (docs/timing.md):

- jitter: a Student t with 3 degrees of freedom (heavy tails: the 99th percentile about
  2.5 x the RMS), clipped at 1.5 s;
- quantisation: the position is the source's latest sample at 4 Hz nearest that instant
  (a uniform error of +-0.125 s);
- repeats: now and then the previous position is sent again under the new time.

The time error's RMS is drawn per aircraft (`time_noise`, s, all three together), the
positions get a little noise of their own (`pos_noise`, m per axis) and are rounded to
1 m. `generate` returns what the feed sends, the truth at the stamped times, the RMS of
each aircraft's time error (what a feed that knows its timing states as `sigma_t`) and
where the aircraft turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SUB = 10  # Hz: the paths integrated at this rate, interpolated between
SOURCE_RATE = 4.0  # Hz: the source's samples, the time quantised to the nearest
REPEAT = 0.005  # probability that a position is the previous one sent again
TURN_RATE = (1.5, 3.0)  # deg/s
CLIP = 1.5  # s: the jitter's largest magnitude
LEGS = (0.3, 0.5, 0.1, 0.1)  # probabilities of a leg: straight, turn, climb, speed change


@dataclass(frozen=True)
class StampedFeed:
    """One generated feed: N aircraft, K seconds."""

    ts: np.ndarray  # (K,) s: the stamped times
    pos: np.ndarray  # (N, K, 3) m: what the feed sends
    truth: np.ndarray  # (N, K, 3) m: the true positions at the stamped times
    sigma_t: np.ndarray  # (N,) s: RMS of each aircraft's time error
    turning: np.ndarray  # (N, K) bool: turning at more than 0.5 deg/s
    vel: np.ndarray  # (N, K, 3) m/s: the true velocity at the stamped times


def paths(n: int, duration: float, rng: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Times (M,) at `SUB` Hz, positions and velocities (n, M, 3), turn rates (n, M) rad/s
    of n aircraft: legs of 10-60 s, straight, turning, climbing or descending, or
    changing speed (a turn one leg in two)."""
    h = 1.0 / SUB
    steps = int(round(duration * SUB)) + 1
    pos = np.column_stack([rng.uniform(-50e3, 50e3, (n, 2)), rng.uniform(2e3, 10e3, n)])
    speed, heading = rng.uniform(80, 300, n), rng.uniform(-np.pi, np.pi, n)
    climb, turn, accel, vz = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    change = rng.uniform(0, 30, n)
    out, vel, rate = np.empty((n, steps, 3)), np.empty((n, steps, 3)), np.empty((n, steps))
    for i in range(steps):
        t = i * h
        due = t >= change
        if due.any():  # a new leg
            k = int(due.sum())
            kind = rng.choice(4, k, p=LEGS)
            sign = rng.choice([-1.0, 1.0], k)
            turn[due] = np.where(kind == 1, sign * np.radians(rng.uniform(*TURN_RATE, k)), 0.0)
            vz[due] = np.where(kind == 2, rng.uniform(-15, 15, k), 0.0)
            accel[due] = np.where(kind == 3, rng.uniform(-2, 2, k), 0.0)
            change[due] = t + rng.uniform(10, 60, k)
        v = np.column_stack([speed * np.cos(heading), speed * np.sin(heading), climb])
        out[:, i], vel[:, i], rate[:, i] = pos, v, turn
        climb += (vz - climb) * h / 5.0  # eased in over about 5 s
        speed = np.clip(speed + accel * h, 80, 300)
        heading += turn * h
        pos = pos + h * v
    return np.arange(steps) * h, out, vel, rate


def _at(times: np.ndarray, grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """values (n, M, 3) on the regular grid, linearly interpolated at times (n, K)."""
    h = grid[1] - grid[0]
    f = np.clip((times - grid[0]) / h, 0, len(grid) - 1 - 1e-9)
    i = f.astype(int)
    w = (f - i)[..., None]
    rows = np.arange(values.shape[0])[:, None]
    return values[rows, i] * (1 - w) + values[rows, i + 1] * w


def generate(aircraft: int = 50, runs: int = 1, seed: int = 0, duration: float = 300.0,
             time_noise: tuple[float, float] = (0.1, 0.2),
             pos_noise: tuple[float, float] = (1.0, 3.0), repeat: float = REPEAT,
             dof: int = 3) -> StampedFeed:
    """`aircraft` x `runs` aircraft, one position a second for `duration` s (module
    docstring; `dof`: the jitter's degrees of freedom, 0 for a Gaussian one)."""
    rng = np.random.default_rng(seed)
    n = aircraft * runs
    grid, pos, vel, rate = paths(n, duration + 2 * CLIP + 1.0, rng)
    grid = grid - CLIP - 0.5  # the stamped times start at 0, the paths before them
    ts = np.arange(0.0, duration + 1e-9, 1.0)
    k = len(ts)
    rms = rng.uniform(*time_noise, n)
    quant = 1.0 / SOURCE_RATE
    # the jitter's own share of the RMS: the rest is the quantisation's and the repeats'
    share = np.sqrt(np.maximum(rms ** 2 - quant ** 2 / 12 - repeat, 1e-6))
    unit = (rng.standard_t(dof, (n, k)) / np.sqrt(dof / (dof - 2.0)) if dof
            else rng.standard_normal((n, k)))
    jitter = np.clip(share[:, None] * unit, -CLIP, CLIP)
    true_t = np.round((ts + jitter) / quant) * quant
    for j in range(1, k):  # repeats: the previous position under the new time
        again = rng.random(n) < repeat
        true_t[again, j] = true_t[again, j - 1]
    noise = rng.uniform(*pos_noise, n)[:, None, None] * rng.standard_normal((n, k, 3))
    sent = np.round(_at(true_t, grid, pos) + noise)
    stamped = np.broadcast_to(ts, (n, k))
    i = np.clip(np.round((stamped - grid[0]) * SUB).astype(int), 0, len(grid) - 1)
    rows = np.arange(n)[:, None]
    turning = np.abs(rate[rows, i]) > np.radians(0.5)
    return StampedFeed(ts, sent, _at(stamped, grid, pos), rms, turning, vel[rows, i])
