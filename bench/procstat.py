"""CPU time and memory of processes and their threads, from Linux's /proc (the
benchmarks' shared readers: bench_capacity.py, throughput.py, flood_stages.py)."""

from __future__ import annotations

import os

CLK = os.sysconf("SC_CLK_TCK")


def _stat_fields(path: str) -> list[str]:
    with open(path) as f:
        text = f.read()
    return text[text.rindex(")") + 2:].split()  # fields from `state` on (comm may hold spaces)


def cpu_seconds(pid: int) -> float:
    f = _stat_fields(f"/proc/{pid}/stat")
    return (int(f[11]) + int(f[12])) / CLK  # utime + stime, all threads


def thread_cpu(pid: int) -> dict[int, tuple[str, float]]:
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                comm = f.read().strip()
            fl = _stat_fields(f"/proc/{pid}/task/{tid}/stat")
            out[int(tid)] = (comm, (int(fl[11]) + int(fl[12])) / CLK)
        except (FileNotFoundError, ProcessLookupError):
            pass
    return out


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")
