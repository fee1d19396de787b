"""`track-service --state PATH`: the track table kept in a file across restarts.

The worker thread copies a checkpoint (`TrackService.checkpoint`: the tracks, the display
clock, the last `seq` per sensor) every `--state-period` seconds (default 1 s)
and hands it to a writer thread, which encodes it and writes it atomically: a temporary
file in the same directory, flushed and fsync'ed, then `os.replace` over PATH, so PATH
always holds one whole checkpoint. On SIGTERM/SIGINT the service stops its worker and
writes a last one. At start the file is read back before the service takes any input; a
file that is not a checkpoint this service can take is refused with one line on stderr
and the service starts empty (docs/operations.md).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .. import defaults
from ..tracking import checkpoint
from ..wire.cli import fail

log = logging.getLogger("track-service")


class StateFile:
    """The state file of one service: periodic checkpoints, written off the worker.
    `capture()` copies the service's checkpoint on the thread that owns the tracker
    (`TrackService.checkpoint`)."""

    def __init__(self, path: str | Path, capture: Callable[[], Any],
                 period: float = defaults.STATE_PERIOD) -> None:
        self.path, self.capture = Path(path), capture
        self.period = period
        self.next_due = time.monotonic() + period
        self.pending: Any = None  # a checkpoint.capture waiting for the writer
        self.cond = threading.Condition()
        self.closed = False
        self.writes = 0
        self.writer = threading.Thread(target=self._write_loop, name="state-writer",
                                       daemon=True)
        self.writer.start()

    # ------------------------------------------------------------ worker side
    def tick(self) -> None:
        """On the worker thread: a checkpoint when one is due."""
        now = time.monotonic()
        if now >= self.next_due:
            self.next_due = now + self.period
            self._hand_over(self.capture())

    def final(self) -> None:
        """The last checkpoint, once the worker has stopped; written before returning."""
        data = self.capture()
        with self.cond:
            self.closed, self.pending = True, None
            self.cond.notify_all()
        self.writer.join(timeout=10)
        self.write(checkpoint.encode(data))

    def _hand_over(self, data: Any) -> None:
        with self.cond:
            self.pending = data  # an older one not yet written is superseded
            self.cond.notify_all()

    # ------------------------------------------------------------ writer side
    def _write_loop(self) -> None:
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.pending is not None or self.closed)
                if self.closed:
                    return
                data, self.pending = self.pending, None
            try:
                self.write(checkpoint.encode(data))  # the archive made here, off the worker
            except OSError as exc:
                log.error("cannot write the state file %s: %s", self.path, exc)

    def write(self, data: bytes) -> None:
        """Replace the file atomically with `data` (same directory, fsync, os.replace)."""
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)
        self.writes += 1

    # ------------------------------------------------------------ start
    def restore(self, take: Callable[[bytes], tuple[int, float, str]]) -> str:
        """Read the file and hand it to `take` (`TrackService.restore`, before the worker
        starts: the tracks restored, the checkpoint's age, a note); the line to print. A
        file that cannot be read or a place that cannot be written is an operator's
        mistake: one line and exit 2 (`wire.cli.fail`). A file that is not a checkpoint
        this service can take is set aside as PATH.refused, and the service starts
        empty."""
        where = self.path.parent
        if self.path.is_dir() or not where.is_dir() or not os.access(where, os.W_OK):
            fail(f"cannot write the state file {self.path} (not a file in a writable "
                 "directory)")
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return f"state file {self.path} not there yet: starting empty"
        except OSError as exc:
            fail(f"cannot read the state file {self.path}: {exc.strerror}")
        try:
            tracks, age, note = take(data)
        except checkpoint.CheckpointError as exc:
            refused = self.path.with_name(self.path.name + ".refused")
            os.replace(self.path, refused)
            return f"state file {self.path} refused ({exc}; kept as {refused}): starting empty"
        return (f"restored {tracks} tracks from {self.path} "
                f"(written {age:.1f} s ago{note})")
