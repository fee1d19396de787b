"""Scoring of the `manoeuvres` scenario (clients/feeds/manoeuvres.py), shared by `track-eval
manoeuvres` (through the service) and bench/manoeuvres.py (in-process and peers).

A run's tracker output is, per scan instant t: the established (confirmed or coasting)
tracks' positions at t, and the states (x, P: position and velocity first) of the
tracks updated at t. At each scan the tracks are assigned one-to-one to the aircraft
by distance (SciPy's `linear_sum_assignment`), a pair farther than `c` (2.5 km) not counted;
labelled feeds assign by id. Per aircraft, after its confirmation (its first scan with
an assigned track): the track breaks (distinct track ids assigned, minus one), the
fraction of scans at which a track is assigned (held), the position errors and the
NEES of position and velocity (6-D) while manoeuvring (the aircraft accelerates at t)
and on straight legs (20 s or more after its last manoeuvre, t >= 30 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from zenoh_track.clients.feeds.manoeuvres import Manoeuvres

SETTLE = 20.0  # s after a manoeuvre before the flight counts as a straight leg
START = 30.0  # s: no straight-leg figures before (initiation)
# m: a track farther than this from an aircraft is not on it (a 7 g aircraft leaves a
# straight prediction by 2.2 km in 8 s: a missed scan at 4 s)
C = 2500.0
Shown = dict[float, dict[str, np.ndarray]]  # t -> track id -> position (3,)
States = dict[float, dict[str, tuple[np.ndarray, np.ndarray]]]  # t -> id -> (x, P)


@dataclass
class Aircraft:
    """What the tracker made of one aircraft in one run."""

    name: str
    kind: str
    ids: list[str] = field(default_factory=list)  # track ids, in order of first assignment
    scans: int = 0  # scan instants from its confirmation on
    held: int = 0
    err: dict[str, list[float]] = field(default_factory=lambda: {"man": [], "str": []})
    nees: dict[str, list[float]] = field(default_factory=lambda: {"man": [], "str": []})
    # while manoeuvring: (s since the manoeuvre's leg began, squared error, NEES or NaN)
    onset: list[tuple[float, float, float]] = field(default_factory=list)

    @property
    def breaks(self) -> int:
        return max(len(self.ids) - 1, 0)


def score(sc: Manoeuvres, shown: Shown, states: States, labelled: bool = False,
          c: float = C) -> list[Aircraft]:
    """Every aircraft of the run `sc` against what the tracker showed."""
    from scipy.optimize import linear_sum_assignment

    out = [Aircraft(f.name, f.kind) for f in sc.flights]
    for t in sc.times.tolist():
        tracks = shown.get(round(t, 6), {})
        truth = [f.state(t) for f in sc.flights]
        ids = list(tracks)
        pairs: list[tuple[int, str]] = []
        if labelled:
            pairs = [(i, f.name) for i, f in enumerate(sc.flights) if f.name in tracks]
        elif ids:
            pos = np.array([tracks[k] for k in ids])
            true = np.array([s[0] for s in truth])
            dist = np.linalg.norm(true[:, None] - pos[None], axis=2)
            rows, cols = linear_sum_assignment(np.minimum(dist, 10 * c))
            pairs = [(int(r), ids[k]) for r, k in zip(rows, cols, strict=True)
                     if dist[r, k] <= c]
        got = dict(pairs)
        for i, (a, f) in enumerate(zip(out, sc.flights, strict=True)):
            k = got.get(i)
            if k is None:
                a.scans += bool(a.ids)
                continue
            if k not in a.ids:
                a.ids.append(k)
            a.scans += 1
            a.held += 1
            phase = ("man" if f.manoeuvring(t) else
                     "str" if t >= START and f.quiet_for(t) >= SETTLE else None)
            if phase is None:
                continue
            p, v, _ = truth[i]
            a.err[phase].append(float(np.sum((tracks[k] - p) ** 2)))
            st = states.get(round(t, 6), {}).get(k)
            nees = math.nan
            if st is not None:
                e = st[0][:6] - np.concatenate([p, v])
                nees = float(e @ np.linalg.solve(st[1][:6, :6], e))
                a.nees[phase].append(nees)
            if phase == "man":
                a.onset.append((f.leg_age(t), a.err[phase][-1], nees))
    return out


def summary(aircraft: list[Aircraft]) -> dict[str, dict[str, float]]:
    """Per class: aircraft, breaks (sum, and aircraft with any), the smallest and the mean
    fraction held, RMSE (m) and average NEES while manoeuvring and on straight legs, the
    largest error while manoeuvring."""
    out: dict[str, dict[str, float]] = {}
    for kind in dict.fromkeys(a.kind for a in aircraft):
        group = [a for a in aircraft if a.kind == kind]
        held = [a.held / a.scans if a.scans else 0.0 for a in group]
        row = {"aircraft": len(group), "breaks": sum(a.breaks for a in group),
               "broken": sum(a.breaks > 0 for a in group),
               "never": sum(not a.ids for a in group),
               "held_min": min(held), "held_mean": float(np.mean(held))}
        for ph in ("man", "str"):
            e = [x for a in group for x in a.err[ph]]
            n = [x for a in group for x in a.nees[ph]]
            row[f"rmse_{ph}"] = math.sqrt(np.mean(e)) if e else math.nan
            row[f"nees_{ph}"] = float(np.mean(n)) if n else math.nan
            row[f"max_{ph}"] = math.sqrt(max(e)) if e else math.nan
        out[kind] = row
    return out


HEAD = (f"{'class':<14}{'n':>4}{'breaks':>7}{'broken':>7}{'never':>6}{'held min':>9}"
        f"{'mean':>7}{'RMSE man':>9}{'max man':>8}{'RMSE str':>9}{'NEES man':>9}{'str':>6}")


def table(title: str, sums: dict[str, dict[str, float]]) -> str:
    """One configuration's table, a row per class."""
    lines = [title, HEAD, "-" * len(HEAD)]
    for kind, r in sums.items():
        lines.append(f"{kind:<14}{r['aircraft']:>4.0f}{r['breaks']:>7.0f}{r['broken']:>7.0f}"
                     f"{r['never']:>6.0f}{r['held_min']:>9.3f}{r['held_mean']:>7.3f}"
                     f"{r['rmse_man']:>9.1f}{r['max_man']:>8.0f}{r['rmse_str']:>9.1f}"
                     f"{r['nees_man']:>9.2f}{r['nees_str']:>6.2f}")
    return "\n".join(lines)


