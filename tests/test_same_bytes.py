"""Behaviour kept: a lockstep service publishes the same `tracks/`, `frame` and `errors/`
messages for the same inputs, run after run and change after change.

Four runs through real processes on loopback (a labelled feed, a batched `scan/` feed, an
unlabelled crossing on `plots/`, a multisensor run), each into a fresh lockstep service;
every output sample is kept per key in the order it arrived (one publisher per key keeps
its order) and the keys are taken in sorted order, so the digest does not depend on how
the samples of different keys interleaved. `errors/` bodies carry the wall time of the
rejection (`t_wall`), which is left out. Every message is decoded: everything in it that
is not a float (keys, ids, statuses, counts, lengths, the order of the messages) is hashed
exactly, and its floats (float64 bins included) are kept as one weighted sum per message,
compared to 1e-9. Not to the bit: the compiled kernels and NumPy may round the last bit
differently on another CPU or library version (the same inputs gave other bytes on
another machine), which says nothing about the service. Any change of behaviour, a track
more or less, another association, a filter moved by more than a nanometre in a
kilometre, fails it. The references are in tests/data/same_bytes.json (hashes) and
tests/data/same_bytes.npz (the sums).

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

import numpy as np
import pytest
import zenoh

from zenoh_track.wire import f64_bin, pack, unpack

pytestmark = pytest.mark.slow
DIGESTS = Path(__file__).parent / "data" / "same_bytes.json"
SUMS = DIGESTS.with_suffix(".npz")
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

    def digest(self) -> tuple[str, np.ndarray]:
        """The hash of every message's non-float content and one weighted sum of each
        message's floats, in key order, then arrival order."""
        h, sums = hashlib.sha256(), []
        with self.cond:
            for key in sorted(self.per_key):
                for kind, payload in self.per_key[key]:
                    body = unpack(payload) if payload else None
                    if key.split("/")[1] == "errors":
                        del body["t_wall"]  # the wall time of the rejection
                    elif key.split("/")[1] == "frame":
                        assert body.pop("instance")  # a random name per run
                    floats: list[np.ndarray] = []
                    h.update(f"{key}\0{kind}\0{shape(body, floats)}\0".encode())
                    x = np.concatenate(floats) if floats else np.zeros(0)
                    sums.append(float(np.dot(x, 1.0 + (np.arange(len(x)) % 7) / 7.0)))
        return h.hexdigest(), np.array(sums)


def shape(v: object, floats: list[np.ndarray], key: object = None) -> str:
    """The value with each float replaced by `f` (and gathered into `floats`, a float64
    bin as its array): an exact text of everything else."""
    if isinstance(v, float):
        floats.append(np.array([v]))
        return "f"
    if isinstance(v, bytes):  # the wire's bins: float64 but the frame's status bytes
        if key == "status":
            return v.hex()
        floats.append(np.frombuffer(v, "<f8"))
        return f"b{len(v)}"
    if isinstance(v, dict):
        return "{" + ",".join(f"{k!r}:{shape(v[k], floats, k)}"
                              for k in sorted(v, key=str)) + "}"
    if isinstance(v, list | tuple):
        return "[" + ",".join(shape(x, floats, key) for x in v) + "]"
    return repr(v)


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
        ) -> tuple[str, np.ndarray]:
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
    digest, sums = run(service_factory, *RUNS[name])
    known = json.loads(DIGESTS.read_text()) if DIGESTS.exists() else {}
    known_sums = dict(np.load(SUMS)) if SUMS.exists() else {}
    if request.config.getoption("--update-digests"):
        known[name], known_sums[name] = digest, sums
        DIGESTS.parent.mkdir(exist_ok=True)
        DIGESTS.write_text(json.dumps(dict(sorted(known.items())), indent=1) + "\n")
        np.savez_compressed(SUMS, **known_sums)
        return
    again = "if on purpose, regenerate with `python -m pytest tests/test_same_bytes.py " \
            "--update-digests`"
    assert name in known and name in known_sums, f"no reference for {name}: {again}"
    assert digest == known[name], f"{name}: the service's outputs changed; {again}"
    np.testing.assert_allclose(sums, known_sums[name], rtol=1e-9, atol=1e-6,
                               err_msg=f"{name}: the service's numbers changed; {again}")
