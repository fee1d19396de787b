"""Scenario C through the real service, reduced to 20 runs: VDF reproduces the paper's
behaviour; the service without options (its default IMM) beats it in the turns without
costing much on the straight leg, and is consistent in the turns."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_track.clients.evaluation import evaluate as track_eval

pytestmark = pytest.mark.slow

RUNS, SEED = 20, 3


@pytest.fixture(scope="module")
def reports() -> dict[str, dict]:
    out = {}
    for name in ("cv", "vdf", "default"):
        options = [] if name == "default" else ["--filter", name,
                                                *track_eval.SERVICE_ARGS["maneuver"]]
        got = track_eval.run_through_service(
            "maneuver", RUNS, SEED,
            ["--no-display-keys", "--rate", "2", *options])  # few frames: fast CI
        out[name] = track_eval.evaluate("maneuver", RUNS, SEED, got)
    return out


def phase(report: dict, name: str) -> dict:
    return next(w for w in report["windows"] if w["window"] == name)


def test_vdf_detects_both_turns_and_errors_fall_after_the_switch(reports):
    vdf = reports["vdf"]
    assert phase(vdf, "straight")["manoeuvre"] < 0.05  # quiet on the straight leg
    assert phase(vdf, "slow turn")["manoeuvre_detected"] >= 0.9
    assert phase(vdf, "fast turn")["manoeuvre_detected"] >= 0.9
    ps = vdf["per_scan"]
    t, err = np.array(ps["t"]), np.array(ps["pos_rmse"])
    peak = err[(t >= 610) & (t < 700)].max()
    assert err[(t >= 740)].mean() < 0.6 * peak  # the error peaks at the switch, then falls


def test_default_beats_vdf_in_turns_and_stays_close_to_it_when_straight(reports):
    default, vdf, cv = reports["default"], reports["vdf"], reports["cv"]
    # measured (20 runs, seed 3): default / VDF position RMSE 40.2 / 35.4 m on the
    # straight leg (1.13 x), 60.2 / 103.1 m in the slow turn, 70.3 / 143.4 m in the fast
    # turn; CV (--q 0.003) 35.x m straight
    for name in ("slow turn", "fast turn"):
        assert phase(default, name)["pos_rmse"] < phase(vdf, name)["pos_rmse"]
    straight = phase(default, "straight")
    assert straight["pos_rmse"] <= 1.25 * phase(vdf, "straight")["pos_rmse"]
    assert straight["pos_peak"] <= 1.25 * phase(cv, "straight")["pos_peak"]


def test_default_is_consistent_in_the_turns_and_not_optimistic_when_straight(reports):
    # measured (20 runs, seed 3): NEES 4.02 slow turn, 3.93 fast turn (interval
    # [2.86, 5.33]); 1.55 and 1.96 on the straight legs: conservative, below the
    # interval (docs/explanation/filters.md, "What the default gives up", explains why)
    default = reports["default"]
    lo, hi = default["nees_interval"]
    for name in ("slow turn", "fast turn"):
        assert lo <= phase(default, name)["nees"] <= hi, name
    for name in ("straight", "straight-2"):
        assert phase(default, name)["nees"] <= hi, name
