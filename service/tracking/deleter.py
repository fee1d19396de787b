"""Track deletion: which tracks end."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .store import TrackStore

if TYPE_CHECKING:
    from .protocols import Deleter


class UpdateTimeDeleter:
    """Deletes tracks with no measurement for longer than `delete_after` seconds of
    simulation time (Stone Soup's UpdateTimeDeleter)."""

    def __init__(self, delete_after: float) -> None:
        self.delete_after = delete_after

    def delete_tracks(self, store: TrackStore, now: float) -> list[str]:
        """Ids of the tracks to delete at time `now` (the store is not changed)."""
        out: list[str] = []
        for arrays in store.layouts.values():
            oldest = np.min(arrays.t, where=arrays.alive, initial=np.inf)
            if not now - oldest > self.delete_after:  # none due (every frame asks): one
                continue  # pass, no gather (now - t grows as t falls: the oldest decides)
            rows, ids = arrays.live()
            old = (now - arrays.t[rows] > self.delete_after).nonzero()[0]
            out += [ids[i] for i in old.tolist()]
        return out


class CompositeDeleter:
    """Deletes what any of its deleters deletes."""

    def __init__(self, *deleters: Deleter) -> None:
        self.deleters = deleters

    def delete_tracks(self, store: TrackStore, now: float) -> list[str]:
        out: dict[str, None] = {}
        for deleter in self.deleters:
            out.update(dict.fromkeys(deleter.delete_tracks(store, now)))
        return list(out)
