"""The filters the service offers by name, built from one specification whose defaults
are the service's (`zenoh_track.defaults`): the CLI and the tracker build them the same way."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from .. import defaults
from .ekf import EKFConversion
from .filters import Convert, SingleModelFilter
from .imm import IMM, ModeSet
from .imm_jit import CompiledIMM
from .measurements import MeasurementBatch
from .ucm import CMKFConversion
from .vdf import VDF

FILTERS = ("imm", "cv", "ca", "ekf", "vdf")


Conversion = Callable[[MeasurementBatch], Convert]  # how a batch enters the filter


@dataclass(frozen=True)
class Filter:
    """A built filter: the updater, the white noise q the display and the gating predict
    with, and how a batch of measurements enters its update (`conversion(batch)`:
    `CMKFConversion`, converted, or `EKFConversion`, linearised polar)."""

    updater: SingleModelFilter | IMM | VDF
    q: float
    conversion: Conversion
    name: str = ""  # its name in `FILTERS` (a checkpoint's tracker must have the same)


@dataclass(frozen=True)
class FilterSpec:
    """`name`: imm (quiet CV, nominal CV and CA on converted measurements: `imm.ModeSet`;
    `q` sets the nominal mode's noise, `imm_turn` > 0 adds two coordinated turns,
    `imm_turn_estimated` > 0 a manoeuvre mode turning at its state's own rate), cv and
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
    imm_onset: float = defaults.IMM_ONSET  # s: 1 / the rate of entering the manoeuvre modes
    imm_turn_estimated: float = defaults.IMM_TURN_ESTIMATED  # > 0: a "turn" mode, this jerk

    def build(self) -> Filter:
        """The filter of this name, with its noise and its measurement conversion."""
        if self.name not in FILTERS:
            raise ValueError(f"unknown filter {self.name!r}; one of {', '.join(FILTERS)}")
        if self.name == "imm":
            q = defaults.Q_CV if self.q is None else self.q
            turn = (("turn", self.imm_turn_estimated),) if self.imm_turn_estimated > 0 else ()
            modes = ModeSet(q=q, sojourn=self.imm_sojourn, ct_q=self.imm_ct_q,
                            turn_deg=self.imm_turn, onset=self.imm_onset,
                            manoeuvre=defaults.IMM_MANOEUVRE + turn)
            return Filter(modes.imm(CompiledIMM), q, CMKFConversion, self.name)
        if self.name == "vdf":
            return Filter(VDF(detect=self.vdf_detect, settle=self.vdf_settle), 0.0,
                          CMKFConversion, self.name)
        if self.name == "ca":
            q = defaults.Q_CA if self.q is None else self.q
            return Filter(SingleModelFilter("ca", q, 3), q, CMKFConversion, self.name)
        q = defaults.Q_CV if self.q is None else self.q
        return Filter(SingleModelFilter("cv", q, 2), q,
                      EKFConversion if self.name == "ekf" else CMKFConversion, self.name)
