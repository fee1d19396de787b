"""`track-eval heldout`: the held-out measure of a 1 Hz labelled position feed.

Every other position of each target is sent to a lockstep service (`meas/<sensor>/<id>`,
`{t, pos, sigma}`, sigma as the feed states it, or absent); the others are held out, and
the service's frame 1 s after each position sent is scored against the position held
out there (and, for a generated feed, against the truth), beside two predictors on the
same positions sent: linear extrapolation from the last two, and a constant-velocity
Kalman filter trusting the stated sigma (continuous white acceleration of density
`--cv-q`^2; Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2). Prints RMS and 95th
percentile of the 3-D error, m, and their ratios to linear extrapolation's.

The feed: generated (`--aircraft` targets per run, `--runs` Monte Carlo runs, all at
once): aircraft at 100-250 m/s with turns, climbs and speed changes, positions jittered by
10-30 m per axis (a level per aircraft), quantised to 1 m, with a dead-reckoning error
that drifts to 50 m and snaps back now and then; or (`--feed stamped`) positions of 80-300
m/s aircraft whose time stamps are off by 0.1-0.2 s RMS, heavy-tailed, with repeats and
quantisation (`clients.feeds.stamped`, docs/timing.md), sent with `sigma_t` as each
aircraft's timing is (`--stated-sigma-t true`) or without; or recorded (`--recording`, an
MCAP of `track-record`): its `meas/` messages with Cartesian `pos`, one second apart per
target. The errors are also split along the track (the direction of the held-out
positions' chord, or of the true velocity), across it horizontally and vertically, and,
for the stamped feed, in turns and straight.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import uuid
from typing import Any

import numpy as np
import zenoh

from zenoh_track.clients.evaluation.collect import lockstep_service
from zenoh_track.clients.feeds import stamped
from zenoh_track.clients.lib import Frame, Merge
from zenoh_track.wire import (
    MSGPACK_ENCODING,
    Keys,
    pack,
    peer_config,
    unpack,
    wait_for_tracker,
)

SENSOR = "feed"
WARMUP = 10.0  # s: scored from this long after a target's first position


# ---------------------------------------------------------------- the feeds
def generate(aircraft: int = 50, runs: int = 20, seed: int = 0, duration: float = 300.0,
             jitter: tuple[float, float] = (10.0, 30.0), jump: float = 50.0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (K,), positions (N, K, 3) as a feed sends them and the truth (N, K, 3), N =
    aircraft x runs, one position a second."""
    rng = np.random.default_rng(seed)
    n, sub = aircraft * runs, 10  # integrated at 10 Hz
    ts = np.arange(0.0, duration + 1e-9, 1.0)
    steps = int(duration * sub) + 1
    h = 1.0 / sub
    pos = np.column_stack([rng.uniform(-50e3, 50e3, (n, 2)), rng.uniform(2e3, 10e3, n)])
    speed, heading = rng.uniform(100, 250, n), rng.uniform(-np.pi, np.pi, n)
    climb = np.zeros(n)
    turn, accel, vz = np.zeros(n), np.zeros(n), np.zeros(n)
    change = rng.uniform(0, 30, n)  # s until each aircraft's next manoeuvre
    truth = np.empty((n, len(ts), 3))
    for i in range(steps):
        t = i * h
        if i % sub == 0:
            truth[:, i // sub] = pos
        due = t >= change
        if due.any():  # a new leg: straight, turn, climb or descent, speed change
            k = int(due.sum())
            kind = rng.integers(0, 4, k)
            turn[due] = np.where(kind == 1, np.radians(rng.uniform(-3, 3, k)), 0.0)
            vz[due] = np.where(kind == 2, rng.uniform(-15, 15, k), 0.0)
            accel[due] = np.where(kind == 3, rng.uniform(-2, 2, k), 0.0)
            change[due] = t + rng.uniform(10, 60, k)
        climb += (vz - climb) * h / 5.0  # climb rate eased in over about 5 s
        speed = np.clip(speed + accel * h, 80, 280)
        heading += turn * h
        pos = pos + h * np.column_stack([speed * np.cos(heading), speed * np.sin(heading),
                                         climb])
    sigma = rng.uniform(*jitter, n)[:, None, None]
    noisy = truth + sigma * rng.standard_normal(truth.shape)
    # dead reckoning: an error drifting to `jump` m over 20-60 s, then corrected at once
    drift = np.zeros_like(truth)
    for a in range(n):
        k = 0
        while k < len(ts):
            span = int(rng.integers(20, 61))
            angle = rng.uniform(-np.pi, np.pi)
            ramp = np.linspace(0, jump, span, endpoint=False)[:len(ts) - k]
            drift[a, k:k + span, 0], drift[a, k:k + span, 1] = \
                ramp * np.cos(angle), ramp * np.sin(angle)
            k += span
    return ts, np.round(noisy + drift), truth


def recorded(path: str) -> tuple[np.ndarray, np.ndarray, None]:
    """Times and positions of a recording's `meas/` messages with Cartesian `pos` at
    whole seconds (targets without a position at every second of the common span are
    left out)."""
    from zenoh_track.clients.record.files import Recording  # noqa: PLC0415 (only for this feed)
    by_target: dict[str, dict[float, list[float]]] = {}
    with open(path, "rb") as f:
        rec = Recording(f)
        ids = {c.id for c in rec.channels.values() if "/meas/" in c.key and c.kind == "put"}
        for ch, sample in rec.samples(ids):
            m = unpack(sample.payload)
            if "pos" in m and len(m["pos"]) == 3:
                by_target.setdefault(ch.key.rsplit("/", 1)[1], {})[round(m["t"])] = m["pos"]
    t0 = min(min(v) for v in by_target.values())
    t1 = max(max(v) for v in by_target.values())
    ts = np.arange(t0, t1 + 1, 1.0)
    pos = np.full((len(by_target), len(ts), 3), np.nan)
    for i, v in enumerate(by_target.values()):
        for t, p in v.items():
            pos[i, int(t - t0)] = p
    return ts, pos, None


# ---------------------------------------------------------------- predictors
def linear(ts: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Position 1 s after each position sent (the even indices), extrapolated from the
    last two sent: (N, K, 3), NaN where there is none."""
    out = np.full_like(pos, np.nan)
    out[:, 3::2] = pos[:, 2:-1:2] + (pos[:, 2:-1:2] - pos[:, :-3:2]) / 2.0
    return out


def cv_filter(ts: np.ndarray, pos: np.ndarray, sigma: float, q: float) -> np.ndarray:
    """A textbook CV Kalman filter (R = sigma^2, continuous white acceleration of density
    q^2) on the positions sent, predicted 1 s ahead: (N, K, 3)."""
    n = pos.shape[0]
    out = np.full_like(pos, np.nan)
    x = np.zeros((n, 3, 2))
    p = np.zeros((n, 3, 2, 2))
    started = np.zeros(n, bool)
    last = np.full(n, np.nan)
    for k in range(0, len(ts), 2):
        z = pos[:, k]
        have = np.isfinite(z).all(1)
        new = have & ~started
        x[new, :, 0], x[new, :, 1] = z[new], 0.0
        p[new] = np.diag([sigma ** 2, 1e6])
        started |= new
        upd = have & ~new
        if upd.any():
            dt = (ts[k] - last[upd])[:, None]
            f = np.stack([np.ones_like(dt), dt, np.zeros_like(dt), np.ones_like(dt)], -1
                         ).reshape(-1, 1, 2, 2)
            qm = q ** 2 * np.stack([dt ** 3 / 3, dt ** 2 / 2, dt ** 2 / 2, dt], -1
                                   ).reshape(-1, 1, 2, 2)
            xp = (f @ x[upd][..., None])[..., 0]
            pp = f @ p[upd] @ f.swapaxes(-1, -2) + qm
            s = pp[..., 0, 0] + sigma ** 2 + 1e-12
            gain = pp[..., :, 0] / s[..., None]
            nu = z[upd] - xp[..., 0]
            x[upd] = xp + gain * nu[..., None]
            p[upd] = pp - gain[..., :, None] * pp[..., None, 0, :]
        last[have] = ts[k]
        if k + 1 < len(ts):
            out[started, k + 1] = x[started, :, 0] + x[started, :, 1]
    return out


# ---------------------------------------------------------------- the service
def run_service(ts: np.ndarray, pos: np.ndarray, sigma: float | None,
                service_args: list[str], sigma_t: np.ndarray | None = None) -> np.ndarray:
    """Send the even-indexed positions to a lockstep service (with each target's
    `sigma_t` (N,) s, if given); its frame positions at the odd-indexed instants
    (N, K, 3), NaN elsewhere."""
    ns = f"held{uuid.uuid4().hex[:8]}"
    proc = lockstep_service(ns, ["--no-display-keys", *service_args])
    endpoint = proc.endpoint
    keys = Keys(ns)
    names = [f"t{i:05d}" for i in range(pos.shape[0])]
    index = {k: i for i, k in enumerate(names)}
    slot = {round(float(t), 6): k for k, t in enumerate(ts) if k % 2}
    out = np.full_like(pos, np.nan)
    t_end = ts[-1] if len(ts) % 2 == 0 else ts[-2]
    done = threading.Event()

    merge = Merge(hold=None, stale=None)  # the client library's picture: every instant

    def on_frame(s: Any) -> None:
        for pic in merge.add(Frame.from_payload(s.payload.to_bytes()), time.monotonic()):
            k = slot.get(round(pic.t, 6))
            if k is not None:
                for row, tid in enumerate(pic.id_list):
                    i = index.get(tid)
                    if i is not None:
                        out[i, k] = pic.pos[row]
            if pic.t >= t_end - 1e-6:
                done.set()

    session = zenoh.open(peer_config(endpoint))
    try:
        sub = session.declare_subscriber(keys.frame, zenoh.handlers.Callback(
            on_frame, indirect=False))
        if not wait_for_tracker(session, keys, 1, timeout=30):
            raise SystemExit(f"track-eval: no tracker on {endpoint}")
        enc, block = zenoh.Encoding(MSGPACK_ENCODING), zenoh.CongestionControl.BLOCK
        meas_keys = [zenoh.KeyExpr(keys.meas(SENSOR, k)) for k in names]
        for k in range(0, len(ts), 2):
            for i in np.flatnonzero(np.isfinite(pos[:, k]).all(1)).tolist():
                body = {"t": float(ts[k]), "pos": pos[i, k].tolist()}
                if sigma is not None:
                    body["sigma"] = sigma
                if sigma_t is not None:
                    body["sigma_t"] = float(sigma_t[i])
                session.put(meas_keys[i], pack(body), encoding=enc, congestion_control=block)
        session.put(keys.clock, pack({"t": float(ts[-1]) + 2.0}), encoding=enc,
                    congestion_control=block)
        if not done.wait(600):
            raise SystemExit("track-eval: the service did not publish the last frame")
        sub.undeclare()
    finally:
        session.close()
        proc.stop()
    return out


# ---------------------------------------------------------------- scores
def score(pred: np.ndarray, ref: np.ndarray, ts: np.ndarray, first: np.ndarray,
          where: np.ndarray | None = None, heading: np.ndarray | None = None
          ) -> dict[str, float]:
    """RMS and 95th percentile of the 3-D error at the held-out instants after each
    target's warm-up (`first`: each target's first time; `where` (N, K): only there),
    and, with `heading` (N, K, 3), the RMS along it, across it horizontally and
    vertically."""
    held = np.zeros(len(ts), bool)
    held[1::2] = True
    sel = held[None, :] & (ts[None, :] >= first[:, None] + WARMUP)
    if where is not None:
        sel = sel & where
    diff = (pred - ref)[sel]
    err = np.linalg.norm(diff, axis=-1)
    ok = np.isfinite(err)
    some = bool(ok.any())  # none: a part without instants (a feed without turns)
    out = {"rms": _rms(err[ok]),
           "p95": float(np.percentile(err[ok], 95)) if some else float("nan"),
           "n": int(ok.sum()), "missing": int((~ok).sum())}
    if heading is not None:
        along_u, across_u = _frame(heading[sel][ok])
        e = diff[ok]
        out |= {"along": _rms(np.sum(e * along_u, 1)),
                "across": _rms(np.sum(e * across_u, 1)), "vertical": _rms(e[:, 2])}
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")


def _frame(heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal unit vectors along (N, 3) and across the headings (N, 3)."""
    h = heading.copy()
    h[:, 2] = 0.0
    along = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    return along, np.column_stack([-along[:, 1], along[:, 0], np.zeros(len(h))])


def chord(pos: np.ndarray) -> np.ndarray:
    """The heading at each instant from the positions around it (N, K, 3)."""
    out = np.full_like(pos, np.nan)
    out[:, 1:-1] = pos[:, 2:] - pos[:, :-2]
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    sigma_t, turning, heading = None, None, None
    if args.recording:
        ts, pos, truth = recorded(args.recording)
    elif args.feed == "stamped":
        f = stamped.generate(args.aircraft, args.runs or 20, args.seed, args.duration)
        ts, pos, truth, turning, heading = f.ts, f.pos, f.truth, f.turning, f.vel
        if args.stated_sigma_t == "true":
            sigma_t = f.sigma_t
        elif args.stated_sigma_t != "absent":
            sigma_t = np.full(len(pos), float(args.stated_sigma_t))
    else:
        ts, pos, truth = generate(args.aircraft, args.runs or 20, args.seed, args.duration)
    if heading is None:
        heading = chord(pos)
    sigma = None if args.stated_sigma == "absent" else float(args.stated_sigma)
    first = ts[np.argmax(np.isfinite(pos).all(-1), axis=1)]
    preds = {"service": run_service(ts, pos, sigma, args.service_arg, sigma_t),
             "linear": linear(ts, pos),
             "cv filter": cv_filter(ts, pos, 1.0 if sigma is None else sigma, args.cv_q)}
    refs = {"held-out positions": pos} | ({} if truth is None else {"truth": truth})
    parts = {"": None} | ({} if turning is None else {" (turns)": turning,
                                                        " (straight)": ~turning})
    report = {r + part: {k: score(p, ref, ts, first, where, heading) for k, p in preds.items()}
              for r, ref in refs.items() for part, where in parts.items()}
    print(f"track-eval heldout: {pos.shape[0]} targets, {len(ts)} s, every other position "
          f"sent with sigma {args.stated_sigma}"
          + ("" if args.feed != "stamped" else f" and sigma_t {args.stated_sigma_t}")
          + f", the frame 1 s later scored; service options {args.service_arg or 'none'}")
    print(f"{'against':<32}{'predictor':<12}{'RMS, m':>9}{'p95, m':>9}{'RMS/lin':>8}"
          f"{'p95/lin':>8}{'along':>8}{'across':>8}{'vert.':>7}{'scored':>8}{'missing':>8}")
    for r, rows in report.items():
        lin = rows["linear"]
        for k, v in rows.items():
            print(f"{r:<32}{k:<12}{v['rms']:>9.2f}{v['p95']:>9.2f}"
                  f"{v['rms'] / lin['rms']:>8.3f}{v['p95'] / lin['p95']:>8.3f}"
                  f"{v['along']:>8.2f}{v['across']:>8.2f}{v['vertical']:>7.2f}"
                  f"{v['n']:>8}{v['missing']:>8}")
    sys.stdout.flush()
    return report


def add_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("heldout")
    g.add_argument("--aircraft", type=int, default=50, help="heldout: targets per run")
    g.add_argument("--duration", type=float, default=300.0, help="heldout: s per run")
    g.add_argument("--stated-sigma", default="0",
                   help="heldout: the sigma the feed states, m, or 'absent' (default 0)")
    g.add_argument("--cv-q", type=float, default=1.0,
                   help="heldout: the CV filter's white acceleration density, m/s^1.5")
    g.add_argument("--recording", help="heldout: an MCAP recording of a labelled feed")
    g.add_argument("--feed", choices=("jitter", "stamped"), default="jitter",
                   help="heldout: the generated feed: positions jittered (default) or "
                        "stamped with times that are not theirs (docs/timing.md)")
    g.add_argument("--stated-sigma-t", default="absent",
                   help="heldout, stamped feed: the sigma_t sent, s: 'absent' (default), "
                        "'true' (each aircraft's own) or a number")
