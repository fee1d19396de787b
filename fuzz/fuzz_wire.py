"""Coverage-guided fuzzing of the input decoders and validators (service/wire) with
atheris (`pip install -e '.[fuzz]'`; docs/robustness.md):

    python fuzz/fuzz_wire.py -max_total_time=600 -rss_limit_mb=2048 fuzz/corpus fuzz/seeds
    python -m coverage run fuzz/fuzz_wire.py --replay fuzz/corpus fuzz/seeds  # line coverage

Each input is read two ways: as raw bytes handed to every parser (`parse_measurement`,
`parse_plots`, `parse_clock`), and as a map built field by field from the input (the
contract's field names with values of any type, including NaN, infinities, huge and
tiny numbers, bins, nested maps and lists) and then packed. The promises checked:

- a parser returns or raises `Rejected`; anything else is a crash;
- every rejection's reason has a documented code (`reason_code` is never `other`);
- what is accepted is within the documented limits: finite, inside `keys.BOUNDS`,
  dimension 2 or 3, a scan's kept and refused detections together cover it once.
"""

from __future__ import annotations

import math
import sys

import atheris

with atheris.instrument_imports():
    import msgpack

    from zenoh_track.wire import (
        BOUNDS,
        MAX_ROWS,
        Rejected,
        parse_clock,
        parse_measurement,
        parse_plots,
        reason_code,
    )

NOISE = (10.0, 0.0087, 0.0087, 1.0)
FIELDS = ["t", "r", "az", "el", "sr", "saz", "sel", "sigma", "pos", "sensor_pos", "seq",
          "dets", "dim", "note"]


def value(fdp: atheris.FuzzedDataProvider, depth: int = 0) -> object:
    kind = fdp.ConsumeIntInRange(0, 9 if depth < 2 else 5)
    if kind == 0:
        return fdp.ConsumeFloat()  # NaN, infinities, extremes included
    if kind == 1:
        return fdp.ConsumeIntInRange(-2**63, 2**63 - 1)
    if kind == 2:
        return fdp.ConsumeBool()
    if kind == 3:
        return fdp.ConsumeUnicodeNoSurrogates(fdp.ConsumeIntInRange(0, 8))
    if kind == 4:
        return fdp.ConsumeBytes(8 * fdp.ConsumeIntInRange(0, 6) + fdp.ConsumeIntInRange(0, 1))
    if kind == 5:
        return None
    if kind in (6, 7):
        return [value(fdp, depth + 1) for _ in range(fdp.ConsumeIntInRange(0, 4))]
    if kind == 8:
        return [fdp.ConsumeRegularFloat() for _ in range(fdp.ConsumeIntInRange(0, 4))]
    return {fdp.PickValueInList(FIELDS): value(fdp, depth + 1)
            for _ in range(fdp.ConsumeIntInRange(0, 4))}


def structured(fdp: atheris.FuzzedDataProvider) -> bytes:
    msg = {fdp.PickValueInList(FIELDS): value(fdp) for _ in range(fdp.ConsumeIntInRange(0, 8))}
    try:
        return msgpack.packb(msg, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return b""


def in_bounds(name: str, v: float) -> bool:
    lo, hi = BOUNDS[name]
    return math.isfinite(v) and lo <= v <= hi


def check_measurement(m) -> None:  # noqa: ANN001
    assert m.dim in (2, 3) and len(m.values) == m.dim and len(m.sigmas) == m.dim, m
    assert in_bounds("t", m.t), m
    names = ("r", "az", "el")[:m.dim] if m.polar else ("pos",) * m.dim
    noise = ("sr", "saz", "sel")[:m.dim] if m.polar else ("sigma",) * m.dim
    assert all(in_bounds(n, v) for n, v in zip(names, m.values, strict=True)), m
    assert all(in_bounds(n, v) for n, v in zip(noise, m.sigmas, strict=True)), m
    assert all(in_bounds("sensor_pos", v) for v in m.sensor_pos), m


def rejected(exc: Rejected) -> None:
    assert reason_code(str(exc)) != "other", str(exc)


def one(payload: bytes) -> None:
    try:
        check_measurement(parse_measurement("radar-1", "tgt", payload, NOISE))
    except Rejected as exc:
        rejected(exc)
    try:
        scan = parse_plots("radar-1", payload, NOISE)
    except Rejected as exc:
        rejected(exc)
    else:
        assert in_bounds("t", scan.t)
        for m in scan.detections:
            check_measurement(m)
        rows = sorted([*scan.index, *(i for i, _ in scan.rejected)])
        assert rows == list(range(len(rows))) and len(rows) <= MAX_ROWS, scan
        for _, reason in scan.rejected:
            assert reason_code(reason) != "other", reason
    try:
        assert in_bounds("t", parse_clock(payload))
    except Rejected as exc:
        rejected(exc)


def test_one_input(data: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(data)
    if fdp.ConsumeBool():
        one(fdp.ConsumeBytes(fdp.remaining_bytes()))
    else:
        one(structured(fdp))


def replay(dirs: list[str]) -> None:
    """Run every file of the corpus directories once, without the fuzzer (for coverage.py:
    `python -m coverage run fuzz/fuzz_wire.py --replay fuzz/corpus fuzz/seeds`)."""
    import pathlib

    files = [f for d in dirs for f in sorted(pathlib.Path(d).iterdir()) if f.is_file()]
    for f in files:
        test_one_input(f.read_bytes())
    print(f"replayed {len(files)} inputs")


def main() -> None:
    if sys.argv[1:2] == ["--replay"]:
        replay(sys.argv[2:])
        return
    atheris.Setup(sys.argv, test_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
