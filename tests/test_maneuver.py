"""Scenario C through the real service, reduced to 20 runs: VDF reproduces the paper's
behaviour, the IMM beats it in the turns without costing much on the straight leg."""

from __future__ import annotations

import numpy as np
import pytest

from clients import evaluate as track_eval

pytestmark = pytest.mark.slow

RUNS, SEED = 20, 3


@pytest.fixture(scope="module")
def reports() -> dict[str, dict]:
    out = {}
    for name in ("cv", "vdf", "imm"):
        got = track_eval.run_through_service(
            "maneuver", RUNS, SEED,
            ["--filter", name, "--no-display-keys", "--rate", "2",  # few frames: fast CI
             *track_eval.SERVICE_ARGS["maneuver"]])
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


def test_imm_beats_vdf_in_turns_and_stays_close_to_cv_when_straight(reports):
    imm, vdf, cv = reports["imm"], reports["vdf"], reports["cv"]
    # measured (20 runs, seed 3): IMM / VDF position RMSE 55 / 103 m in the slow turn,
    # 78 / 143 m in the fast turn; on the straight leg IMM / CV 41 / 35 m, peak per-scan
    # RMSE 87 / 83 m
    for name in ("slow turn", "fast turn"):
        assert phase(imm, name)["pos_rmse"] < phase(vdf, name)["pos_rmse"]
    straight_imm, straight_cv = phase(imm, "straight"), phase(cv, "straight")
    assert straight_imm["pos_rmse"] <= 1.25 * straight_cv["pos_rmse"]
    # and its worst scan of the straight leg too, not only its average
    assert straight_imm["pos_peak"] <= 1.25 * straight_cv["pos_peak"]
