"""Interception (scenario C's last step): the offline anchors of SCENARIOS.md, the guidance
kernel against the exact trajectory, and track-intercept against the real service."""

from __future__ import annotations

import functools
import json
import math
import re
import subprocess
import sys
import threading

import numpy as np
import pytest
import zenoh

from zenoh_track.clients.evaluation import evaluate as track_eval
from zenoh_track.clients.feeds.scenarios import ManeuverC
from zenoh_track.clients.intercept.guidance import Interceptor, Law, earliest_reach, intercept_time
from zenoh_track.clients.intercept.intercept import Interceptors
from zenoh_track.clients.intercept.intercept_report import Truth
from zenoh_track.clients.lib.process import stop

START, SPEED, CAPTURE, RATE = np.array([7000.0, 6000.0]), 20.0, 2.55, 30.0
TARGET = ManeuverC()


def true_pos(t: float) -> np.ndarray:
    return TARGET.state(t)[0]


# ---------------------------------------------------------------- (a) the anchors
@functools.cache
def earliest_feasible() -> float:
    """Earliest t with |p(t) - start| <= SPEED t. The target never flies faster than
    18 m/s < SPEED, so |p(t) - start| - SPEED t decreases strictly: bisect its one root."""
    lo, hi = 0.0, TARGET.duration
    assert np.linalg.norm(true_pos(hi) - START) <= SPEED * hi
    while hi - lo > 1e-6:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.linalg.norm(true_pos(mid) - START) > SPEED * mid else (lo, mid)
    return hi


@functools.cache
def pure_pursuit_of_truth() -> float:
    """Pure pursuit of the TRUE target at 30 Hz: during each 1/30 s fly at SPEED toward
    where the target was at its start; the first instant within CAPTURE m."""
    q, dt = START.copy(), 1.0 / RATE
    for n in range(1, int(TARGET.duration * RATE) + 1):
        los = true_pos((n - 1) * dt) - q
        q = q + SPEED * dt * los / np.linalg.norm(los)
        if np.linalg.norm(true_pos(n * dt) - q) < CAPTURE:
            return n * dt
    raise AssertionError("pure pursuit of the truth never closed")


def test_anchors_of_scenario_c():
    """SCENARIOS.md C: the interceptor can first reach the true target at about 599 s,
    pure pursuit of the true target closes to 2.55 m at about 688 s."""
    speeds = [np.linalg.norm(TARGET.state(t)[1]) for t in np.arange(0, 800, 0.5)]
    assert max(speeds) < SPEED  # what makes the bisection above valid
    t_first, t_pursuit = earliest_feasible(), pure_pursuit_of_truth()
    assert abs(t_first - 599.0) <= 3.0, t_first  # 599.28 s
    assert abs(t_pursuit - 688.0) <= 3.0, t_pursuit  # 687.70 s
    # the module's own estimate of the physical limit (from truth samples) agrees
    def pos_at(ts):
        return np.array([true_pos(t) for t in ts])

    assert abs(earliest_reach(pos_at, START, SPEED, 0.0, 800.0, step=0.01) - t_first) < 0.02


# ---------------------------------------------------------------- guidance kernel
@functools.cache
def truth_frames() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ts = np.arange(int(TARGET.duration * RATE) + 1) / RATE
    states = [TARGET.state(t) for t in ts]
    return ts, np.array([s[0] for s in states]), np.array([s[1] for s in states])


def fly_at_truth(law: Law) -> Interceptor:
    """An interceptor stepped by exact display frames (true position and velocity)."""
    plane = Interceptor("maneuver-000", law)
    for t, p, v in zip(*truth_frames(), strict=True):
        plane.frame(float(t), [p[0], p[1], 0.0], [v[0], v[1], 0.0])
        if plane.capture_t is not None:
            break
    return plane


