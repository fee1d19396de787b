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
import json
import math
import sys
import threading
import time
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from zenoh_track.clients.intercept.guidance import (
    DEFAULT_CAPTURE,
    DEFAULT_SPEED,
    DEFAULT_START,
    EPS_T,
    GUIDANCE,
    PN_FORMS,
    Interceptor,
    Law,
)
from zenoh_track.clients.intercept.intercept_report import (
    Truth,
    line,
    result_row,
    summarize,
    summary_line,
)
from zenoh_track.wire import (
    CHUNK,
    MSGPACK_ENCODING,
    Keys,
    add_zenoh_args,
    on_signals,
    open_session,
    pack,
    unpack,
)


# ---------------------------------------------------------------- many interceptors
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
    zenoh_track.clients.evaluation.evaluate.run_through_service's):

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
                            encoding=zenoh.Encoding(MSGPACK_ENCODING),
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

        `stop` is not polled: whoever sets it must then call wake() (see main())."""
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
        with self.cond:
            items = sorted(self.state.planes.items())
            truths = {k: v for k, v in self.state.truth.items() if v}
            return [result_row(tid, self.name, self.law, pl, truths.get(tid))
                    for tid, pl in items]

    def summary(self, rows: list[dict[str, Any]] | None = None) -> dict[str, Any]:
        """The run's summary over `rows` (default: results())."""
        return summarize(self.law, self.results() if rows is None else rows)


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
    stop = on_signals()
    threading.Thread(target=lambda: (stop.wait(), ic.wake()), name="intercept-stop",
                     daemon=True).start()
    session = open_session(args)
    try:
        ic.attach(session, Keys(args.ns), targets=args.target or None,
                  like=args.targets_like, truth=args.truth,
                  token=args.instance or uuid.uuid4().hex[:8])
        print("track-intercept: ready", file=sys.stderr, flush=True)
        ic.wait(until=args.until, idle=args.idle or None, stop=stop.event)
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
