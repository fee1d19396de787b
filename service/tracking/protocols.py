"""The tracker loop's seams (`tracker.Tracker.step`), with Stone Soup's names: what an
updater (the filter), an associator and its stages, an initiator, a deleter, the track
life, the display and the noise check must offer. The tracker and the adapter call
nothing else on a component (tests/test_protocols.py reads their calls). A new part is
one module that satisfies its protocol plus one registration (docs/architecture.md,
"Where to add")."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from ..estimation.measurements import MeasurementBatch
from .batches import Detections, Labelled, Unlabelled
from .hypotheses import Hypotheses, Seen, WeightedUpdate
from .store import Column, TrackArrays, TrackStore

if TYPE_CHECKING:
    from .display import DisplayConfig, Snapshot
    from .gating import Gating
    from .noise_check import NoiseReport

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

    def update_pda(self, arrays: TrackArrays, rows: np.ndarray, dt: np.ndarray,
                   weighted: WeightedUpdate) -> tuple[np.ndarray, ...] | None:
        """`update` by weighted detections (JPDA), or None where the filter has no way
        of its own: the tracker then updates by the equivalent measurement."""
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


class LabelledAssociator(Associator[Labelled, Labelled], Protocol):
    """The associator of labelled measurements, which remembers something of each track
    (the sensor of its last update) in its own per-row `columns` of the store, and by
    id for a checkpoint."""

    columns: Mapping[str, Column]

    def forget(self, ids: Sequence[str]) -> None: ...

    def memory(self, store: TrackStore) -> dict[str, str]: ...

    def remember(self, store: TrackStore, last: Mapping[str, str]) -> None: ...


class ScanAssociator(Associator[Unlabelled, Detections], Protocol):
    """The associator of unlabelled scans. Its stages may keep an update aside a scan
    (`settle`: a second look) and count what they did (`counts`, for `status`)."""

    def settle(self, arrays: TrackArrays, rows: np.ndarray) -> np.ndarray:
        """Rows of `arrays` were just updated by this associator's part: the mask of
        those put back on their branch before the update (their states not reported)."""
        ...

    def counts(self) -> dict[str, int]: ...


class Scene(Protocol):
    """One part of an unlabelled scan against the tracks of its layout, as an
    association stage sees it (`plot_association.Scene`)."""

    arrays: TrackArrays
    rows: np.ndarray  # the tracks in play (store rows)
    z: np.ndarray  # the detections, converted
    r: np.ndarray
    t: float
    pd: float
    lam: float  # the clutter density
    every: Gating  # every track in play gated against every detection
    hyp: Hypotheses

    def gate(self, rows: np.ndarray) -> Gating: ...

    def regate(self) -> None: ...


class Stage(Protocol):
    """A step wrapped around the plain association of the established (confirmed) tracks
    (`plot_association.ScanAssociator.associate`); a stage that has nothing to do at one
    of the hooks returns what it was given."""

    def before(self, scene: Scene) -> None:
        """Before the association (may change the store's rows and `scene.regate()`)."""
        ...

    def pairs(self, scene: Scene) -> np.ndarray | None:
        """Which pairs of `scene.every` the established tracks may take (None: all)."""
        ...

    def after(self, scene: Scene, taken: Gating, free: np.ndarray) -> np.ndarray:
        """After the established tracks took their detections (gated as `taken`;
        `free`: the detections left): the detections still free."""
        ...

    def settle(self, arrays: TrackArrays, rows: np.ndarray) -> np.ndarray: ...

    def counts(self) -> dict[str, int]: ...


class Initiator(Protocol):
    """New tracks from the measurements no track claimed."""

    def initiate(self, store: TrackStore, dim: int, batch: MeasurementBatch,
                 names: Sequence[str], speed: float | None = None
                 ) -> tuple[TrackArrays, np.ndarray, list[str | None]]: ...


class Deleter(Protocol):
    """Which tracks end at a time."""

    def delete_tracks(self, store: TrackStore, now: float) -> list[str]: ...


class Life(Protocol):
    """The life of tracks of unlabelled scans: tentative at birth, confirmed by the scans
    that see them (`life.MofNLife`), a lost one continued by a new one."""

    def start(self, arrays: TrackArrays, rows: np.ndarray) -> None:
        """New tracks of an unlabelled scan (detected once)."""
        ...

    def count(self, store: TrackStore, seen: Sequence[Seen]) -> dict[str, tuple[str, int]]:
        """A scan's detections and misses counted; {new id: (old id, its updates)} of
        the tracks it confirmed that continue a lost one under the lost one's id."""
        ...

    def counts(self) -> dict[str, int]: ...


class Display(Protocol):
    """What the display keeps of every track and draws at an instant
    (`display.DisplayState`)."""

    config: DisplayConfig  # its rate and lag set the frames' clock

    def initiate(self, arrays: TrackArrays, rows: np.ndarray, x: np.ndarray | None = None,
                 p: np.ndarray | None = None) -> None: ...

    def update(self, arrays: TrackArrays, rows: np.ndarray, t: np.ndarray, x: np.ndarray,
               p: np.ndarray) -> None: ...

    def forget(self, arrays: TrackArrays, rows: np.ndarray) -> None: ...

    def snapshot(self, store: TrackStore, t: float, detail: bool = True) -> Snapshot: ...


class NoiseMonitor(Protocol):
    """Each sensor's stated noise against what its measurements show
    (`noise_check.NoiseCheck`)."""

    def adjust(self, sensors: str | list[str], batch: MeasurementBatch, rows: np.ndarray,
               dt: np.ndarray, order: int, ids: list[str | None], updates: np.ndarray
               ) -> tuple[MeasurementBatch, np.ndarray, np.ndarray]: ...

    def observe(self, sensors: str | list[str], ids: list[str | None], rows: np.ndarray,
                batch: MeasurementBatch, nis: np.ndarray, ok: np.ndarray) -> None: ...

    def status(self) -> dict[str, dict]: ...

    def due(self, wall: float) -> list[NoiseReport]: ...
