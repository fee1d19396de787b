"""The unlabelled-scan scenarios of `track-feed` (`<ns>/plots/<sensor>`), built with
`zenoh_track.clients.feeds.plotgen` from the feed's options.

- `crossing`: N straight flyers crossing near the origin, one Cartesian radar
  (`plotgen.crossing`).
- `multisensor`: the same flyers seen by 2 or 3 polar 2-D radars at different positions
  and scan phases (`plotgen.multisensor`; `--sigma` is their range noise, `--saz`
  their azimuth noise).
- `manoeuvres`: aircraft flying straight, standard-rate, 4 g, 7 g S-turns and climbing
  turns, one 3-D radar (`zenoh_track.clients.feeds.manoeuvres`); `--labelled` sends the same
  detections
  of the aircraft as labelled measurements (no clutter) instead.
- `swarm --plots`: the targets of the labelled `swarm` scenario (same seed, same
  positions, speeds and headings), in the horizontal plane, scanned whole once per
  turn by one Cartesian radar at the origin with Pd and clutter. A plots scan has one
  time, so a turn is one scan at k s: sending sectors would count every track outside
  the sector as missed.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from zenoh_track.clients.feeds import manoeuvres, plotgen, scenarios

SCENARIOS = ("crossing", "multisensor")  # plots only; swarm is labelled unless --plots
TARGETS = {"crossing": 20, "multisensor": 20, "swarm": 100}  # default --targets


def add_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("unlabelled scans (crossing, multisensor, swarm --plots)")
    g.add_argument("--plots", action="store_true",
                   help="swarm: publish the targets as unlabelled scans on <ns>/plots/<sensor>")
    g.add_argument("--pd", type=float, default=0.9, help="detection probability")
    g.add_argument("--clutter", type=float, default=None,
                   help="mean false detections per scan of one radar (Poisson, uniform; "
                        "default 20, manoeuvres 10)")
    g.add_argument("--sigma", type=float, default=25.0,
                   help="m: Cartesian noise per axis (multisensor: range noise)")
    g.add_argument("--saz", type=float, default=0.002, help="multisensor: azimuth noise, rad")
    g.add_argument("--scans", type=int, default=100, help="scans per radar (not swarm)")
    g.add_argument("--radars", type=int, choices=(2, 3), default=3, help="multisensor")
    g.add_argument("--period", type=float, default=1.0, help="manoeuvres: scan period, s")
    g.add_argument("--per-class", type=int, default=2,
                   help="manoeuvres: aircraft of each class")
    g.add_argument("--classes", type=classes, default=manoeuvres.CLASSES,
                   help="manoeuvres: the classes, comma-separated (default "
                        f"{','.join(manoeuvres.CLASSES)}; also "
                        f"{','.join(manoeuvres.SLOW_CLASSES)})")
    g.add_argument("--labelled", action="store_true",
                   help="manoeuvres: labelled measurements on <ns>/meas/ instead of scans")
    g.add_argument("--columnar", action="store_true",
                   help="send scans in the columnar form (bins) instead of a list of dets")


def classes(text: str) -> tuple[str, ...]:
    """`--classes`: names of the manoeuvres scenario's classes, comma-separated."""
    out = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in out if c not in manoeuvres.CLASSES + manoeuvres.SLOW_CLASSES]
    if bad or not out:
        raise argparse.ArgumentTypeError(
            f"unknown class {', '.join(bad) or '(none)'}; one of "
            f"{', '.join(manoeuvres.CLASSES + manoeuvres.SLOW_CLASSES)}")
    return out


def is_plots(args: argparse.Namespace) -> bool:
    """Whether the feed's scenario is sent as unlabelled scans."""
    return (args.scenario in SCENARIOS or (args.scenario == "swarm" and args.plots)
            or (args.scenario == "manoeuvres" and not args.labelled))


def targets(args: argparse.Namespace) -> int:
    return TARGETS[args.scenario] if args.targets is None else args.targets


def clutter(args: argparse.Namespace) -> float:
    return (10.0 if args.scenario == "manoeuvres" else 20.0) if args.clutter is None \
        else args.clutter


def scenario(args: argparse.Namespace) -> Any:
    """The scenario the feed's options describe (a `plotgen.Scenario`, or for
    `manoeuvres` a `manoeuvres.Manoeuvres`: the same scans, polar 3-D)."""
    if args.scenario == "manoeuvres":
        return manoeuvres.Manoeuvres(args.period, args.pd, clutter(args), args.per_class,
                                     args.seed, sensor=args.sensor, classes=args.classes)
    n = targets(args)
    if args.scenario == "crossing":
        return plotgen.crossing(targets=n, pd=args.pd, clutter=clutter(args), sigma=args.sigma,
                                scans=args.scans, seed=args.seed, sensor=args.sensor)
    if args.scenario == "multisensor":
        return plotgen.multisensor(targets=n, radars=args.radars, pd=args.pd,
                                   clutter=clutter(args), sr=args.sigma, saz=args.saz,
                                   scans=args.scans, seed=args.seed)
    if args.scenario == "swarm":
        return swarm(n, args.seed, args.duration, args.pd, clutter(args), args.sigma,
                     args.sensor)
    raise ValueError(f"{args.scenario} has no unlabelled form")


def swarm(targets: int, seed: int, duration: float, pd: float, clutter: float,
          sigma: float, sensor: str = "radar1") -> plotgen.Scenario:
    """The labelled swarm's targets (its first turn's truth, taken back to t = 0) in the
    horizontal plane, one Cartesian scan a second from 0 to `duration`."""
    _, _, truth = next(scenarios.swarm(targets, seed, duration=0.0, sectors=1))
    ids = [name for name, _ in truth]
    pos = np.array([tr["pos"][:2] for _, tr in truth])
    vel = np.array([tr["vel"][:2] for _, tr in truth])
    t = np.array([tr["t"] for _, tr in truth])
    flyers = plotgen.Flyers(ids, pos - vel * t[:, None], vel)
    scans = int(duration) + 1
    half_width = plotgen._region(flyers, scans - 1.0, 3 * sigma, None)
    return plotgen.Scenario(flyers, [plotgen.Radar(sensor, (0.0, 0.0, 0.0))], scans, 1.0, pd,
                            clutter, half_width, sigma=sigma, seed=seed)
