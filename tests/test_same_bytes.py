"""Behaviour to the bit: a lockstep service publishes the same `tracks/`, `frame` and
`errors/` bytes for the same inputs, run after run and change after change.

Four runs through real processes on loopback (a labelled feed, a batched `scan/` feed, an
unlabelled crossing on `plots/`, a multisensor run), each into a fresh lockstep service;
every output sample is kept per key in the order it arrived (one publisher per key keeps
its order) and the keys are taken in sorted order, so the digest does not depend on how
the samples of different keys interleaved. `errors/` bodies carry the wall time of the
rejection (`t_wall`), which is left out of the digest; everything else is hashed byte for
byte. The digests are in tests/data/same_bytes.json.

A change that alters the tracker's output on purpose (a new default filter, a fix) makes
this test fail; regenerate the digests then, and say why in the commit:

    .venv/bin/python -m pytest tests/test_same_bytes.py --update-digests
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections import defaultdict
from pathlib import Path

import pytest
import zenoh

from zenoh_track.wire import f64_bin, pack, unpack

pytestmark = pytest.mark.slow
DIGESTS = Path(__file__).parent / "data" / "same_bytes.json"
BLOCK = zenoh.CongestionControl.BLOCK
OUTPUTS = ("track/tracks/**", "track/frame", "track/errors/**")


class Outputs:
    """Every `tracks/`, `frame` and `errors/` sample, per key, in arrival order."""

    def __init__(self, session: zenoh.Session) -> None:
        self.cond = threading.Condition()
        self.per_key: dict[str, list[tuple[str, bytes]]] = defaultdict(list)
        self.subs = [session.declare_subscriber(k, zenoh.handlers.Callback(
            self._on, indirect=False)) for k in OUTPUTS]

    def _on(self, s: zenoh.Sample) -> None:
        kind = "put" if s.kind == zenoh.SampleKind.PUT else "delete"
        with self.cond:
            self.per_key[str(s.key_expr)].append((kind, s.payload.to_bytes()))
            self.cond.notify_all()

    def counts(self) -> dict[str, int]:
        """Samples received: frames, tracks/ puts and deletes, errors."""
        c = {"frame": 0, "put": 0, "delete": 0, "errors": 0}
        for key, samples in self.per_key.items():
            what = key.split("/")[1]
            if what == "tracks":
                for kind, _ in samples:
                    c[kind] += 1
            else:
                c[what] += len(samples)
        return c

    def wait_for(self, want: dict[str, int], timeout: float = 60.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: self.counts() == want, timeout)

    def digest(self) -> str:
        h = hashlib.sha256()
        with self.cond:
            for key in sorted(self.per_key):
                for kind, payload in self.per_key[key]:
                    if key.split("/")[1] == "errors":
                        body = unpack(payload)
                        del body["t_wall"]  # the wall time of the rejection
                        payload = pack(dict(sorted(body.items())))
                    h.update(f"{key}\0{kind}\0{len(payload)}\0".encode())
                    h.update(payload)
        return h.hexdigest()


def status(s: zenoh.Session) -> dict:
    replies = [r for r in s.get("track/status", timeout=10) if r.ok is not None]
    assert replies, "no status reply"
    return unpack(replies[0].ok.payload.to_bytes())


def bad_singles(s: zenoh.Session, target: str, end: float) -> None:
    """Inputs the service refuses, after the feed (which ended at `end`): the parser's
    and the tracker's reasons (a missing field, a bad key, a 3-D measurement for a 2-D
    track, a time before the track's last update)."""
    for key, body in ((f"track/meas/radar1/{target}", {"r": 1000.0, "az": 0.1}),
                      ("track/meas/radar1/a/b", {"t": end, "r": 1000.0, "az": 0.1}),
                      (f"track/meas/radar9/{target}", {"t": end, "r": 1000.0, "az": 0.1,
                                                       "el": 0.1}),
                      (f"track/meas/radar1/{target}", {"t": end - 100.0, "pos": [1.0, 2.0]})):
        s.put(key, pack(body), congestion_control=BLOCK)


def bad_scan(s: zenoh.Session, target: str, end: float) -> None:
    """A batched scan with one good row and one out-of-range row."""
    s.put("track/scan/radar1", pack({"t": end, "ids": [target, "x-bad"],
                                     "r": f64_bin([5000.0, -1.0]), "az": f64_bin([0.1, 0.1]),
                                     "el": f64_bin([0.01, 0.01])}), congestion_control=BLOCK)


RUNS = {
    "labelled": (("maneuver", "--runs", "4"), bad_singles, "maneuver-000", 802.0),
    "batched": (("swarm", "--targets", "30", "--duration", "12", "--batched"), bad_scan,
                "swarm-0000", 12.5),
    "unlabelled": (("crossing", "--targets", "8", "--scans", "30"), None, None, 0.0),
    "multisensor": (("multisensor", "--targets", "8", "--scans", "25"), None, None, 0.0),
}


def run(service_factory, feed: tuple[str, ...], bad, target: str | None, end: float
        ) -> str:
    svc, s = service_factory("--clock", "lockstep")
    out = Outputs(s)
    svc.feed(*feed)
    if bad is not None:
        bad(s, target, end)
    st = status(s)
    want = {"frame": st["frames_published"], "put": st["tracks_puts"],
            "delete": st["tracks_deleted"], "errors": st["meas_rejected"]}
    assert out.wait_for(want), (out.counts(), want)
    assert want["put"] > 0 and want["frame"] > 0
    return out.digest()


@pytest.mark.parametrize("name", list(RUNS))
def test_same_bytes(name, service_factory, request):
    digest = run(service_factory, *RUNS[name])
    known = json.loads(DIGESTS.read_text()) if DIGESTS.exists() else {}
    if request.config.getoption("--update-digests"):
        known[name] = digest
        DIGESTS.parent.mkdir(exist_ok=True)
        DIGESTS.write_text(json.dumps(dict(sorted(known.items())), indent=1) + "\n")
        return
    assert name in known, f"no digest for {name}: run with --update-digests"
    assert digest == known[name], (
        f"{name}: the service's output bytes changed; if on purpose, regenerate with "
        "`python -m pytest tests/test_same_bytes.py --update-digests`")