def onset_table(aircraft: list[Aircraft], period: float, scans: int = 8) -> str:
    """Per class, the manoeuvring samples by scans since the manoeuvre's leg began (its
    first `scans`, then the rest): RMSE, mean NEES and that scan's share of the class's
    NEES sum (where the NEES while manoeuvring comes from)."""
    lines = [f"{'class':<14}{'scan':>6}{'n':>6}{'RMSE':>8}{'NEES':>9}{'share':>7}"]
    for kind in dict.fromkeys(a.kind for a in aircraft):
        got = [s for a in aircraft if a.kind == kind for s in a.onset]
        total = sum(n for *_, n in got if not math.isnan(n))
        for k in range(scans + 1):
            sel = [s for s in got if min(int(s[0] / period + 1e-9), scans) == k]
            nees = [n for *_, n in sel if not math.isnan(n)]
            if sel:
                lines.append(f"{kind:<14}{k if k < scans else f'{k}+':>6}{len(sel):>6}"
                             f"{math.sqrt(np.mean([e for _, e, _ in sel])):>8.1f}"
                             f"{np.mean(nees) if nees else math.nan:>9.1f}"
                             f"{sum(nees) / total if total else math.nan:>7.2f}")
    return "\n".join(lines)


def blair_q(a_max: float, period: float, sigma: float) -> float:
    """White acceleration std (m/s^2, the piecewise-constant model) of an NCV filter
    designed by Blair's rule for a target accelerating up to `a_max`: the steady-state
    alpha-beta gains (Kalata's relation beta = 2(2 - alpha) - 4 sqrt(1 - alpha)) that
    minimise the largest position MSE, noise variance plus the squared bias a T^2
    (1 - alpha) / beta of a constant acceleration, and the process noise of those gains
    by the tracking index Lambda^2 = beta^2 / (1 - alpha) = (q T^2 / sigma)^2 (Blair,
    "Design of nearly constant velocity track filters for tracking maneuvering
    targets", FUSION 2008; Kalata, IEEE TAES 20(2), 1984)."""
    alpha = np.linspace(1e-3, 0.999, 20_000)
    beta = 2 * (2 - alpha) - 4 * np.sqrt(1 - alpha)
    var = sigma**2 * (2 * alpha**2 + 2 * beta - 3 * alpha * beta) / (alpha * (4 - 2 * alpha - beta))
    bias = a_max * period**2 * (1 - alpha) / beta
    k = int(np.argmin(var + bias**2))
    lam = beta[k] / math.sqrt(1 - alpha[k])
    return float(lam * sigma / period**2)
