"""`track-service` / `python -m zenoh_track`: run one tracker instance."""

from __future__ import annotations

import argparse
import logging
import sys
import uuid
from typing import Any

from . import __version__, defaults, malloc  # noqa: F401 (malloc: glibc's arenas set

# up on import, before NumPy's import starts a thread)
from .adapter import TrackService
from .adapter.origin import OriginQueryable
from .estimation import jit
from .estimation.catalog import FILTERS, FilterSpec
from .tracking.compiled import KERNELS
from .tracking.display import DisplayConfig
from .tracking.plot_association import SensorModels
from .tracking.tracker import SCAN_ASSOCIATORS, Tracker, TrackerConfig
from .wire import (
    Keys,
    Origin,
    Rejected,
    add_zenoh_args,
    fail,
    on_signals,
    open_session,
    parse_origin,
    read_file,
)


def seconds(text: str) -> float:
    """An option's time: a finite number of seconds above zero."""
    value = float(text)
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: a number of seconds above 0")
    return value


def non_negative(text: str) -> float:
    """An option's finite number of at least 0 (a log-likelihood ratio, a noise)."""
    value = float(text)
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: a finite number of at least 0")
    return value


def tracker_config(args: argparse.Namespace) -> TrackerConfig:
    """The tracker's configuration from the options."""
    spec = FilterSpec(args.filter, args.q, args.imm_ct_q, args.imm_turn, args.imm_sojourn,
                      args.vdf_detect, args.vdf_settle, args.imm_onset,
                      args.imm_turn_estimated)
    m, n = confirm_rule(args.confirm)
    sensors = sensor_models(args)
    return TrackerConfig(filter=spec, init_speed=args.init_speed, init_accel=args.init_accel,
                         delete_after=args.delete_after,
                         display=DisplayConfig(rate=args.rate, blend=args.blend,
                                               blend_speed=args.blend_speed, lag=args.lag),
                         associator=args.associator, sensors=sensors,
                         gate_probability=args.gate, second_look=args.second_look,
                         stitch_reach=args.stitch_reach,
                         max_speed=args.max_speed, max_accel=args.max_accel,
                         confirm_m=m, confirm_n=n, confirm_score=args.confirm_score,
                         delete_misses=args.delete_misses, delete_sigma=args.delete_sigma)


def sensor_models(args: argparse.Namespace) -> SensorModels:
    """Pd and clutter density per sensor: the flags, and --sensors FILE.json over them
    (an unreadable or malformed file: one line and exit 2)."""
    if not args.sensors:
        return SensorModels(args.pd, args.clutter_density)
    text = read_file(args.sensors, "--sensors file")
    try:
        return SensorModels.from_json(text, args.pd, args.clutter_density)
    except (ValueError, TypeError, AttributeError) as exc:
        fail(f"--sensors {args.sensors}: not a JSON map of sensor -> {{pd, clutter_density}}"
             f" ({exc})")


