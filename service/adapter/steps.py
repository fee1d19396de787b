"""The worker's calls into the tracker, every one of them, in one place (`TrackerCalls`): the
rest of the adapter reaches the tracker through these methods only."""

from __future__ import annotations

from typing import Any

from ..tracking import checkpoint
from ..tracking.batches import Instant, Labelled, StepOutcome, Unlabelled, Want
from ..tracking.display import Snapshot
from ..tracking.protocols import NoiseMonitor
from ..tracking.tracker import Tracker
from ..wire import PlotScan


class TrackerCalls:
    """Every call the adapter makes into the tracker, in one place."""

    def __init__(self, tracker: Tracker) -> None:
        self.tracker = tracker

    def __len__(self) -> int:
        return len(self.tracker)

    def rows(self, rows: Labelled, want: Want | None, pause: Any) -> StepOutcome:
        """Labelled rows, in order, in one pass over their columns (`pause`: called
        between parts of a long update)."""
        return self.tracker.step(rows, want, pause)

    def scan(self, scan: PlotScan) -> StepOutcome:
        """An unlabelled scan."""
        return self.tracker.step(Unlabelled.of(scan.sensor, scan.t, scan.detections))

    def instant(self, t: float) -> list[str]:
        """A display instant: no input (coast and delete); the tracks deleted."""
        return self.tracker.step(Instant(t)).deleted

    @property
    def noise(self) -> NoiseMonitor:
        """Each sensor's stated noise against its measurements (reports, status)."""
        return self.tracker.noise

    def second_look(self) -> dict[str, int]:
        """How often the second look acted since start (status)."""
        counts = self.tracker.counts()
        return {k: counts[k] for k in ("deferred", "reverted", "chances", "retaken")}

    def continued(self) -> int:
        """Lost tracks continued by a new one under their id since start (status)."""
        return self.tracker.counts()["continued"]

    def delete(self, t: float) -> list[str]:
        return self.tracker.delete(t)

    def drop_newer(self, t: float) -> list[str]:
        return self.tracker.drop_newer(t)

    def snapshot(self, t: float) -> Snapshot:
        return self.tracker.snapshot(t, detail=False)

    def ids(self) -> list[str]:
        return self.tracker.ids()

    def has(self, track_id: str) -> bool:
        return track_id in self.tracker

    def state(self, track_id: str) -> dict[str, Any]:
        return self.tracker.state(track_id)

    def capture(self, extra: dict[str, Any]) -> Any:
        return checkpoint.capture(self.tracker, extra=extra)

    def load(self, data: bytes) -> dict[str, Any]:
        return checkpoint.load(self.tracker, data)
