"""A Foxglove WebSocket protocol client for the tests and benchmarks of `track-foxglove`
(the SDK has a server and no Python client).

It offers the subprotocol the SDK's server accepts (`foxglove.sdk.v1`), reads
`serverInfo` and the `advertise` messages, subscribes channels by topic and reads the
binary message frames (opcode 1, u32 subscription id, u64 log time in ns, the payload:
Foxglove WebSocket protocol v1, "Message Data"). Payloads decode with the schema that the
channel advertised: protobuf from its FileDescriptorSet, JSON as JSON.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import socket
import struct
from typing import Any

import aiohttp
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 1


def message_class(name: str, descriptor_set: bytes) -> Any:
    """The protobuf class of message `name` from a FileDescriptorSet (a channel's schema)."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


class FoxgloveClient:
    """One connection: `channels` by topic, `receive()` the next message's
    (topic, log time ns, payload)."""

    def __init__(self) -> None:
        self.http: aiohttp.ClientSession | None = None
        self.ws: aiohttp.ClientWebSocketResponse | None = None
        self.server_info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}
        self.topic_of: dict[int, str] = {}  # subscription id -> topic
        self._classes: dict[str, Any] = {}

    async def connect(self, url: str, subprotocol: str = SUBPROTOCOL,
                      advertised: set[str] | None = None, timeout: float = 20.0,
                      rcvbuf: int | None = None) -> None:
        """Connect and read until serverInfo and the `advertised` topics have come.
        `rcvbuf`: the socket's receive buffer, bytes (None: the system's, which grows to
        tens of MB and holds many frames that a slow reader has not taken)."""
        def make_socket(addr: Any) -> socket.socket:
            family, kind, proto, _, _ = addr
            sock = socket.socket(family, kind, proto)
            if rcvbuf is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            return sock

        self.http = aiohttp.ClientSession(
            connector=aiohttp.TCPConnector(socket_factory=make_socket))
        self.ws = await self.http.ws_connect(url, protocols=(subprotocol,), max_msg_size=0,
                                             autoping=True)
        want = advertised or set()

        async def until() -> None:
            while not self.server_info or not want <= set(self.channels):
                await self._text(await self.ws.receive())  # type: ignore[union-attr]

        await asyncio.wait_for(until(), timeout)

    async def _text(self, msg: aiohttp.WSMessage) -> None:
        if msg.type != aiohttp.WSMsgType.TEXT:
            if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                            aiohttp.WSMsgType.ERROR):
                raise ConnectionError(f"the server closed the connection: {msg.extra}")
            return
        body = json.loads(msg.data)
        if body.get("op") == "serverInfo":
            self.server_info = body
        elif body.get("op") == "advertise":
            for ch in body["channels"]:
                self.channels[ch["topic"]] = ch

    async def subscribe(self, *topics: str) -> None:
        subs = []
        for topic in topics:
            sub_id = len(self.topic_of) + 1
            self.topic_of[sub_id] = topic
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        await self.ws.send_str(json.dumps({"op": "subscribe",  # type: ignore[union-attr]
                                           "subscriptions": subs}))

    async def receive(self, timeout: float = 20.0) -> tuple[str, int, bytes]:
        """The next message of a subscribed channel (text messages read on the way)."""
        async def next_message() -> tuple[str, int, bytes]:
            while True:
                msg = await self.ws.receive()  # type: ignore[union-attr]
                if msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == MESSAGE_DATA:
                    sub_id, log_time = struct.unpack_from("<IQ", msg.data, 1)
                    return self.topic_of[sub_id], log_time, msg.data[13:]
                await self._text(msg)

        return await asyncio.wait_for(next_message(), timeout)

    def decode(self, topic: str, payload: bytes) -> Any:
        """The payload as the channel's schema says: a protobuf message or a JSON value."""
        ch = self.channels[topic]
        if ch["encoding"] == "json":
            return json.loads(payload)
        if ch["encoding"] != "protobuf":
            raise ValueError(f"{topic}: encoding {ch['encoding']!r}")
        cls = self._classes.get(topic)
        if cls is None:
            cls = self._classes[topic] = message_class(ch["schemaName"],
                                                       base64.b64decode(ch["schema"]))
        return cls.FromString(payload)

    async def close(self) -> None:
        if self.ws is not None:
            await self.ws.close()
        if self.http is not None:
            await self.http.close()


class PlainViewer:
    """A blocking client that takes one message at a time off its socket and nothing
    ahead of it (a browser or aiohttp reads on while its caller is busy): what is waiting
    for it is what its kernel's receive buffer and the server hold. Subscribes `topics`
    on connecting; `receive()` the next message's (topic, log time ns, payload)."""

    def __init__(self, port: int, topics: tuple[str, ...], rcvbuf: int,
                 timeout: float = 20.0) -> None:
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.settimeout(timeout)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                           f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {SUBPROTOCOL}"
                           "\r\n\r\n").encode())
        head = b""
        while not head.endswith(b"\r\n\r\n"):
            head += self._exactly(1)
        if b" 101 " not in head.split(b"\r\n", 1)[0]:
            raise ConnectionError(head.decode(errors="replace"))
        channels: dict[str, int] = {}
        while not set(topics) <= set(channels):
            opcode, data = self._message()
            if opcode == 1:
                body = json.loads(data)
                if body.get("op") == "advertise":
                    channels |= {ch["topic"]: ch["id"] for ch in body["channels"]}
        self.topic_of = {i + 1: topic for i, topic in enumerate(topics)}
        self._send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": channels[t]} for i, t in self.topic_of.items()]}).encode())

    def _exactly(self, n: int) -> bytes:
        buf = bytearray(n)
        view, got = memoryview(buf), 0
        while got < n:
            k = self.sock.recv_into(view[got:], n - got)
            if not k:
                raise ConnectionError("the server closed the connection")
            got += k
        return bytes(buf)

    def _message(self) -> tuple[int, bytes]:
        """The next whole message (fragments joined): its opcode and payload."""
        opcode, parts = 0, []
        while True:
            b0, b1 = self._exactly(2)
            size = b1 & 0x7F
            if size == 126:
                size = struct.unpack(">H", self._exactly(2))[0]
            elif size == 127:
                size = struct.unpack(">Q", self._exactly(8))[0]
            opcode = opcode or b0 & 0x0F
            parts.append(self._exactly(size))
            if b0 & 0x80:
                return opcode, b"".join(parts)

    def _send(self, data: bytes) -> None:
        mask = os.urandom(4)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
        head = bytes([0x81, 0x80 | 126]) + struct.pack(">H", len(data)) if len(data) > 125 \
            else bytes([0x81, 0x80 | len(data)])
        self.sock.sendall(head + mask + masked)

    def receive(self) -> tuple[str, int, bytes]:
        while True:
            opcode, data = self._message()
            if opcode == 2 and data[0] == MESSAGE_DATA:
                sub_id, log_time = struct.unpack_from("<IQ", data, 1)
                return self.topic_of[sub_id], log_time, data[13:]
            if opcode == 8:
                raise ConnectionError("the server closed the connection")

    def close(self) -> None:
        self.sock.close()