def confirm_rule(text: str) -> tuple[int, int]:
    """`M/N` -> (M, N), 1 <= M <= N <= 16."""
    try:
        m, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise SystemExit(f"track-service: --confirm takes M/N, e.g. 3/5, not {text!r}") from None
    if not 1 <= m <= n <= 16:
        raise SystemExit(f"track-service: --confirm {text}: need 1 <= M <= N <= 16")
    return m, n


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-service", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--clock", choices=("realtime", "lockstep"), default=defaults.CLOCK,
                   help="display clock (default %(default)s)")
    p.add_argument("--rate", type=float, default=defaults.RATE, help="display rate, Hz")
    p.add_argument("--filter", choices=FILTERS, default=defaults.FILTER,
                   help="imm (default): IMM of a quiet CV, a nominal CV (--q), a CA and "
                        "three manoeuvre modes (coordinated turns at 3 deg/s both ways, a "
                        "55 m/s^2 CV) on converted measurements; cv: CMKF, nearly-constant "
                        "velocity; ca: CMKF, nearly-constant acceleration; ekf: EKF on polar "
                        "measurements, CV (baseline); vdf: variable-dimension CV/CA "
                        "(scenario C's method)")
    p.add_argument("--imm-ct-q", type=float, default=defaults.IMM_CT_Q,
                   help="IMM: the turn modes' noise as a multiple of --q (with --imm-turn)")
    p.add_argument("--imm-turn", type=float, default=defaults.IMM_TURN_DEG,
                   help="IMM: add coordinated-turn modes at +- this rate, deg/s, chained "
                        "with the nominal mode as the CA mode is (default 0: none; the "
                        "manoeuvre modes turn at 3 deg/s whatever this)")
    p.add_argument("--imm-turn-estimated", type=non_negative, default=defaults.IMM_TURN_ESTIMATED,
                   metavar="JERK",
                   help="IMM: add a manoeuvre mode that turns at the rate of its own velocity "
                        "and acceleration (any rate, any plane), with this white jerk, m/s^3 "
                        "(5: 5-7 %% closer in 4 g and climbing turns for 1.2 x the filter's CPU "
                        "and a little straight-line accuracy (scenario B: 1.051 x its bound); "
                        "docs/accuracy.md; default 0: none)")
    p.add_argument("--imm-sojourn", type=seconds, default=defaults.IMM_SOJOURN,
                   help="IMM: mean time in the quiet and in the nominal mode, s (staying "
                        "probability exp(-dt/sojourn); default %(default)s)")
    p.add_argument("--imm-onset", type=seconds, default=defaults.IMM_ONSET, metavar="SECONDS",
                   help="IMM: 1 / the rate of entering the manoeuvre modes, s; smaller "
                        "reacts to a turn's first scans sooner and keeps the covariance "
                        "honest while manoeuvring, at the price of noisier straight flight "
                        "(docs/accuracy.md, 'Manoeuvres'; default %(default)s)")
    p.add_argument("--vdf-detect", type=float, default=defaults.VDF_DETECT,
                   help="VDF detection threshold")
    p.add_argument("--vdf-settle", type=float, default=defaults.VDF_SETTLE,
                   help="VDF return threshold")
    p.add_argument("--q", type=float, default=None,
                   help=f"process noise per axis (a continuous white noise of density "
                        f"q^2 |dt| over a step dt): m/s^2 for cv and the imm's nominal mode "
                        f"(default {defaults.Q_CV}), m/s^3 for ca (default {defaults.Q_CA})")
    p.add_argument("--init-speed", type=float, default=defaults.INIT_SPEED,
                   help="prior velocity std at initiation, m/s")
    p.add_argument("--init-accel", type=float, default=defaults.INIT_ACCEL,
                   help="prior acceleration std at initiation (ca), m/s^2")
    p.add_argument("--delete-after", type=float, default=defaults.DELETE_AFTER,
                   help="delete a track after this many seconds without a measurement")
    p.add_argument("--sr", type=float, default=defaults.SR, help="default range noise std, m")
    p.add_argument("--saz", type=float, default=defaults.SAZ,
                   help="default azimuth noise std, rad")
    p.add_argument("--sel", type=float, default=defaults.SEL,
                   help="default elevation noise std, rad")
    p.add_argument("--sigma", type=float, default=defaults.SIGMA,
                   help="default Cartesian noise std, m")
    p.add_argument("--blend-speed", type=float, default=defaults.BLEND_SPEED, metavar="M/S",
                   help="when a correction lands, absorb it into the drawn position at this "
                        "speed relative to the track instead of stepping: every frame moves "
                        "at most SPEED / --rate beyond the track's own motion, and a "
                        "correction of d metres takes d / SPEED seconds (0: off; default)")
    p.add_argument("--blend", type=float, default=defaults.BLEND, metavar="SECONDS",
                   help="absorb each correction over this period instead of stepping; with "
                        "--blend-speed, the longest a correction may take (0: plain "
                        "prediction, the contract's lockstep semantics; default)")
    p.add_argument("--lag", type=float, default=defaults.LAG, metavar="SECONDS",
                   help="publish frames for now - lag, smoothed between the two filtered "
                        "states that bracket the instant (accuracy rather than latency)")
    p.add_argument("--no-display-keys", action="store_true",
                   help="publish only the `frame` key, never per-target display/<id> keys "
                        "(by default display/<id> goes out for the tracks someone "
                        "subscribes to, and for no other)")
    p.add_argument("--meas", action="append", default=[], metavar="KEYEXPR",
                   help="measurement key expression(s) this instance tracks (repeatable; "
                        "default <ns>/meas/**): a shard takes its part of the key space, "
                        "e.g. 'track/meas/radar-a/**' or 'track/meas/*/swarm-0$*'")
    p.add_argument("--scan", action="append", default=[], metavar="KEYEXPR",
                   help="batched labelled scan key expression(s) this instance takes "
                        "(repeatable; default <ns>/scan/*): shards partition them by sensor")
    g = p.add_argument_group("unlabelled scans (<ns>/plots/<sensor>)")
    g.add_argument("--plots", action="append", default=[], metavar="KEYEXPR",
                   help="scan key expression(s) this instance tracks (repeatable; default "
                        "<ns>/plots/*): shards partition scans by sensor")
    g.add_argument("--associator", choices=tuple(SCAN_ASSOCIATORS), default=defaults.ASSOCIATOR,
                   help="gnn: global nearest neighbour (default); jpda: joint probabilistic "
                        "data association")
    g.add_argument("--pd", type=float, default=defaults.PD,
                   help="detection probability of every sensor (default %(default)s)")
    g.add_argument("--clutter-density", type=float, default=defaults.CLUTTER_DENSITY,
                   metavar="PER_M2", help="false detections per m^2 (2-D) or m^3 (3-D) "
                                          "(default: estimated from the scans)")
    g.add_argument("--sensors", metavar="FILE.json",
                   help='per-sensor settings: {"radar1": {"pd": 0.9, "clutter_density": '
                        '2e-7}, ...}; the flags give the rest')
    g.add_argument("--gate", type=float, default=defaults.GATE_PROBABILITY,
                   metavar="PROBABILITY", help="chi-square gate probability "
                                               "(default %(default)s)")
    g.add_argument("--second-look", type=non_negative, default=defaults.SECOND_LOOK,
                   metavar="LN_RATIO", help="a confirmed track whose detection beats a miss "
                   "by less than this log-likelihood ratio keeps its miss branch, and the "
                   "next scan chooses (0: off; default %(default)s)")
    g.add_argument("--max-speed", type=float, default=defaults.MAX_SPEED,
                   help="m/s: fastest target (the speed gate of confirmed tracks); a new "
                        "track's velocity prior has std a third of it per axis (default "
                        "%(default)s)")
    g.add_argument("--max-accel", type=non_negative, default=defaults.MAX_ACCEL,
                   metavar="M_S2", help="an aircraft's hardest manoeuvre: a detection or "
                   "an update beyond it from a track's extrapolation waits for a second "
                   "look, and a lost track is continued within it (default %(default)s = "
                   "10 g)")
    g.add_argument("--stitch-reach", type=non_negative, default=None,
                   metavar="M_S2", help="a track confirmed within an aircraft's reach at "
                   "this acceleration of one confirmed track that missed every scan it "
                   "took (and no other) continues that track's id (0: off; default: "
                   "--max-accel)")
    g.add_argument("--confirm", default=f"{defaults.CONFIRM_M}/{defaults.CONFIRM_N}",
                   metavar="M/N", help="confirm a track detected in M of its last N scans "
                                       "(default %(default)s) ...")
    g.add_argument("--confirm-score", type=float, default=defaults.CONFIRM_SCORE,
                   help="... whose track score (log-likelihood ratio) reached this "
                        "(default %(default)s = ln 100)")
    g.add_argument("--delete-misses", type=int, default=defaults.DELETE_MISSES,
                   help="delete a confirmed track after this many missed scans in a row "
                        "at Pd 0.9, or as many as are as unlikely at its sensors' Pd (12 at "
                        "0.7), a detection between them taking back ln(Pd/0.1) of their "
                        "evidence (default %(default)s)")
    g.add_argument("--delete-sigma", type=float, default=defaults.DELETE_SIGMA,
                   help="m: delete a track whose position sigma exceeds this")
    g.add_argument("--reorder", type=float, default=defaults.REORDER, metavar="SECONDS",
                   help="how long a scan waits for older scans of other sensors, s of "
                        "simulation time (default %(default)s)")
    p.add_argument("--state", metavar="PATH",
                   help="keep the track table in this file: a checkpoint every "
                        "--state-period s and at SIGTERM/SIGINT, read back at start "
                        "(docs/operations.md)")
    p.add_argument("--state-period", type=float, default=defaults.STATE_PERIOD,
                   metavar="SECONDS", help="seconds between checkpoints (default %(default)s)")
    p.add_argument("--max-jump", type=float, default=defaults.MAX_JUMP, metavar="SECONDS",
                   help="refuse an input more than this from the picture's time, unless "
                        f"{defaults.NEW_TIMELINE} such come in a row (a new timeline; "
                        "default %(default)s s)")
    p.add_argument("--origin", metavar="LAT,LON,ALT",
                   help="the deployment's geodetic frame: positions are East-North-Up metres "
                        "about this WGS-84 point (degrees, degrees, metres above the "
                        "ellipsoid), answered on <ns>/origin to gateways and displays "
                        "(default: a local frame without geodetic meaning)")
    p.add_argument("--instance", default=None, help="liveliness instance name")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def origin_option(text: str | None) -> Origin | None:
    """`--origin`, or one line and exit 2."""
    try:
        return None if text is None else parse_origin(text)
    except Rejected as exc:
        fail(f"--origin {text}: {exc}")


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    stop = on_signals()  # first: before Zenoh or anything else starts a thread
    origin = origin_option(args.origin)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    tracker = Tracker.from_config(tracker_config(args))
    # lockstep drops nothing: BLOCK puts wait for a slow subscriber. Opened before the
    # kernels are compiled: a refused or unreachable router is said at once
    with stop.interrupting():
        session = open_session(args, serve=True, block=args.clock == "lockstep",
                               stamp=True)
    try:
        with stop.interrupting():  # stopped while starting: nothing taken, nothing to save
            svc, origin_answer = start(args, session, tracker, origin)
    except SystemExit:
        session.close()
        raise
    logging.getLogger("track-service").info("running: ns=%s clock=%s", args.ns, args.clock)
    print(f"track-service {__version__}: ns={args.ns} clock={args.clock} rate={args.rate} Hz",
          flush=True)
    stop.wait()
    # the worker stops, the final checkpoint is written, then the session closes; a close
    # that blocks on data queued for a vanished peer (lockstep BLOCK) is cut short by the
    # stop's deadline (wire.STOP_GRACE)
    origin_answer.close()
    svc.close()
    session.close()


