"""Generated inputs, valid and invalid, against the running service (a real process,
real Zenoh on loopback, lockstep clock), beside a good feed (docs/robustness.md).

Each example is one second of simulation time: the good feed's four measurements, up to
eight generated messages (tests/payloads.py: labelled measurements, unlabelled scans,
batched labelled scans, clock messages, each valid or broken in one way), a clock
message, a `status` query. Checked
after every example: `meas_accepted` grew by exactly the measurements and detections the
contract says are valid, `meas_rejected` by exactly the others, `rejected_by_reason`
sums to `meas_rejected` with no code `other`, every rejection came on `errors/` with the
input's key and the expected code, every valid labelled measurement published its
`tracks/`. At the end: the good tracks equal, to 1e-9, a tracker in this process fed the
good measurements alone; the frames ran without a gap; the service answers `status`.

ROBUST_EXAMPLES (default 300) sets the number of examples; bench/bench_robustness.py
runs many more.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections import Counter, defaultdict

import numpy as np
import pytest
import zenoh
from conftest import client_session
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from payloads import KEYS, Sent, batched, clock, labelled, scan
from reference.record import track

from zenoh_track.__main__ import parser, tracker_config
from zenoh_track.clients import ServiceProcess
from zenoh_track.tracking.tracker import Tracker
from zenoh_track.wire import Measurement, free_port, pack, unpack, wait_for_tracker

pytestmark = pytest.mark.slow

EXAMPLES = int(os.environ.get("ROBUST_EXAMPLES", "300"))
OPTIONS = ["--clock", "lockstep", "--filter", "cv", "--delete-after", "3",
           "--no-display-keys"]
GOOD = {f"good-{i}": (np.array([1000.0 * i, -2000.0, 500.0 * i]),
                      np.array([50.0, 20.0 * i, -5.0])) for i in range(4)}
SIGMA = 10.0  # m: the good feed's noise per axis
BLOCK = zenoh.CongestionControl.BLOCK


class Listener:
    """Counts what the service publishes: rejections by input key, the `tracks/` of
    generated targets, the last `tracks/` of each good target, frame instants."""

    def __init__(self, session: zenoh.Session) -> None:
        self.cond = threading.Condition()
        self.errors: dict[str, list[str]] = defaultdict(list)
        self.tracked: set[str] = set()
        self.good: dict[str, dict] = {}
        self.frames: list[float] = []
        self.subs = [session.declare_subscriber(KEYS.errors("**"), self._error),
                     session.declare_subscriber(KEYS.tracks("*"), self._track),
                     session.declare_subscriber(KEYS.frame, self._frame)]

    def _error(self, s: zenoh.Sample) -> None:
        body = unpack(s.payload.to_bytes())
        with self.cond:
            self.errors[body["key"]].append(body["code"])
            self.cond.notify_all()

    def _track(self, s: zenoh.Sample) -> None:
        if s.kind != zenoh.SampleKind.PUT:
            return
        tid = str(s.key_expr).rsplit("/", 1)[1]
        with self.cond:
            if tid in GOOD:
                self.good[tid] = unpack(s.payload.to_bytes())
            self.tracked.add(tid)
            self.cond.notify_all()

    def _frame(self, s: zenoh.Sample) -> None:
        t = unpack(s.payload.to_bytes())["t"]
        with self.cond:
            self.frames.append(t)

    def wait(self, pred, timeout: float = 30.0) -> bool:
        with self.cond:
            return self.cond.wait_for(pred, timeout)


class Run:
    """The service, the good feed and the tallies, across examples."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.svc = ServiceProcess(*OPTIONS, ns=KEYS.ns, clock=None, endpoint=self.endpoint)
        self.session = client_session(self.endpoint)
        if not wait_for_tracker(self.session, KEYS, 1, timeout=30):
            raise RuntimeError(f"service did not come up: {self.svc.stop()[-2000:]}")
        self.listen = Listener(self.session)
        self.t = 10.0
        self.rng = np.random.default_rng(12)
        self.reference = Tracker.from_config(tracker_config(parser().parse_args(OPTIONS)))
        self.expected: dict[str, list[str | None]] = defaultdict(list)
        self.tally: Counter[str] = Counter()
        self.durations: list[float] = []

    def status(self) -> dict:
        replies = list(self.session.get(KEYS.status, timeout=30))
        assert replies and replies[0].ok is not None, "no status reply"
        return unpack(replies[0].ok.payload.to_bytes())

    def put(self, key: str, payload: bytes) -> None:
        self.session.put(key, payload, congestion_control=BLOCK)

    def example(self, data: st.DataObject) -> None:
        self.durations.append(time.monotonic())
        t = self.t
        sents: list[Sent] = []
        for j in range(data.draw(st.integers(1, 8), label="messages")):
            kind = data.draw(st.sampled_from(["labelled"] * 5 + ["scan"] * 2 + ["batched",
                                                                                "clock"]))
            sents += data.draw(labelled(t) if kind == "labelled" else
                               scan(t + 0.5 + 0.01 * j) if kind == "scan" else
                               batched(t) if kind == "batched" else clock(t))
        before = self.status()
        good = []
        for tid, (p0, v) in GOOD.items():
            pos = p0 + v * t + self.rng.normal(0.0, SIGMA, 3)
            good.append(Measurement("good", tid, t, 3, False, tuple(pos.tolist()),
                                    (SIGMA,) * 3, (0.0, 0.0, 0.0), None))
            self.put(KEYS.meas("good", tid), pack({"t": t, "pos": pos.tolist(),
                                                   "sigma": SIGMA}))
        track(self.reference, good)
        for s in sents:
            self.put(s.key, s.payload)
            self.expected[s.key] += s.codes
        self.put(KEYS.clock, pack({"t": t + 0.9}))  # releases the scans held
        after = self.status()
        ok, bad = sum(s.ok for s in sents), sum(s.bad for s in sents)
        self.tally.update(messages=len(sents), applied=ok, rejected=bad, examples=1)
        assert after["meas_accepted"] - before["meas_accepted"] == len(GOOD) + ok, \
            (after, before, sents)
        assert after["meas_rejected"] - before["meas_rejected"] == bad, (after, before, sents)
        reasons = after["rejected_by_reason"]
        assert "other" not in reasons and sum(reasons.values()) == after["meas_rejected"]
        keys = {s.key for s in sents}
        targets = {s.target for s in sents if s.target} | {x for s in sents
                                                            for x in s.targets}
        got = self.listen
        assert got.wait(lambda: all(len(got.errors[k]) >= len(self.expected[k])
                                    for k in keys) and targets <= got.tracked), \
            ({k: (got.errors[k], self.expected[k]) for k in keys}, targets - got.tracked)
        for k in keys:
            want = self.expected[k]
            assert len(got.errors[k]) == len(want), (k, got.errors[k], want)
            assert all(w is None or g == w for g, w in zip(got.errors[k], want, strict=True)), \
                (k, got.errors[k], want)
        self.t += 1.0

    def finish(self) -> dict:
        """The checks after all examples; the figures."""
        st_ = self.status()
        assert st_["frames_skipped"] == 0 and st_["timeline_jumps"] == 0, st_
        got = self.listen
        assert got.wait(lambda: all(got.good.get(tid, {}).get("t") == self.t - 1.0
                                    for tid in GOOD))
        err_model, err_ref = [], []
        for tid, (p0, v) in GOOD.items():
            served, ref = got.good[tid], self.reference.state(tid)
            assert np.allclose(served["x"], ref["x"], rtol=1e-9, atol=1e-9), tid
            assert np.allclose(served["P"], ref["P"], rtol=1e-9, atol=1e-9), tid
            truth = p0 + v * (self.t - 1.0)
            err_model.append(np.sum((np.array(served["pos"]) - truth) ** 2))
            err_ref.append(np.sum((np.array(ref["pos"]) - truth) ** 2))
        frames = np.array(sorted(got.frames))
        steps = np.round(np.diff(frames) * 30)
        assert len(frames) > 30 and (steps == 1).all(), "frames with a gap or a repeat"
        extra = {k: len(v) for k, v in got.errors.items()
                 if len(v) != len(self.expected.get(k, []))}
        assert not extra, extra  # no rejection of a valid input, none unreported
        return {**self.tally, "status": st_, "frames": len(frames),
                "good_rmse_served": math.sqrt(np.mean(err_model)),
                "good_rmse_reference": math.sqrt(np.mean(err_ref))}

    def close(self) -> str:
        for sub in self.listen.subs:
            sub.undeclare()
        self.session.close()
        return self.svc.stop()


