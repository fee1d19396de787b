"""Child processes of the programs, the tests and the benchmarks: `stop` and `stop_all`,
and `track-service` as a child process on a free loopback port (what the pytest plugin,
the project's tests and track-eval start a service with)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

from zenoh_track.clients.lib.session import Client, connect
from zenoh_track.wire import DEFAULT_NS, Keys, free_port

NOTICE_POLL = 1.0  # s between two looks at a starting service's log
START_NOTES = ("track-service: compiling", "track-service: kernels")  # what a start says
COMPILE_WAIT = 600.0  # s: the longest a first start's compile may take on a busy machine


def stop(proc: subprocess.Popen[Any] | None, timeout: float = 15.0) -> str:
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


def stop_all(procs: list[subprocess.Popen[Any] | None], timeout: float = 15.0) -> None:
    """`stop` several processes at once: all terminated together, then each waited for
    within the one `timeout` (not one timeout after another), the late ones killed."""
    live = [p for p in procs if p is not None]
    for proc in live:
        if proc.poll() is None:
            proc.terminate()
    deadline = time.monotonic() + timeout
    for proc in live:
        stop(proc, timeout=max(0.0, deadline - time.monotonic()))


class ServiceProcess:
    """`python -m zenoh_track` (the track-service program) listening on a free
    127.0.0.1 port (or `endpoint`), or connected to `connect` (a router, say), namespace
    `ns`, `--clock clock` unless None, then `args`, with `env` added to the environment
    (NUMBA_CACHE_DIR, say); its stdout and stderr go to `log` (a
    temporary file by default).

    `wait()` blocks until its liveliness token is seen (its `client` then open),
    `stop()` ends it and returns its log."""

    def __init__(self, *args: str, ns: str = DEFAULT_NS, clock: str | None = "lockstep",
                 endpoint: str | None = None, connect: str | None = None,
                 log: str | Path | None = None, python: str = sys.executable,
                 env: Mapping[str, str] | None = None) -> None:
        self.endpoint = connect or endpoint or f"tcp/127.0.0.1:{free_port()}"
        self.ns = ns
        self.keys = Keys(ns)
        self.args = ("-e" if connect else "-l", self.endpoint, "--ns", ns,
                     *(("--clock", clock) if clock else ()), *args)
        self.client: Client | None = None
        self._own_log = log is None
        if log is None:
            fd, name = tempfile.mkstemp(prefix=f"track-service-{ns}-", suffix=".log")
            os.close(fd)
            log = name
        self.log_path = Path(log)
        self._log_text: str | None = None
        with open(self.log_path, "wb") as out:
            self.proc = subprocess.Popen([python, "-m", "zenoh_track", *self.args],
                                         stdout=out, stderr=subprocess.STDOUT,
                                         env={**os.environ, "PYTHONUNBUFFERED": "1",
                                              **(env or {})})

    def log(self) -> str:
        """What the service has written so far (stdout and stderr, in order)."""
        if self._log_text is not None:
            return self._log_text
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def wait(self, timeout: float = 30.0,
             notice: Callable[[str], None] | None = None) -> Client:
        """Its `client` (a Client of its namespace) once it is alive; RuntimeError with
        the end of its log when it exits or stays silent for `timeout` s (a first
        start's compile of the kernels may take up to COMPILE_WAIT). `notice` is given
        each line the service writes about its start meanwhile (that compile, with its
        progress)."""
        if self.client is None:
            self.client = connect(self.endpoint, ns=self.ns)
        deadline = time.monotonic() + timeout
        told = 0
        while True:
            try:
                self.client.wait_for_service(timeout=min(NOTICE_POLL, timeout))
                alive = True
            except TimeoutError:
                alive = False
            lines = [ln for ln in self.log().splitlines() if ln.startswith(START_NOTES)]
            if lines and not told:  # compiling: silence is not the measure any more
                deadline = max(deadline, time.monotonic() + COMPILE_WAIT)
            if notice is not None:
                for line in lines[told:]:
                    notice(line)
            told = len(lines)
            if alive:
                return self.client
            code = self.proc.poll()
            if code is not None or time.monotonic() >= deadline:
                state = f"exited with status {code}" if code is not None else \
                    f"not alive after {timeout:g} s"
                raise RuntimeError(f"track-service {' '.join(self.args)}: {state}; its "
                                   f"log:\n{self.log()[-3000:]}") from None

    def feed(self, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        """Run `track-feed ARGS` against it (its endpoint and namespace); raises
        CalledProcessError when the feed fails."""
        cmd = [sys.executable, "-m", "zenoh_track.clients.feeds.feed", *args, "-e", self.endpoint,
               "--ns", self.ns]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=True)

    def stop(self, timeout: float = 15.0) -> str:
        """Close its client, terminate it (kill it after `timeout` s) and return its log."""
        if self.client is not None:
            self.client.close()
            self.client = None
        stop(self.proc, timeout)
        if self._log_text is None:
            self._log_text = self.log()
            if self._own_log:
                self.log_path.unlink(missing_ok=True)
        return self._log_text

    def __enter__(self) -> ServiceProcess:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()
