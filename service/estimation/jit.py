"""Compiled kernels that serve as soon as they are ready, and not a moment before.

The service's fast kernels (the default IMM's update, the frame's draw) are compiled by
Numba and cached per machine. A machine's first compile takes tens of seconds on two
cores; a service that waited for it would not be alive for that long. Instead every
kernel has a plain NumPy form (its reference: the same filter to 1e-9, the same frame to
the bit), which serves from the first measurement, while a child process compiles the
kernels into Numba's cache on another core. The service then loads them from the cache
in a thread of its own and they take over at the start of the next pass (`ready` is read
once per call). A warm cache takes the same way in a second or so. Neither NumPy's
fallback nor the service's start imports Numba.

Where the outputs must be a function of the inputs alone (the lockstep clock: a replay
gives the same bytes), the caller waits for the kernels instead (`prepare(wait=True)`).

A kernel module offers `warm()`: compile its kernels, or load them from the cache, on a
tiny problem. `python -m <this module> <module> ...` warms the named modules (the child).
"""

from __future__ import annotations

import importlib
import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from types import ModuleType

__all__ = ["prepare", "ready", "state"]

log = logging.getLogger(__name__)
FIRST_COMPILE = 35.0  # s: a lockstep first start to its banner, measured on a 2-core machine
SAY_AFTER = 5.0  # s: longer than loading them from a warm cache takes on a busy machine
ORPHAN_POLL = 0.2  # s: how often the compiling child checks that its service still runs
_ready = threading.Event()
_state = "plain"  # plain -> compiling -> compiled, or failed: <why>
_lock = threading.Lock()
_thread: threading.Thread | None = None


def ready() -> bool:
    """Whether the compiled kernels are loaded here and may serve."""
    return _ready.is_set()


def state() -> str:
    """`plain` (NumPy only), `compiling`, `compiled`, or `failed: <why>` (NumPy serves)."""
    return _state


def prepare(modules: Sequence[ModuleType], wait: bool = False,
            say: Callable[[str], None] | None = None) -> None:
    """Compile the kernels of `modules` in a child process (a machine's first start) or
    find them in the cache, then load them here and let them serve, returning at once;
    or, with `wait`, compile or load them here before returning, telling `say` what it
    does when that lasts more than SAY_AFTER (a first start). Idempotent."""
    global _thread, _state
    if wait:
        load(modules, say)
        return
    with _lock:
        if _thread is None and not _ready.is_set():
            _state = "compiling"
            names = [m.__name__ for m in modules]
            _thread = threading.Thread(target=_compile_and_load, args=(names,),
                                       name="kernels", daemon=True)
            _thread.start()


def load(modules: Sequence[ModuleType], say: Callable[[str], None] | None = None) -> None:
    """Compile or load the kernels of `modules` in this process, now. With `say`, a
    compile that lasts over SAY_AFTER is announced once, with its expected length, and
    each module's end is told as it comes (a first start is silent for no one)."""
    global _state
    start = time.monotonic()
    note = None
    if say is not None:
        note = threading.Timer(SAY_AFTER, say, args=(
            f"compiling the filter kernels, the first start on this machine only (about "
            f"{FIRST_COMPILE:.0f} s on two cores; then cached)...",))
        note.daemon = True
        note.start()
    try:
        for k, module in enumerate(modules, 1):
            module.warm()
            if say is not None and note is not None and note.finished.is_set():
                say(f"kernels {k}/{len(modules)} ready ({module.__name__.rsplit('.', 1)[-1]},"
                    f" {time.monotonic() - start:.0f} s)")
    finally:
        if note is not None:
            note.cancel()
    _state = "compiled"
    _ready.set()


def _compile_and_load(names: list[str]) -> None:
    global _state
    child = subprocess.run([sys.executable, "-m", __name__, str(os.getpid()), *names],
                           capture_output=True, text=True)
    if child.returncode != 0:  # NumPy goes on serving; say why once
        lines = (child.stderr or "").strip().splitlines() or [f"exit {child.returncode}"]
        _state = f"failed: {lines[-1]}"
        log.warning("compiled kernels unavailable, NumPy serves: %s", lines[-1])
        return
    try:
        load([importlib.import_module(name) for name in names])  # from the cache now
    except Exception as exc:  # noqa: BLE001 - any failure leaves NumPy serving
        _state = f"failed: {exc}"
        log.warning("compiled kernels unavailable, NumPy serves: %s", exc)


def _orphaned(parent: int) -> None:
    """In the child: exit as soon as the service that started it is gone (stopped or
    killed), so a stop never leaves a compile running behind it."""
    while os.getppid() == parent:
        time.sleep(ORPHAN_POLL)
    os._exit(1)


if __name__ == "__main__":  # the child: warm each module named, while its parent lives
    threading.Thread(target=_orphaned, args=(int(sys.argv[1]),), daemon=True).start()
    for name in sys.argv[2:]:
        importlib.import_module(name).warm()
