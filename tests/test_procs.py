"""`zenoh_track.clients.lib.process`: stopping child processes, with real processes."""

from __future__ import annotations

import subprocess
import sys
import time

from zenoh_track.clients.lib.process import stop_all

STUBBORN = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); " \
           "print('ready', flush=True); time.sleep(60)"
POLITE = "import time; print('ready', flush=True); time.sleep(60)"


def child(code: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
    return proc


def test_stop_all_bounds_the_whole_stop_by_one_timeout():
    """Two children that ignore SIGTERM are killed after one shared timeout, not one
    timeout each; the polite one exits on SIGTERM; None entries are skipped."""
    procs = [child(STUBBORN), child(POLITE), child(STUBBORN)]
    start = time.monotonic()
    stop_all([procs[0], None, procs[1], procs[2]], timeout=1.5)
    took = time.monotonic() - start
    assert all(p.returncode is not None for p in procs)
    assert procs[0].returncode == procs[2].returncode == -9  # killed
    assert procs[1].returncode == -15  # terminated
    assert took < 2 * 1.5  # one shared timeout (one each would take 3 s or more)
