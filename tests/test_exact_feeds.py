"""Jittered 1 Hz positions stated exact, through the real service on loopback (lockstep):
a smooth path with turns, climbs and speed changes plus 10-30 m of noise per axis,
quantised to 1 m, with a 50 m dead-reckoning snap now and then
(`zenoh_track.clients.evaluation.heldout`, the held-out measure of `track-eval heldout`):
every other position sent with `sigma` 0 (and without sigma), the frame 1 s later scored
against the position held out. The service must stay stable (no error growing like a
random walk, as the piecewise-constant noise model's undamped oscillation did: 8 x linear
extrapolation's error on a real feed) and be at least as good as linear extrapolation from
the last two positions."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_track.clients.evaluation import heldout as held

pytestmark = pytest.mark.slow
AIRCRAFT = 500


@pytest.fixture(scope="module")
def feed() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # 500 aircraft in each pass: the noise check's window fills within one pass, after
    # the IMM has taken the jitter for manoeuvres (a check that also asked for a high
    # NIS never reported such a sensor: 1.05 x linear's RMS; 20 aircraft did not show it)
    ts, pos, _ = held.generate(aircraft=AIRCRAFT, runs=1, seed=0, duration=120.0)
    return ts, pos, held.linear(ts, pos)


def errors(pred: np.ndarray, pos: np.ndarray, ts: np.ndarray, t0: float, t1: float
           ) -> np.ndarray:
    sel = np.zeros(len(ts), bool)
    sel[1::2] = True
    sel &= (ts >= t0) & (ts < t1)
    return np.linalg.norm(pred[:, sel] - pos[:, sel], axis=-1).ravel()


@pytest.mark.parametrize("sigma", [0.0, None])
def test_jittered_positions_stated_exact_stay_stable(feed, sigma):
    ts, pos, lin = feed
    got = held.run_service(ts, pos, sigma, [])
    e, e_lin = errors(got, pos, ts, 10.0, 121.0), errors(lin, pos, ts, 10.0, 121.0)
    assert np.isfinite(e).all() and len(e) == AIRCRAFT * 55  # every held-out instant drawn
    rms, rms_lin = np.sqrt(np.mean(e ** 2)), np.sqrt(np.mean(e_lin ** 2))
    # the target (docs/accuracy.md, "Exact positions"): 0.8 x linear's RMS. Measured
    # (`track-eval heldout --runs 1 --aircraft 500 --duration 120`): sigma 0 and absent
    # 0.74 x; the piecewise model 5.8 x
    rms_ratio = 0.8
    assert rms <= rms_ratio * rms_lin
    assert np.percentile(e, 95) <= np.percentile(e_lin, 95)
    # stable: the last 40 s no worse against linear extrapolation than the whole
    late, late_lin = errors(got, pos, ts, 80.0, 121.0), errors(lin, pos, ts, 80.0, 121.0)
    assert np.sqrt(np.mean(late ** 2)) <= 1.1 * rms_ratio * np.sqrt(np.mean(late_lin ** 2))
