"""Stop on the first SIGINT or SIGTERM, whatever thread it lands on; at once on the second.

CPython runs a signal's Python handler in the main thread only, between bytecodes. A
process-directed signal taken by another thread (Zenoh's, a sender's, a kernel's) just
flags it, and a main thread blocked in a lock without a timeout never looks: the stop
would never come. The C-level handler also writes the signal's number to the wakeup fd
(`signal.set_wakeup_fd`) from whichever thread took it; a thread of our own reads that fd,
sets the stop event (waking whatever waits on it) and arms a deadline, so the process is
gone `grace` seconds after the first signal whatever it is doing (the orderly stop, a
final checkpoint among it, fits well inside) and at once after a second signal.

Every program of the product calls `on_signals()` first thing in `main()`. Those with a
loop of their own wait on or poll the returned `Stop`; straight-line programs ask for
`interrupt=True`: the signal then also ends the main thread as `sys.exit(128 + signum)`
would, its `finally` blocks run, without a traceback. A SIGINT ignored by whoever started
the program (a background job) stays ignored.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

STOP_GRACE = 4.0  # s: the longest an orderly stop may take before the process just exits
SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Stop:
    """The stop event of a program: set by the first SIGINT/SIGTERM (`on_signals`)."""

    def __init__(self, grace: float = STOP_GRACE, interrupt: bool = False) -> None:
        self.event = threading.Event()
        self.grace = grace
        self.interrupt = interrupt
        self.signum: int | None = None

    def is_set(self) -> bool:
        return self.event.is_set()

    def set(self) -> None:
        """Stop as a signal would, from the program itself (an end of input, say)."""
        self.event.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until stopped (True) or for `timeout` s (False)."""
        return self.event.wait(timeout)

    @contextmanager
    def interrupting(self) -> Iterator[None]:
        """Within: a signal also ends the main thread (SystemExit) in a step that waits on
        no event of ours (a compile, a connection's retries)."""
        before, self.interrupt = self.interrupt, True
        try:
            if self.is_set():
                raise SystemExit(128 + (self.signum or signal.SIGTERM))
            yield
        finally:
            self.interrupt = before

    # ------------------------------------------------------------ signal side
    def _python_handler(self, signum: int, _frame: object) -> None:
        """The main thread's handler: the watcher does the rest."""
        if self.interrupt:
            raise SystemExit(128 + signum)

    def _watch(self, fd: int) -> None:
        while True:
            try:
                data = os.read(fd, 64)
            except InterruptedError:
                continue
            except OSError:
                return
            for signum in data:
                if signum not in SIGNALS:
                    continue
                if self.event.is_set() and self.signum is not None:
                    os._exit(128 + signum)  # a second signal: at once
                self.signum = signum
                self.event.set()
                deadline = threading.Timer(self.grace, os._exit, args=(128 + signum,))
                deadline.daemon = True
                deadline.start()


def on_signals(grace: float = STOP_GRACE, interrupt: bool = False) -> Stop:
    """Install the stop on SIGINT and SIGTERM (from the main thread, before the program
    starts threads of its own) and return it."""
    stop = Stop(grace, interrupt)
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    for sig in SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, stop._python_handler)
    signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    threading.Thread(target=stop._watch, args=(read_end,), name="stop-signals",
                     daemon=True).start()
    return stop