def test_guidance_on_exact_frames():
    t_first = earliest_feasible()
    pure = fly_at_truth(Law(guidance="pure"))
    assert pure.capture_t == pytest.approx(pure_pursuit_of_truth(), abs=1e-6)
    # the collision course re-aimed every frame is within 1 % of the physical limit
    coll = fly_at_truth(Law(guidance="intercept"))
    assert t_first <= coll.capture_t <= 1.01 * t_first, coll.capture_t  # 601.5 s
    assert coll.capture_dist < CAPTURE
    # pure PN (heading rate N * LOS rate) converges in this slow tail chase
    ppn = fly_at_truth(Law(guidance="pn", pn_form="pure", nav=4.0))
    assert t_first <= ppn.capture_t <= 1.04 * t_first, ppn.capture_t  # 615.2 s
    assert ppn.capture_t < pure.capture_t
    # the interceptor never exceeds its speed: it cannot beat the physical limit
    for plane in (pure, coll, ppn):
        assert plane.capture_t >= t_first


def test_pn_turn_rate_limit():
    law = Law(guidance="pn", nav=4.0, max_turn=math.radians(5.0))
    plane = Interceptor("x", law)
    headings = []
    for n in range(60):  # a target crossing fast, close by: PN asks for hard turns
        t = n / RATE
        plane.frame(t, [6900.0 + 0.0 * t, 5900.0 + 30.0 * t, 0.0], [0.0, 30.0, 0.0])
        headings.append(math.atan2(plane.hy, plane.hx))
    turns = np.abs(np.diff(np.unwrap(headings)))
    assert turns.max() <= math.radians(5.0) / RATE + 1e-12
    assert turns.max() > 0.99 * math.radians(5.0) / RATE  # the limit was reached


def test_intercept_time_solves_the_collision_triangle():
    rng = np.random.default_rng(1)
    for _ in range(200):
        r = rng.normal(0, 1000, 2)
        speed, h = rng.uniform(0, 0.99 * SPEED), rng.uniform(-math.pi, math.pi)
        v = speed * np.array([math.cos(h), math.sin(h)])
        tau = intercept_time(tuple(r), tuple(v), SPEED)
        assert tau is not None and tau > 0  # a slower target can always be met
        assert np.linalg.norm(r + v * tau) == pytest.approx(SPEED * tau, rel=1e-9)
    # a faster target flying straight away cannot be met; equal speeds: linear case
    assert intercept_time((100.0, 0.0), (30.0, 0.0), SPEED) is None
    assert intercept_time((100.0, 0.0), (-20.0, 0.0), SPEED) == pytest.approx(2.5)
    assert intercept_time((100.0, 0.0), (20.0, 0.0), SPEED) is None


def test_truth_interpolation_is_exact_for_scenario_c():
    truth = Truth()
    for t in np.arange(0.0, 802.0, 2.0):
        p, v, a = TARGET.state(t)
        truth.add({"t": t, "pos": p.tolist(), "vel": v.tolist(), "acc": a.tolist()})
    for t in (1.0, 379.9, 381.3, 599.97, 605.0, 633.3, 661.0, 799.0):
        assert np.allclose(truth.pos(t)[:2], true_pos(t), atol=1e-6), t
    assert truth.pos(np.array([1.0, 2.0])).shape == (2, 3)


