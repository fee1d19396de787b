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
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from types import ModuleType

__all__ = ["prepare", "ready", "state"]

log = logging.getLogger(__name__)
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
            slow: Callable[[], None] | None = None) -> None:
    """Compile the kernels of `modules` in a child process (a machine's first start) or
    find them in the cache, then load them here and let them serve, returning at once;
    or, with `wait`, compile or load them here before returning (`slow` is called if that
    lasts more than a second: a first start). Idempotent."""
    global _thread, _state
    if wait:
        note = threading.Timer(1.0, slow) if slow is not None else None
        if note is not None:
            note.start()
        try:
            load(modules)
        finally:
            if note is not None:
                note.cancel()
        return
    with _lock:
        if _thread is None and not _ready.is_set():
            _state = "compiling"
            names = [m.__name__ for m in modules]
            _thread = threading.Thread(target=_compile_and_load, args=(names,),
                                       name="kernels", daemon=True)
            _thread.start()


def load(modules: Sequence[ModuleType]) -> None:
    """Compile or load the kernels of `modules` in this process, now (benchmarks and
    tests that call the kernels directly)."""
    global _state
    for module in modules:
        module.warm()
    _state = "compiled"
    _ready.set()


def _compile_and_load(names: list[str]) -> None:
    global _state
    child = subprocess.run([sys.executable, "-m", __name__, *names],
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


if __name__ == "__main__":  # the child: warm each module named
    for name in sys.argv[1:]:
        importlib.import_module(name).warm()
