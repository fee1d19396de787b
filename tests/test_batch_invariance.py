"""A track's published state does not depend on how its measurements were batched: a
lockstep service given the same inputs in other worker batches (a replay, another
machine's timing) publishes the same bits (service/estimation/batch.py)."""

from __future__ import annotations

import random

import numpy as np
import pytest
from reference.record import track

from zenoh_track import defaults
from zenoh_track.clients.feeds import scenarios
from zenoh_track.estimation.batch import einsum
from zenoh_track.estimation.catalog import FilterSpec
from zenoh_track.tracking.tracker import Tracker, TrackerConfig
from zenoh_track.wire import pack, parse_measurement


def swarm_measurements(targets: int = 12, duration: float = 8.0) -> list:
    out = []
    for t0, meas, _ in scenarios.swarm(targets, 0, duration, sectors=32):
        for target, m in meas:
            body = {"t": m.get("t", t0), **{k: v for k, v in m.items() if k != "t"}}
            out.append(parse_measurement("radar1", target, pack(body), defaults.NOISE))
    return out


def published(measurements: list, sizes, filter_name: str) -> list[bytes]:
    """The state and covariance bytes of each measurement's track after its update, the
    measurements applied in batches of the sizes drawn from `sizes`."""
    tracker = Tracker.from_config(TrackerConfig(filter=FilterSpec(filter_name)))
    out, i = [], 0
    while i < len(measurements):
        batch = measurements[i:i + sizes()]
        i += len(batch)
        outcomes, _ = track(tracker, batch)
        for o in outcomes:
            assert o.reason is None, o.reason
            k = o.states.ids.index(o.meas.target)
            out.append(np.asarray(o.states.x[k]).tobytes() + np.asarray(o.states.p[k]).tobytes())
    return out


@pytest.mark.parametrize("filter_name", ["imm", "cv", "ca"])
def test_states_are_bit_identical_whatever_the_batches(filter_name):
    ms = swarm_measurements()
    one = published(ms, lambda: 1, filter_name)
    rnd = random.Random(1)
    assert len(one) == len(ms)
    assert published(ms, lambda: 256, filter_name) == one
    assert published(ms, lambda: rnd.randint(1, 40), filter_name) == one


def test_einsum_of_one_row_takes_the_loop_of_many():
    """The case the helper exists for: NumPy's own einsum gave other last bits for a batch
    of one on this project's machine (x86-64 with FMA: the test above failed without the
    helper); the helper gives the bits of a longer batch."""
    rng = np.random.default_rng(1)
    cases = [("ijn,ajn->ain", (3, 3), (2, 3)), ("jkn,kn->jn", (3, 7), (7,))]
    for sub, sa, sb in cases:
        a, b = rng.normal(size=(*sa, 200)), rng.normal(size=(*sb, 200))
        full = np.einsum(sub, a, b)
        for n in range(200):
            row = (a[..., n:n + 1].copy(), b[..., n:n + 1].copy())
            assert (einsum(sub, *row) == full[..., n:n + 1]).all()
            out = np.empty_like(full[..., :1])
            assert einsum(sub, *row, out=out) is out and (out == full[..., n:n + 1]).all()
