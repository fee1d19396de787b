"""The tracker loop's seams (`tracker.Tracker.step`), with Stone Soup's names: what an
updater (the filter), an associator, an initiator and a deleter must offer. A new one is
one module that satisfies its protocol plus one registration (docs/architecture.md,
"Where to add")."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

import numpy as np

from ..estimation.measurements import MeasurementBatch
from .batches import Detections, Labelled, Unlabelled
from .hypotheses import Hypotheses
from .store import TrackArrays, TrackStore

# (x_pred (N, n), P_pred (N, n, n)) -> (z, R[, h, hx]): the measurements as the filter
# takes them, made for its own prediction (`estimation.filters.Convert`)
Convert = Callable[[np.ndarray, np.ndarray], tuple]


class Updater(Protocol):
    """A filter over the rows of a layout: predicts them to their measurements' times and
    updates them (`estimation.filters`, `imm`, `vdf`)."""

    @property
    def order(self) -> int: ...  # the model order of the store's states (2: CV, 3: CA)

    @property
    def fields(self) -> dict[str, tuple]: ...  # per-row columns it keeps in the store

    def initiate(self, arrays: TrackArrays, rows: np.ndarray) -> None: ...

    def update(self, arrays: TrackArrays, rows: np.ndarray, dt: np.ndarray,
               convert: Convert) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """New x (N, n), P (N, n, n), NIS and the mask of finite rows (the store is not
        changed)."""
        ...

    def inflate(self, arrays: TrackArrays, rows: np.ndarray, dp: np.ndarray) -> None: ...

    def labels(self, arrays: TrackArrays, rows: np.ndarray) -> Sequence[Any]: ...

    # what its tracks are gated with at t (rows -> mean, covariance, likelihood: the IMM's
    # widest mode, `imm.IMM.gate_prediction`), or None: their combined state
    gate_prediction: Callable[[TrackArrays, np.ndarray, float], tuple] | None


ScanT = TypeVar("ScanT", Labelled, Unlabelled, contravariant=True)
PartT = TypeVar("PartT", Labelled, Detections)


class Associator(Protocol[ScanT, PartT]):
    """Which measurement of a scan updates which track: of labelled scans
    (`Associator[Labelled, Labelled]`) or of unlabelled ones
    (`Associator[Unlabelled, Detections]`)."""

    def split(self, scan: ScanT) -> list[tuple[list[int], PartT]]:
        """The parts of a scan associated one after the other, each with the indices of
        its rows in the scan (labelled: a target at most once a part; unlabelled: one
        dimension a part)."""
        ...

    def associate(self, store: TrackStore, part: PartT) -> Hypotheses: ...


class Initiator(Protocol):
    """New tracks from the measurements no track claimed."""

    def initiate(self, store: TrackStore, dim: int, batch: MeasurementBatch,
                 names: Sequence[str], speed: float | None = None
                 ) -> tuple[TrackArrays, np.ndarray, list[str | None]]: ...


class Deleter(Protocol):
    """Which tracks end at a time."""

    def delete_tracks(self, store: TrackStore, now: float) -> list[str]: ...