def run_examples(examples: int, derandomize: bool = True) -> dict:
    """Start a service, throw `examples` generated examples at it, check; the figures."""
    run = Run()
    started = time.monotonic()
    try:
        @settings(max_examples=examples, deadline=None, database=None,
                  derandomize=derandomize, print_blob=True,
                  phases=[Phase.explicit, Phase.generate],  # no shrinking: the service
                  # keeps its state between examples, so a shrunk one would not repeat
                  suppress_health_check=list(HealthCheck))
        @given(data=st.data())
        def one(data: st.DataObject) -> None:
            run.example(data)

        one()
        figures = run.finish()
    except BaseException:
        print("service stderr:", run.close()[-5000:])
        raise
    err = run.close()
    assert "Traceback" not in err, err[-3000:]
    figures["seconds"] = time.monotonic() - started
    return figures


def report(fig: dict) -> str:
    s = fig["status"]
    return (f"{fig['examples']} examples, {fig['messages']} generated messages "
            f"({fig['applied']} measurements/detections applied, {fig['rejected']} "
            f"rejected) in {fig['seconds']:.0f} s; service: meas_accepted "
            f"{s['meas_accepted']}, meas_rejected {s['meas_rejected']}, by reason "
            f"{dict(sorted(s['rejected_by_reason'].items()))}, frames "
            f"{fig['frames']} without a gap; good tracks' position RMSE "
            f"{fig['good_rmse_served']:.3f} m (a tracker fed the good feed alone: "
            f"{fig['good_rmse_reference']:.3f} m)")


def test_generated_inputs_through_the_service():
    fig = run_examples(EXAMPLES)
    print("\n" + report(fig))
    assert fig["rejected"] > 0 and fig["applied"] > 0
    assert fig["good_rmse_served"] == pytest.approx(fig["good_rmse_reference"], rel=1e-9)
