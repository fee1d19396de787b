"""`track-replay FILE --plot OUT.png`: a recording at a glance, without a viewer.

Left, the picture seen from above: every track's path (from the recorded `frame`
samples, else from `tracks/`), its last position marked and labelled when there are few
tracks; tracks the frames only ever showed as tentative (clutter) are counted, not drawn.
Right, the samples per second of wall time (receive time) for each kind of key
(`meas`, `tracks`, `frame`, ...), so gaps and bursts of a session show at once.
"""

from __future__ import annotations

import struct
from collections import defaultdict

import numpy as np

from zenoh_track.clients.lib.frames import NO_STATUS, Frame
from zenoh_track.clients.record.files import Recording
from zenoh_track.wire import need, unpack

MAX_LABELS = 30  # tracks labelled by id when there are at most this many


def paths(rec: Recording, channels: set[int]
          ) -> tuple[dict[str, list[tuple[float, float]]], set[str]]:
    """Each track's (x, y) positions in receive order: from `frame` when recorded (every
    10th), else from the `tracks/` messages; and the tracks that never left `tentative`
    (known from a frame's status bin, protocol 1.1)."""
    frames = {cid for cid in channels if rec.channels[cid].key.endswith("/frame")
              and rec.channels[cid].kind == "put"}
    tracks = {cid for cid in channels if "/tracks/" in rec.channels[cid].key
              and rec.channels[cid].kind == "put"}
    out: dict[str, list[tuple[float, float]]] = defaultdict(list)
    seen_tentative, established = set(), set()
    for k, (ch, s) in enumerate(rec.samples(frames or tracks)):
        try:
            msg = unpack(s.payload)
            if frames:
                if k % 10:
                    continue
                f = Frame.decode(msg)
                for tid, (x, y) in zip(f.id_list, f.pos[:, :2].tolist(), strict=True):
                    out[tid].append((x, y))
                for tid, code in zip(f.id_list, f.codes.tolist(), strict=True):
                    if code != NO_STATUS:
                        (seen_tentative if code == 0 else established).add(tid)
            else:
                out[ch.key.rsplit("/", 1)[1]].append((msg["pos"][0], msg["pos"][1]))
        except (ValueError, KeyError, TypeError, IndexError, struct.error):
            continue
    return out, seen_tentative - established


def rates(rec: Recording, channels: set[int]) -> tuple[float, dict[str, np.ndarray]]:
    """Samples per second of receive time for each kind of key (the chunk after the
    namespace), from the first sample on."""
    times: dict[str, list[int]] = defaultdict(list)
    for ch, s in rec.samples(channels):
        parts = ch.key.split("/")
        times[parts[1] if len(parts) > 1 else parts[0]].append(s.log_time)
    t0 = min(v[0] for v in times.values())
    end = max(v[-1] for v in times.values())
    bins = np.arange(0, (end - t0) / 1e9 + 1.0, 1.0)
    return t0, {k: np.histogram((np.array(v) - t0) / 1e9, bins=bins)[0]
                for k, v in sorted(times.items())}


def plot(path: str, out: str, channels: set[int] | None = None) -> None:
    need("matplotlib", "plot", "track-replay --plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(path, "rb") as f:
        rec = Recording(f)
        chosen = set(rec.channels) if channels is None else channels
        trails, tentative = paths(rec, chosen)
        trails = {k: v for k, v in trails.items() if k not in tentative}
        _, per_kind = rates(rec, chosen)
        ns = rec.namespace or "?"
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.5),
                                  gridspec_kw={"width_ratios": [1.1, 1]})
    for tid, pts in sorted(trails.items()):
        xy = np.array(pts) / 1000.0
        line, = ax.plot(xy[:, 0], xy[:, 1], lw=0.8)
        ax.plot(xy[-1, 0], xy[-1, 1], "o", ms=3, color=line.get_color())
        if len(trails) <= MAX_LABELS:
            ax.annotate(tid, xy[-1], fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("East, km")
    ax.set_ylabel("North, km")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.set_title(f"{len(trails)} tracks (namespace {ns})" + (
        f"; {len(tentative)} never confirmed, not drawn" if tentative else ""))
    for kind, counts in per_kind.items():
        ax2.plot(np.arange(len(counts)), counts, label=f"{kind} ({counts.sum():,})", lw=1)
    ax2.set_xlabel("receive time since the first sample, s")
    ax2.set_ylabel("samples per second")
    ax2.set_yscale("symlog", linthresh=10)
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8)
    ax2.set_title("samples per second by key")
    fig.suptitle(path.rsplit("/", 1)[-1])
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
