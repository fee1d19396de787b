"""Each viewer's connection as this process's kernel sees it. The server (foxglove-sdk)
does not expose its sockets; they are this process's own, found in /proc/self/fd by the
port they were accepted on. Of each, the server reads how many bytes the viewer's kernel
has not yet taken (SIOCOUTQ: sent and not acknowledged, or not sent) and the receive
window it advertises (TCP_INFO's `tcpi_snd_wnd`: the room left in its receive buffer,
which the viewer's reading frees), so that it gives a viewer a new frame only once the
previous one has drained; and it sets a small send buffer
(SO_SNDBUF), which bounds what the kernel holds for a viewer that reads slowly (Linux
lets it grow to `net.ipv4.tcp_wmem`'s maximum, 4 MB by default). Elsewhere than Linux
no connection is found and nothing is changed."""

from __future__ import annotations

import fcntl
import os
import socket
import struct
from dataclasses import dataclass

FD_DIR = "/proc/self/fd"
SIOCOUTQ = 0x5411  # Linux: bytes in a TCP socket's send queue (TIOCOUTQ)
# offsets in Linux's struct tcp_info (include/uapi/linux/tcp.h)
TCP_INFO_LAST_DATA_RECV = 52  # tcpi_last_data_recv, u32 ms
TCP_INFO_DATA_SEGS_IN = 152  # tcpi_data_segs_in, u32
TCP_INFO_SND_WND = 228  # tcpi_snd_wnd, u32 bytes (Linux 5.4 and later)
TCP_INFO_BYTES = 232


@dataclass(frozen=True)
class Connection:
    """An accepted connection: its file descriptor and the socket's identity
    (`socket:[inode]`), which tells a reused descriptor from the viewer's own."""

    fd: int
    inode: str

    def alive(self) -> bool:
        try:
            return os.readlink(f"{FD_DIR}/{self.fd}") == self.inode
        except OSError:
            return False

    def unsent(self) -> int | None:
        """Bytes the viewer has not acknowledged (None: the connection is gone)."""
        if not self.alive():
            return None
        try:
            return struct.unpack("i", fcntl.ioctl(self.fd, SIOCOUTQ, b"\0" * 4))[0]
        except OSError:
            return None

    def window(self) -> int | None:
        """The receive window the viewer last advertised, bytes (None: unknown)."""
        info = self._info()
        if info is None or len(info) < TCP_INFO_SND_WND + 4:
            return None
        return struct.unpack_from("I", info, TCP_INFO_SND_WND)[0]

    def recency(self) -> tuple[int, int]:
        """How lately the viewer sent something, smallest first: milliseconds since it
        last sent data, then (within the same millisecond) the fewer of its data
        segments received last (a viewer that has sent more than its opening request)."""
        info = self._info()
        if info is None:
            return (1 << 32, 0)
        return (struct.unpack_from("I", info, TCP_INFO_LAST_DATA_RECV)[0],
                -struct.unpack_from("I", info, TCP_INFO_DATA_SEGS_IN)[0])

    def _info(self) -> bytes | None:
        try:
            with socket.socket(fileno=os.dup(self.fd)) as sock:  # closes the duplicate only
                return sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, TCP_INFO_BYTES)
        except OSError:
            return None

    def set_send_buffer(self, size: int) -> None:
        try:
            with socket.socket(fileno=os.dup(self.fd)) as sock:  # closes the duplicate only
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, size)
        except OSError:
            pass


def accepted(port: int) -> list[Connection]:
    """The TCP connections of this process accepted on `port` (not its listening
    socket)."""
    if not os.path.isdir(FD_DIR):
        return []
    found = []
    for name in os.listdir(FD_DIR):
        try:
            link = os.readlink(f"{FD_DIR}/{name}")
            if not link.startswith("socket:"):
                continue
            sock = socket.socket(fileno=os.dup(int(name)))
        except (OSError, ValueError):
            continue
        try:
            if sock.type == socket.SOCK_STREAM and sock.family in (
                    socket.AF_INET, socket.AF_INET6) and sock.getsockname()[1] == port:
                sock.getpeername()  # OSError: the listening socket
                found.append(Connection(int(name), link))
        except OSError:
            continue
        finally:
            sock.close()  # the duplicate only
    return found
