"""The send buffer of each viewer's connection, kept small: the Foxglove WebSocket
protocol has no acknowledgement, so whatever the kernel holds for a viewer that reads
slowly is old frames, and Linux lets a connection's send buffer grow to
`net.ipv4.tcp_wmem`'s maximum (4 MB by default: 8 frames of 1,000 tracks). The server
(foxglove-sdk) does not expose its sockets; they are this process's own, found in
/proc/self/fd by the port they were accepted on, and given SO_SNDBUF (which also stops
the kernel's growing of it). Elsewhere than Linux nothing is changed."""

from __future__ import annotations

import os
import socket

FD_DIR = "/proc/self/fd"


def trim_send_buffers(port: int, size: int, done: set[tuple[int, tuple]]) -> int:
    """Set SO_SNDBUF to `size` bytes on the connections accepted on `port` that are not
    in `done` (fd, peer); returns how many were set."""
    if not os.path.isdir(FD_DIR):
        return 0
    count = 0
    for name in os.listdir(FD_DIR):
        try:
            if not os.readlink(f"{FD_DIR}/{name}").startswith("socket:"):
                continue
            sock = socket.socket(fileno=os.dup(int(name)))
        except (OSError, ValueError):
            continue
        try:
            if sock.type != socket.SOCK_STREAM or sock.family not in (
                    socket.AF_INET, socket.AF_INET6) or sock.getsockname()[1] != port:
                continue
            key = (int(name), sock.getpeername())  # OSError: the listening socket
            if key not in done:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, size)
                done.add(key)
                count += 1
        except OSError:
            continue
        finally:
            sock.close()  # the duplicate only
    return count
