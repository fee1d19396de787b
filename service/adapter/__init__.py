"""The Zenoh adapter: the stages a sample goes through, in order, each a module.

1. `ingest`: Zenoh's channels and callbacks to typed inputs (`Singles`, `Scan`, `Plots`,
   `ClockMessage`, `Query`), in the order they came; `decode` (with `layouts`) reads
   their keys and payloads into checked columns.
2. `admit`: the time policy (`timeline`), unlabelled scans reordered across sensors
   (`reorder`), `seq` gaps.
3. `worker`: the one thread that takes each batch through the stages, and `TrackerCalls`,
   every call into the tracker.
4. `schedule`: the display clock (`Clock`: `Lockstep`, `Realtime`), the instants due.
5. `publish`: the outputs (`encode`: MessagePack from columns; `listeners`: who
   subscribes to which per-target key), `queries`: status and late joiners.
6. `state`: the `--state` file, checkpoints through the service's public calls.
"""

from .worker import TrackService

__all__ = ["TrackService"]
