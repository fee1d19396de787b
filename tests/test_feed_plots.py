"""track-feed's unlabelled scenarios (crossing, multisensor, swarm --plots): the payloads
are plotgen's scans, truth and clock as the labelled feed sends them; `swarm` without
`--plots` is the labelled swarm as before."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from conftest import Collector

from zenoh_track.clients.feeds import feed, feed_plots, plotgen, scenarios
from zenoh_track.wire import MSGPACK_ENCODING, Keys, unpack


class Recorder:
    """Stands in for a zenoh.Session: records every put (and its encoding)."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []
        self.encodings: set[str] = set()

    def put(self, key: object, payload: bytes, congestion_control: object = None,
            encoding: object = None) -> None:
        self.puts.append((str(key), bytes(payload)))
        self.encodings.add(str(encoding))


def published(*argv: str) -> tuple[argparse.Namespace, int, list[tuple[str, bytes]]]:
    args = feed.parser().parse_args(list(argv))
    rec = Recorder()
    sent = feed.publish(rec, args)  # type: ignore[arg-type]
    assert rec.encodings == {MSGPACK_ENCODING}  # every put says what its payload is
    return args, sent, rec.puts


@pytest.mark.parametrize("argv", [
    ("crossing", "--targets", "6", "--scans", "12", "--clutter", "10", "--seed", "3"),
    ("multisensor", "--radars", "2", "--targets", "5", "--scans", "8", "--columnar"),
    ("swarm", "--plots", "--targets", "30", "--duration", "4", "--t0", "100"),
])
def test_payloads_are_plotgen_scans(argv):
    args, sent, puts = published(*argv, "--truth")
    sc = feed_plots.scenario(args)
    keys, expected = Keys(), []
    for scan in sc:
        scan = scan._replace(t=scan.t + args.t0)
        expected += [(keys.truth(k), {"t": scan.t, "pos": p.tolist(), "vel": v.tolist()})
                     for k, (p, v) in scan.truth.items()]
        expected.append((keys.plots(scan.sensor), sc.payload(scan, args.columnar)))
    expected.append((keys.clock, {"t": scan.t + sc.dt}))
    assert [k for k, _ in puts] == [k for k, _ in expected]
    for (_, got), (_, want) in zip(puts, expected, strict=True):
        assert got == want if isinstance(want, bytes) else unpack(got) == want
    assert sent == sum(len(s.dets) for s in sc)


def test_scenarios_follow_the_options():
    args = feed.parser().parse_args(["crossing", "--pd", "0.8", "--clutter", "5",
                                     "--sigma", "30", "--scans", "7", "--seed", "2"])
    sc = feed_plots.scenario(args)
    ref = plotgen.crossing(targets=20, pd=0.8, clutter=5.0, sigma=30.0, scans=7, seed=2)
    assert [s.dets.tolist() for s in sc] == [s.dets.tolist() for s in ref]
    ms = feed_plots.scenario(feed.parser().parse_args(["multisensor", "--radars", "2"]))
    assert len(ms.radars) == 2 and all(r.polar for r in ms.radars)
    assert [r.phase for r in ms.radars] == [0.0, 0.5] and len(ms.flyers.ids) == 20


def test_swarm_plots_are_the_swarm_targets():
    """The unlabelled swarm flies the labelled swarm's targets (horizontal plane)."""
    args = feed.parser().parse_args(["swarm", "--plots", "--targets", "40", "--seed", "5"])
    sc = feed_plots.scenario(args)
    assert sc.scans == 61 and len(sc.flyers.ids) == 40
    for _, _, truth in scenarios.swarm(40, 5, duration=3.0, sectors=4):
        for name, tr in truth:
            i = sc.flyers.ids.index(name)
            pos, vel = sc.flyers.at(tr["t"])
            assert np.allclose(pos[i], tr["pos"][:2], atol=1e-6)
            assert np.allclose(vel[i], tr["vel"][:2])


def test_swarm_without_plots_is_labelled():
    """`swarm` alone: labelled measurements with one seq counter, truth first, 100 targets
    by default, sectors as before; the clock one period after the last report."""
    args, sent, puts = published("swarm", "--duration", "2", "--truth")
    keys, expected, seq = Keys(), [], 0
    for t, meas, truth in scenarios.swarm(100, 0, 2.0, sectors=32):
        expected += [(keys.truth(k), feed.stamped(tr, t, 0.0)) for k, tr in truth]
        for k, m in meas:
            expected.append((keys.meas("radar1", k), feed.stamped(m, t, 0.0, seq=seq)))
            seq += 1
    expected.append((keys.clock, {"t": t + 1.0}))
    assert [k for k, _ in puts] == [k for k, _ in expected]
    assert [unpack(p) for _, p in puts] == [m for _, m in expected]
    assert sent == seq == 300 and not any("/plots/" in k for k, _ in puts)


def test_swarm_without_truth_sends_the_same_bytes():
    """Without `--truth` the swarm's measurements are made from columns (no truth maps
    made and thrown away): byte for byte what the run with truth sends, less the truth."""
    with_truth = published("swarm", "--duration", "2", "--truth", "--t0", "12.5")[2]
    plain = published("swarm", "--duration", "2", "--t0", "12.5")[2]
    assert plain == [(k, p) for k, p in with_truth if "/truth/" not in k]
    assert len(plain) == 301


@pytest.mark.slow
def test_feed_scans_reach_the_service(service_factory):
    """Over Zenoh: the scans the service's peers receive are plotgen's, every one is
    applied, and the feed confirmed receipt before it exited."""
    svc, s = service_factory("--clock", "lockstep", "--rate", "2")
    plots = Collector(s, svc.keys.plots("*"))
    argv = ("multisensor", "--radars", "2", "--targets", "6", "--scans", "10")
    svc.feed(*argv, "--columnar")
    sc = feed_plots.scenario(feed.parser().parse_args(list(argv)))
    want = [(svc.keys.plots(x.sensor), unpack(sc.payload(x, columnar=True))) for x in sc]
    assert plots.wait_for(lambda xs: len(xs) >= len(want), 30)
    assert [(k, b) for k, _, b in plots.samples] == want
    status = [unpack(r.ok.payload.to_bytes()) for r in s.get(svc.keys.status, timeout=10)
              if r.ok is not None][0]
    assert status["scans_applied"] == len(want) and status["meas_rejected"] == 0
