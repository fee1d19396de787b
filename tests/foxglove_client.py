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