# ---------------------------------------------------------------- (b) through the service
@pytest.fixture(scope="module")
def service_filters() -> set[str]:
    """The service's --filter choices, as its --help states them."""
    out = subprocess.run([sys.executable, "-m", "zenoh_track", "--help"], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    m = re.search(r"--filter \{([^}]*)\}", out)
    assert m, f"no --filter {{...}} choices in the service's --help:\n{out}"
    return set(m.group(1).split(","))


# (service arguments, allowed mean capture time over the physical limit). Measured with
# 5 runs, seed 0: the default filter (IMM since 0c9ac8e; CV before: 645 s, +7.6 %)
# 646 s (+7.8 %): its velocity lags the slow turn, so the collision course aims short;
# the IMM at scenario C's low process noise (zenoh_track.clients.evaluation.evaluate.SERVICE_ARGS)
# 618 s (+3.1 %).
CASES = [pytest.param([], 0.10, id="default-filter"),
         pytest.param(["--filter", "imm", *track_eval.SERVICE_ARGS["maneuver"]], 0.05,
                      id="imm-scenario-c")]


class KeyCounter:
    """Counts samples per key and keeps the last body (decoded) of each."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.count: dict[str, int] = {}
        self.last: dict[str, bytes] = {}
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, s) -> None:
        with self.lock:
            k = str(s.key_expr)
            self.count[k] = self.count.get(k, 0) + 1
            self.last[k] = s.payload.to_bytes()


def wait_for_token(session: zenoh.Session, key: str, timeout: float = 30.0) -> bool:
    ready = threading.Event()
    sub = session.liveliness().declare_subscriber(
        key, lambda s: ready.set() if s.kind == zenoh.SampleKind.PUT else None, history=True)
    try:
        return ready.wait(timeout)
    finally:
        sub.undeclare()


@pytest.mark.slow
@pytest.mark.parametrize(("service_args", "tolerance"), CASES)
def test_intercept_through_service(service_factory, service_filters, service_args, tolerance):
    from zenoh_track.wire import unpack

    if "--filter" in service_args:  # a case the service cannot run fails, it is not skipped
        name = service_args[service_args.index("--filter") + 1]
        assert name in service_filters, f"no --filter {name} in {sorted(service_filters)}"
    runs = 5
    svc, s = service_factory("--clock", "lockstep", *service_args)
    shown = KeyCounter(s, f"{svc.ns}/display/interceptor-$*")
    # pure pursuit in this process, on the test's own session (the in-process API)
    pursuit = Interceptors(Law(guidance="pure"), name="pursuit").attach(
        s, svc.keys, like="maneuver-", truth=True, publish=False)
    proc = subprocess.Popen(
        [sys.executable, "-m", "zenoh_track.clients.intercept.intercept", "-e", svc.endpoint,
         "--ns", svc.ns,
         "--targets-like", "maneuver-", "--guidance", "intercept", "--truth", "--json",
         "--instance", "itest"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for_token(s, f"{svc.ns}/alive/intercept/itest"), stop(proc)[-3000:]
        svc.feed("maneuver", "--runs", str(runs), "--truth")
        out, err = proc.communicate(timeout=120)  # it ends after the feed's closing clock
    finally:
        stop(proc)
    assert proc.returncode == 0, err[-3000:]
    report = json.loads(out)
    summ, rows = report["summary"], report["targets"]
    assert pursuit.wait(timeout=60)
    pursuit.detach()
    psumm = pursuit.summary()

    t_first = earliest_feasible()
    names = [f"maneuver-{i:03d}" for i in range(runs)]
    # every interceptor is displayed, once per frame of its target, as a display entity
    frames = round(800 / 2 + 1) * 2 * 30  # frames strictly before the closing clock (802 s)
    with shown.lock:
        assert shown.count == {f"{svc.ns}/display/interceptor-{n}": frames for n in names}
        last = {k: unpack(b) for k, b in shown.last.items()}
    for n in names:
        body = last[f"{svc.ns}/display/interceptor-{n}"]
        assert body["id"] == f"interceptor-{n}" and body["status"] == "confirmed"
        assert body["sigma"] == 0.0 and body["age"] == 0.0 and len(body["pos"]) == 3
        assert body["t"] == pytest.approx((frames - 1) / 30)
    # lockstep: every frame reached the interceptor; the truth gives the physical limit
    assert [r["target"] for r in rows] == names
    assert all(r["frames"] == frames for r in rows)
    assert all(abs(r["earliest_reach_t"] - t_first) < 0.05 for r in rows)
    # capture within 2.55 m of the tracked target, close to the physical limit
    assert summ["captured"] >= runs - 1, [r["closest_dist"] for r in rows]
    assert all(r["capture_dist"] < CAPTURE for r in rows if r["captured"])
    mean_t = summ["mean_capture_t"]
    assert (1 - 0.03) * t_first <= mean_t <= (1 + tolerance) * t_first, mean_t
    # the true miss at capture is the track's error (tens of metres), not the radius
    assert summ["true_dist_at_capture_median"] < 150.0, summ
    assert summ["true_dist_at_capture_p90"] >= summ["true_dist_at_capture_median"]
    # pure pursuit of the same tracks captures too, but later
    assert psumm["captured"] >= runs - 1
    assert psumm["mean_capture_t"] > mean_t + 20.0, (psumm["mean_capture_t"], mean_t)
