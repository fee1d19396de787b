"""The ingest stage's typed inputs (service/adapter/ingest.py): a run of single messages
cut at a count of messages and joined again keeps every message once, in order."""

from __future__ import annotations

from zenoh_track.adapter.ingest import ClockMessage, LabelledScan, Plots, Query, Singles, cut, size


def run(lo: int, hi: int) -> Singles:
    return Singles([f"k{i}" for i in range(lo, hi)], [bytes([i % 256]) for i in range(lo, hi)],
                   [float(i) for i in range(lo, hi)])


def flat(items: list) -> list:
    out = []
    for it in items:
        out += [(k, p, w) for k, p, w in zip(it.keys, it.payloads, it.walls, strict=True)] \
            if isinstance(it, Singles) else [it]
    return out


def test_cut_takes_n_messages_splitting_a_run_where_n_falls():
    clock = ClockMessage("ns/clock", b"c", 9.0)
    items = [run(0, 5), clock, run(5, 12), Plots("ns/plots/r", b"p", 3.0)]
    assert [size(i) for i in items] == [5, 1, 7, 1]
    for n in range(0, 16):
        head, rest = cut(items, n)
        assert sum(map(size, head)) == min(n, 14)
        assert flat(head) + flat(rest) == flat(items)  # every message once, in order
    head, rest = cut(items, 8)
    assert flat(head)[-1] == ("k6", bytes([6]), 6.0) and flat(rest)[0] == ("k7", bytes([7]), 7.0)
    assert cut(items, 6) == ([items[0], clock], items[2:])  # no run split on a boundary


def test_a_run_joined_from_pieces_is_the_run():
    whole = run(0, 9)
    a, b = whole.cut(4)
    assert (len(a), len(b)) == (4, 5)
    assert Singles.joined([a, b]) == whole
    assert Singles.joined(whole.each()) == whole and len(whole.each()) == 9
    assert Singles.joined([whole]) is whole
    assert Singles.one("k", b"x", 1.0) == Singles(["k"], [b"x"], [1.0])


def test_every_input_names_its_key():
    q = Query("status", type("Q", (), {"key_expr": "ns/status"})())
    assert [i.key for i in (run(3, 5), LabelledScan("ns/scan/r", b"", 0.0), q)] == [
        "k3", "ns/scan/r", "ns/status"]
