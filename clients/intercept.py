"""`track-intercept`: fly simulated interceptors at displayed tracks (scenario C's last step).

For each target (`--target ID`, repeatable, or `--targets-like PREFIX`: every display id
with that prefix) one interceptor flies at a fixed speed (default 20 m/s) from a start
point (default (7000, 6000) m) in the horizontal plane; its z follows the target's
displayed z. It is steered by the target's display states `<ns>/display/<target>` with
one guidance law (`--guidance`):

- `pure`: pure pursuit, velocity along the line of sight to the displayed position;
- `pn`: proportional navigation, heading rate = N * LOS rate * closing speed / speed,
  i.e. lateral acceleration N Vc dlambda/dt (Zarchan, Tactical and Strategic Missile
  Guidance, ch. 2), N = `--nav` (default 4), limited to `--max-turn` deg/s (default 30);
  while the range opens (closing speed <= 0) it turns toward the line of sight at the
  turn limit instead. In a slow tail chase (scenario C: 20 m/s against 18 m/s, closing
  speed a few m/s) the effective gain N Vc / V is below 1 and this law lags the line of
  sight; `--pn-form pure` uses pure PN, heading rate = N * LOS rate (lateral acceleration
  N V dlambda/dt), which does converge there;
- `intercept`: predicted intercept point (collision course): aim at p + v tau, the point
  where a constant-velocity target with the displayed `vel` is met at the interceptor's
  speed, tau the least positive root of |p + v tau - q| = s tau; pure pursuit when there
  is no root. `pure` and `intercept` turn instantly; only `pn` has a turn limit.

Lockstep: the interceptor advances once per display frame of its target, by the time
between successive frames (dt = t_n - t_(n-1)), on the velocity commanded at the previous
frame; then it measures its distance to the displayed target and chooses its next
velocity. It is therefore as deterministic as the frames (lockstep service: every 1/30 s
instant). Its state is published on `<ns>/display/interceptor-<target>` as an ordinary
display entity (sigma 0, status `confirmed`, age 0; extra fields `target`, `captured`),
congestion control BLOCK.

Capture: the first frame at which the distance to the displayed (tracked) target is below
`--capture` (default 2.55 m, the paper's figure) is the capture; the interceptor then holds
there (velocity 0) and keeps publishing that state; `--no-hold` keeps it flying. The
closest approach (time and distance) is taken over the frames while flying, so with the
default hold it is the capture frame. With `--truth` it also subscribes
`<ns>/truth/<target>` (track-feed --truth) and reports the distance to the TRUE target at
the moment of capture / closest approach (truth interpolated with constant acceleration
from the last truth sample before that instant) and the earliest time at which the true
target could have been reached at all (|p_true(t) - start| <= speed * (t - launch)).

The run ends when the feed's closing `<ns>/clock` message has been followed by every
target's frames (lockstep), at `--until T` (simulation time), after `--idle` s without a
frame, or on Ctrl-C; then one line per target and a summary are printed (`--json`: one
JSON document). While running it holds the liveliness token
`<ns>/alive/intercept/<instance>` and prints `track-intercept: ready` on stderr once its
subscribers are declared.

In-process use (an evaluation that owns the feed): `Interceptors(...).attach(session,
keys, targets=[...] | like="maneuver-", truth=True)`, publish the scenario, then
`wait(...)`, `results()`, `summary()`.
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from service.wire import CHUNK, Keys, add_zenoh_args, open_session, pack, unpack

from .scenarios import interpolate

GUIDANCE = ("pure", "pn", "intercept")
PN_FORMS = ("true", "pure")
DEFAULT_START = (7000.0, 6000.0)
DEFAULT_SPEED = 20.0
DEFAULT_CAPTURE = 2.55  # m: the interceptor-target distance of seeds/002
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
        s = self.law.speed if self.flying else 0.0
        return {"t": self.t, "id": f"{name}-{self.target}", "pos": [self.x, self.y, self.z],
                "vel": [s * self.hx, s * self.hy, 0.0], "sigma": 0.0, "status": "confirmed",
                "age": 0.0, "target": self.target, "captured": self.capture_t is not None}


# ---------------------------------------------------------------- truth
class Truth:
    """True states of one target at scan instants, interpolated with constant acceleration
    (the sample's `acc`, else the velocity difference to the next sample, else 0) by
    clients.scenarios.interpolate."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []

    @staticmethod
    def _vec(x: Any) -> np.ndarray:
        out = np.zeros(3)
        vals = [float(a) for a in x][:3]
        out[:len(vals)] = vals
        return out

    def add(self, msg: dict[str, Any]) -> None:
        t = float(msg["t"])
        row = (self._vec(msg["pos"]), self._vec(msg.get("vel", [0.0])),
               self._vec(msg["acc"]) if msg.get("acc") is not None else None)
        k = bisect.bisect_left(self.t, t)
        if k < len(self.t) and abs(self.t[k] - t) < EPS_T:
            self.rows[k] = row
        else:
            self.t.insert(k, t)
            self.rows.insert(k, row)

    def __bool__(self) -> bool:
        return bool(self.t)

    def acc(self, k: int) -> np.ndarray:
        p, v, a = self.rows[k]
        if a is not None:
            return a
        if k + 1 < len(self.t):
            return (self.rows[k + 1][1] - v) / (self.t[k + 1] - self.t[k])
        return np.zeros(3)

    def pos(self, t: float | np.ndarray) -> np.ndarray:
        """True position(s) at t: (3,) for a float, (n, 3) for an array."""
        P = np.stack([r[0] for r in self.rows])
        V = np.stack([r[1] for r in self.rows])
        A = np.stack([self.acc(i) for i in range(len(self.t))])
        out = interpolate(np.asarray(self.t), P, V, A, t, eps=EPS_T)[0]
        return out if np.ndim(t) else out[0]


# ---------------------------------------------------------------- many interceptors
def percentile(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


@dataclass
class _State:
    planes: dict[str, Interceptor] = field(default_factory=dict)
    truth: dict[str, Truth] = field(default_factory=dict)
    ended: set[str] = field(default_factory=set)  # deleted tracks
    clock_end: float | None = None
    last_frame_wall: float | None = None


class Interceptors:
    """Interceptors for several displayed targets on one Zenoh session.

    The interceptors are stepped, and their states published, in the subscriber callbacks
    themselves, on Zenoh's receive thread (direct callbacks: samples keep their order, and
    no Python worker thread competes for the GIL with that thread; a worker thread that
    held the GIL starved the receive thread under load, the tracker's BLOCK publisher
    waited past Zenoh's `wait_before_close` and the link was reset, losing frames).
    A slow interceptor therefore slows the lockstep service down instead of losing data.
    Typical in-process use, on the session that publishes the scenario (e.g.
    clients.evaluate.run_through_service's):

        ic = Interceptors(Law(guidance="intercept")).attach(session, keys,
                                                           like="maneuver-", truth=True)
        feed.publish(session, feed_args)      # with --truth
        ic.wait(timeout=600)                  # until the feed's clock end is displayed
        rows, summary = ic.results(), ic.summary()
        ic.detach()
    """

    def __init__(self, law: Law | None = None, name: str = "interceptor") -> None:
        if not CHUNK.match(name):
            raise ValueError(f"interceptor name {name!r} is not a key chunk")
        self.law = law or Law()
        self.name = name
        self.state = _State()
        self.cond = threading.Condition()
        self.session: Any = None
        self.keys: Keys | None = None
        self.targets: set[str] | None = None
        self.like: str | None = None
        self.publish = True
        self.subs: list[Any] = []
        self.pubs: dict[str, Any] = {}
        self.token: Any = None
        self.error: BaseException | None = None
        self.until: float | None = None  # frames after this simulation time are ignored
        self.pub_lock = threading.Lock()  # a publisher is not undeclared during its put

    # -------------------------------------------------------- wiring
    def attach(self, session: Any, keys: Keys, targets: Iterable[str] | None = None,
               like: str | None = None, truth: bool = False, publish: bool = True,
               token: str | None = None) -> Interceptors:
        """Subscribe the display (and truth) keys of `targets`, or of every id starting
        with `like`, and the lockstep clock. `token`: declare the liveliness token
        `<ns>/alive/intercept/<token>` once subscribed (readiness for other processes)."""
        targets = list(targets or [])
        if bool(targets) == (like is not None):
            raise ValueError("give either targets or like (a prefix)")
        for tid in [*targets, *([like] if like else [])]:
            if not CHUNK.match(tid):
                raise ValueError(f"{tid!r} is not a key chunk")
        self.session, self.keys, self.publish = session, keys, publish
        self.targets = set(targets) if targets else None
        self.like = like

        def direct(kind: str) -> Any:
            handle = self._handle

            def on_sample(s: Any) -> None:
                body = s.payload.to_bytes() if s.kind == zenoh.SampleKind.PUT else None
                try:
                    handle(kind, str(s.key_expr), body)
                except Exception as exc:  # a malformed message must not stop the others
                    self.error = exc

            return zenoh.handlers.Callback(on_sample, indirect=False)

        pattern = f"{like}$*" if like else "*"
        exprs = [keys.display(t) for t in targets] if targets else [keys.display(pattern)]
        texprs = [keys.truth(t) for t in targets] if targets else [keys.truth(pattern)]
        self.subs = [session.declare_subscriber(k, direct("display")) for k in exprs]
        if truth:
            self.subs += [session.declare_subscriber(k, direct("truth")) for k in texprs]
        self.subs.append(session.declare_subscriber(keys.clock, direct("clock")))
        if token:
            self.token = session.liveliness().declare_token(
                f"{keys.ns}/alive/intercept/{token}")
        return self

    def detach(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.subs = []
        if self.token is not None:
            self.token.undeclare()
            self.token = None
        with self.pub_lock:  # after a put under way; no publisher is declared after this
            self.publish = False
            for p in self.pubs.values():
                p.undeclare()
            self.pubs = {}

    # -------------------------------------------------------- samples
    def _wanted(self, tid: str) -> bool:
        if self.targets is not None:
            return tid in self.targets
        return (tid.startswith(self.like or "") and not tid.startswith(f"{self.name}-")
                and not tid.startswith("interceptor-"))

    def _handle(self, kind: str, key: str, body: bytes | None) -> None:
        assert self.keys is not None
        st = self.state
        if kind == "clock":
            if body is not None:
                t = float(unpack(body)["t"])
                with self.cond:
                    st.clock_end = t if st.clock_end is None else max(st.clock_end, t)
                    self.cond.notify_all()
            return
        what = "display" if kind == "display" else "truth"
        chunks = self.keys.chunks_after(key, what)
        if len(chunks) != 1 or not self._wanted(chunks[0]):
            return
        tid = chunks[0]
        if kind == "truth":
            if body is not None:
                msg = unpack(body)
                with self.cond:
                    st.truth.setdefault(tid, Truth()).add(msg)
            return
        if body is None:  # the track was deleted
            with self.cond:
                st.ended.add(tid)
                self.cond.notify_all()
            return
        msg = unpack(body)
        t = float(msg["t"])
        if self.until is not None and t > self.until + EPS_T:
            return
        p = [float(a) for a in msg["pos"]]
        v = [float(a) for a in msg.get("vel", [0.0, 0.0, 0.0])]
        if len(p) < 2 or len(v) < 2 or not all(map(math.isfinite, p + v + [t])):
            return
        with self.cond:
            plane = st.planes.get(tid)
            if plane is None:
                plane = st.planes[tid] = Interceptor(tid, self.law)
            moved = plane.frame(t, p, v)
            st.ended.discard(tid)
            # wake wait() on the first frame (its idle limit starts) and when this target
            # reaches the end (wait() may be done); not on every frame: a waiter woken that
            # often would take the GIL and this lock from Zenoh's receive thread
            wake = st.last_frame_wall is None or (
                moved and self._at_end_locked(plane, self.until))
            st.last_frame_wall = time.monotonic()
            state = plane.display(self.name) if moved and self.publish else None
        if state is not None:
            with self.pub_lock:
                if self.publish:
                    pub = self.pubs.get(tid)
                    if pub is None:
                        pub = self.pubs[tid] = self.session.declare_publisher(
                            self.keys.display(f"{self.name}-{tid}"),
                            congestion_control=zenoh.CongestionControl.BLOCK)
                    pub.put(pack(state))
        if wake:  # once the frame's state is out
            with self.cond:
                self.cond.notify_all()

    # -------------------------------------------------------- completion
    def _at_end_locked(self, plane: Interceptor, until: float | None) -> bool:
        """Whether `plane` has had its frames up to `until`, or without it, every frame
        strictly before the end the feed announced on `<ns>/clock` (unknown: False)."""
        if plane.t is None:
            return False
        if until is not None:
            return plane.t >= until - EPS_T
        end = self.state.clock_end
        # no frame before end is due any more
        return end is not None and plane.t + max(plane.dt, EPS_T) >= end - EPS_T

    def _done_locked(self, until: float | None) -> bool:
        st = self.state
        if not st.planes:
            return False
        if self.targets is not None and not self.targets <= set(st.planes) | st.ended:
            return False
        if until is None and st.clock_end is None:
            return False
        return all(self._at_end_locked(plane, until) for tid, plane in st.planes.items()
                   if tid not in st.ended and plane.t is not None)

    def done(self, until: float | None = None) -> bool:
        """True once every target's frames reached `until`, or, without it, the end the
        feed announced on `<ns>/clock` (all frames strictly before it are in)."""
        with self.cond:
            return self._done_locked(until)

    def wait(self, until: float | None = None, timeout: float | None = None,
             idle: float | None = None, stop: threading.Event | None = None) -> bool:
        """Block until done(until), `timeout` s, `idle` s without a frame (after the first
        one), or `stop` is set. Returns done(until). Frames after `until` are ignored.

        `stop` is not polled: whoever sets it must then call wake() (from another thread
        than this one; a signal handler runs in the main thread: see main())."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self.cond:
            if until is not None:
                self.until = until
            while not self._done_locked(until):
                if stop is not None and stop.is_set():
                    break
                limits = [] if deadline is None else [deadline]
                last = self.state.last_frame_wall  # moved on by every frame
                if idle and last is not None:
                    limits.append(last + idle)
                wake_at = min(limits, default=None)
                now = time.monotonic()
                if wake_at is not None and now >= wake_at:
                    break  # timeout, or idle
                self.cond.wait(None if wake_at is None else wake_at - now)
            return self._done_locked(until)

    def wake(self) -> None:
        """Make wait() look at its conditions again (after its `stop` event was set)."""
        with self.cond:
            self.cond.notify_all()

    # -------------------------------------------------------- results
    def results(self) -> list[dict[str, Any]]:
        """One dict per target, sorted by id (times s, distances m; None where unknown)."""
        law = self.law
        out = []
        with self.cond:
            items = sorted(self.state.planes.items())
            truths = {k: v for k, v in self.state.truth.items() if v}
            for tid, pl in items:
                row: dict[str, Any] = {
                    "target": tid, "id": f"{self.name}-{tid}", "guidance": law.guidance,
                    "launch_t": pl.t_launch, "last_t": pl.t, "frames": pl.frames,
                    "captured": pl.capture_t is not None, "capture_t": pl.capture_t,
                    "capture_dist": pl.capture_dist, "closest_t": pl.closest_t,
                    "closest_dist": pl.closest_dist if pl.closest_t is not None else None,
                    "pos": [pl.x, pl.y, pl.z], "capture_true_dist": None,
                    "closest_true_dist": None, "earliest_reach_t": None}
                tr = truths.get(tid)
                if tr is not None:
                    if pl.capture_t is not None and pl.capture_pos is not None:
                        row["capture_true_dist"] = float(np.linalg.norm(
                            tr.pos(pl.capture_t) - np.array(pl.capture_pos)))
                    if pl.closest_t is not None and pl.closest_pos is not None:
                        row["closest_true_dist"] = float(np.linalg.norm(
                            tr.pos(pl.closest_t) - np.array(pl.closest_pos)))
                    if pl.t_launch is not None:
                        row["earliest_reach_t"] = earliest_reach(
                            tr.pos, law.start, law.speed, pl.t_launch,
                            max(tr.t[-1], pl.t or tr.t[-1]), step=1e-2)
                out.append(row)
        return out

    def summary(self, rows: list[dict[str, Any]] | None = None) -> dict[str, Any]:
        rows = self.results() if rows is None else rows
        cap = [r for r in rows if r["captured"]]
        times = [r["capture_t"] for r in cap]
        true_cap = [r["capture_true_dist"] for r in cap if r["capture_true_dist"] is not None]
        true_ca = [r["closest_true_dist"] for r in rows if r["closest_true_dist"] is not None]
        early = [r["earliest_reach_t"] for r in rows if r["earliest_reach_t"] is not None]
        law = self.law
        return {
            "guidance": law.guidance, "speed": law.speed, "start": list(law.start),
            "capture_radius": law.capture, "hold": law.hold,
            "nav": law.nav, "max_turn_deg_s": math.degrees(law.max_turn),
            "pn_form": law.pn_form,
            "targets": len(rows), "captured": len(cap),
            "capture_fraction": len(cap) / len(rows) if rows else None,
            "mean_capture_t": float(np.mean(times)) if times else None,
            "median_capture_t": percentile(times, 50),
            "mean_earliest_reach_t": float(np.mean(early)) if early else None,
            "true_dist_at_capture_median": percentile(true_cap, 50),
            "true_dist_at_capture_p90": percentile(true_cap, 90),
            "true_dist_at_closest_median": percentile(true_ca, 50),
            "true_dist_at_closest_p90": percentile(true_ca, 90),
            "median_closest_dist": percentile(
                [r["closest_dist"] for r in rows if r["closest_dist"] is not None], 50),
        }


# ---------------------------------------------------------------- text output
def _f(x: float | None, fmt: str = ".2f", unit: str = "") -> str:
    return "-" if x is None else f"{x:{fmt}}{unit}"


def line(r: dict[str, Any]) -> str:
    head = f"{r['target']:<16} {r['guidance']:<9}"
    if r["captured"]:
        s = (f"{head} captured at t={_f(r['capture_t'])} s, {_f(r['capture_dist'], '.3f')} m "
             f"from the track, {_f(r['capture_true_dist'])} m from the true target")
    else:
        s = (f"{head} not captured: closest {_f(r['closest_dist'])} m at "
             f"t={_f(r['closest_t'])} s, {_f(r['closest_true_dist'])} m from the true target")
    if r["earliest_reach_t"] is not None:
        s += f"; earliest feasible t={r['earliest_reach_t']:.2f} s"
    return s


def summary_line(s: dict[str, Any]) -> str:
    if not s["targets"]:
        return f"track-intercept: {s['guidance']}: no target seen"
    out = (f"track-intercept: {s['guidance']}: {s['captured']}/{s['targets']} captured "
           f"({100 * s['capture_fraction']:.0f} %) within {s['capture_radius']} m of the track, "
           f"mean capture t={_f(s['mean_capture_t'])} s")
    if s["mean_earliest_reach_t"] is not None:
        out += f" (earliest feasible {s['mean_earliest_reach_t']:.2f} s)"
    if s["true_dist_at_capture_median"] is not None:
        out += (f"; true-target distance at capture: median "
                f"{s['true_dist_at_capture_median']:.2f} m, p90 "
                f"{s['true_dist_at_capture_p90']:.2f} m")
    elif s["true_dist_at_closest_median"] is not None:
        out += (f"; true-target distance at closest approach: median "
                f"{s['true_dist_at_closest_median']:.2f} m, p90 "
                f"{s['true_dist_at_closest_p90']:.2f} m")
    return out


# ---------------------------------------------------------------- CLI
def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-intercept", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--target", action="append", default=[], metavar="ID",
                   help="target id to intercept (repeatable)")
    g.add_argument("--targets-like", metavar="PREFIX",
                   help="intercept every displayed target whose id starts with PREFIX")
    p.add_argument("--guidance", choices=GUIDANCE, default="intercept",
                   help="pure pursuit, proportional navigation, or predicted intercept point "
                        "(default %(default)s)")
    p.add_argument("--speed", type=float, default=DEFAULT_SPEED, help="interceptor speed, m/s")
    p.add_argument("--start", type=float, nargs=2, default=list(DEFAULT_START),
                   metavar=("X", "Y"), help="launch point, m (default 7000 6000)")
    p.add_argument("--capture", type=float, default=DEFAULT_CAPTURE,
                   help="capture radius around the tracked target, m (default 2.55)")
    p.add_argument("--no-hold", action="store_true",
                   help="keep flying after capture (closest approach over the whole run)")
    p.add_argument("--nav", type=float, default=4.0, help="PN navigation constant N")
    p.add_argument("--max-turn", type=float, default=30.0, help="PN turn-rate limit, deg/s")
    p.add_argument("--pn-form", choices=PN_FORMS, default="true",
                   help="true: turn rate = N * LOS rate * closing speed / speed (default); "
                        "pure: turn rate = N * LOS rate")
    p.add_argument("--truth", action="store_true",
                   help="subscribe <ns>/truth/<target> and report true-target distances")
    p.add_argument("--until", type=float, default=None,
                   help="stop once every target's frames reach this simulation time")
    p.add_argument("--idle", type=float, default=30.0,
                   help="stop after this many wall seconds without a frame (0: never)")
    p.add_argument("--name", default="interceptor",
                   help="display ids are NAME-<target> (default %(default)s)")
    p.add_argument("--instance", default=None, help="liveliness instance name")
    p.add_argument("--json", action="store_true", help="print one JSON document")
    add_zenoh_args(p)
    return p


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    law = Law(guidance=args.guidance, speed=args.speed, start=tuple(args.start),
              capture=args.capture, nav=args.nav, max_turn=math.radians(args.max_turn),
              pn_form=args.pn_form,
              hold=not args.no_hold)
    ic = Interceptors(law, name=args.name)
    stop = threading.Event()

    def on_signal(*_: Any) -> None:
        stop.set()
        ic.wake()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    session = open_session(args)
    try:
        ic.attach(session, Keys(args.ns), targets=args.target or None,
                  like=args.targets_like, truth=args.truth,
                  token=args.instance or uuid.uuid4().hex[:8])
        print("track-intercept: ready", file=sys.stderr, flush=True)
        # wait on another thread: the signal handlers run in this one, where one could
        # come between the waiter's look at `stop` and its wait, and its wake be lost
        waiter = threading.Thread(target=ic.wait, name="intercept-wait", kwargs={
            "until": args.until, "idle": args.idle or None, "stop": stop})
        waiter.start()
        waiter.join()
        ic.detach()
        rows = ic.results()
        summ = ic.summary(rows)
        if args.json:
            print(json.dumps({"summary": summ, "targets": rows}, indent=1), flush=True)
        else:
            for r in rows:
                print(line(r))
            print(summary_line(summ), flush=True)
        if ic.error is not None:
            print(f"track-intercept: a message was skipped: {ic.error!r}", file=sys.stderr)
    finally:
        session.close()


if __name__ == "__main__":
    main()
