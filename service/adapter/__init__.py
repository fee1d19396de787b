"""The Zenoh adapter: the stages a sample goes through, in order, each a module.

1. `ingest`: Zenoh's channels and callbacks to typed inputs (`Singles`, `LabelledScan`,
   `Plots`, `ClockMessage`, `Query`), in the order they came; `decode` (with `layouts`)
   reads their keys and payloads into checked columns.
2. `admit`: the time policy (`timeline`), unlabelled scans reordered across sensors
   (`reorder`), `seq` gaps; with the clock, it makes each input a `plan`.
3. `worker`: the one thread that plans each input and carries the plan out, and
   `steps.TrackerCalls`, every call into the tracker.
4. `schedule`: what the worker asks of the display clock (`Clock`), its drivers in
   `clocks` (`Lockstep`, `Realtime`), the frames (`Frames`).
5. `publish`: the outputs (`encode`: MessagePack from columns; `listeners`: who
   subscribes to which per-target key), `queries`: status and late joiners.
6. `state`: the `--state` file, checkpoints through the service's public calls.
"""

from .worker import TrackService

__all__ = ["TrackService"]