def start(args: argparse.Namespace, session: Any, tracker: Tracker,
          origin: Origin | None) -> tuple[TrackService, OriginQueryable]:
    """The kernels ready (lockstep) or compiling (realtime), the origin answered, the state
    file read back, the service started."""
    # the compiled kernels: a realtime service is alive at once on their NumPy forms and
    # takes the compiled ones when ready (a machine's first start compiles them in a child
    # process); lockstep outputs are a function of the inputs alone, so it waits for them
    jit.prepare(KERNELS, wait=args.clock == "lockstep", say=lambda line: print(
        f"track-service: {line}", file=sys.stderr, flush=True))
    # answered before the liveliness token is declared: a client that sees the service
    # alive can ask its origin
    origin_answer = OriginQueryable(session, Keys(args.ns), origin)
    svc = TrackService(session, Keys(args.ns), tracker, clock=args.clock,
                       instance=args.instance or uuid.uuid4().hex[:8],
                       noise=(args.sr, args.saz, args.sel, args.sigma),
                       per_target_display=not args.no_display_keys,
                       meas_keys=args.meas or None, plot_keys=args.plots or None,
                       scan_keys=args.scan or None,
                       reorder=args.reorder, max_jump=args.max_jump,
                       state=args.state, state_period=args.state_period, origin=origin)
    if svc.state is not None:
        print(f"track-service: {svc.state.restore(svc.restore)}", file=sys.stderr, flush=True)
    return svc.start(), origin_answer


if __name__ == "__main__":
    main()
