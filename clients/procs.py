"""Child processes of the tools, the tests and the benchmarks."""

from __future__ import annotations

import subprocess
import time


def stop(proc: subprocess.Popen | None, timeout: float = 15.0) -> str:
    """Terminate `proc`, wait up to `timeout` s for it to exit, then kill it and wait.

    Returns what it wrote on stderr if that was piped (else ""); whatever else was piped
    is read and dropped, so a full pipe cannot keep it from exiting. A process that has
    already exited, or None, is only reaped.
    """
    if proc is None:
        return ""
    if proc.poll() is None:
        proc.terminate()
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    if isinstance(err, bytes):
        err = err.decode(errors="replace")
    return err or ""


def stop_all(procs: list[subprocess.Popen | None], timeout: float = 15.0) -> None:
    """`stop` several processes at once: all terminated together, then each waited for
    within the one `timeout` (not one timeout after another), the late ones killed."""
    live = [p for p in procs if p is not None]
    for proc in live:
        if proc.poll() is None:
            proc.terminate()
    deadline = time.monotonic() + timeout
    for proc in live:
        stop(proc, timeout=max(0.0, deadline - time.monotonic()))
