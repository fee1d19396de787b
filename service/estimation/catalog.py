"""The filters the service offers by name, built from one specification whose defaults
are the service's (`service.defaults`): the CLI and the tracker build them the same way."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .. import defaults
from .filters import SingleModelFilter
from .imm import ModeSet
from .vdf import VDF

FILTERS = ("imm", "cv", "ca", "ekf", "vdf")


@dataclass(frozen=True)
class FilterSpec:
    """`name`: imm (quiet CV, nominal CV and CA on converted measurements: `imm.ModeSet`;
    `q` sets the nominal mode's noise, `imm_turn` > 0 adds two coordinated turns), cv and
    ca (single-model CMKFs), ekf (CV with the linearised polar update: the baseline of
    scenario B) or vdf (the variable-dimension filter of scenario C). `q`: the white noise per
    axis (`models`: a continuous white noise of density q^2 |dt| over a step dt; m/s^2
    for cv, ekf and the imm's unit, m/s^3 for ca); None: the filter's default."""

    name: str = defaults.FILTER
    q: float | None = None
    imm_ct_q: float = defaults.IMM_CT_Q
    imm_turn: float = defaults.IMM_TURN_DEG
    imm_sojourn: float = defaults.IMM_SOJOURN
    vdf_detect: float = defaults.VDF_DETECT
    vdf_settle: float = defaults.VDF_SETTLE

    def build(self) -> tuple[Any, float, str]:
        """The updater, the noise q the display and the gating predict with, and how
        polar measurements enter ("cmkf": converted, "ekf": linearised)."""
        if self.name not in FILTERS:
            raise ValueError(f"unknown filter {self.name!r}; one of {', '.join(FILTERS)}")
        if self.name == "imm":
            q = defaults.Q_CV if self.q is None else self.q
            modes = ModeSet(q=q, sojourn=self.imm_sojourn, ct_q=self.imm_ct_q,
                            turn_deg=self.imm_turn)
            return modes.imm(), q, "cmkf"
        if self.name == "vdf":
            return VDF(detect=self.vdf_detect, settle=self.vdf_settle), 0.0, "cmkf"
        if self.name == "ca":
            q = defaults.Q_CA if self.q is None else self.q
            return SingleModelFilter("ca", q, 3), q, "cmkf"
        q = defaults.Q_CV if self.q is None else self.q
        return SingleModelFilter("cv", q, 2), q, "ekf" if self.name == "ekf" else "cmkf"
