"""The client library of the track service (docs/client.md): a `Client` from `connect`,
a `Feed` that publishes checked measurements, a `Picture` of every frame as NumPy
columns (`Frame`). Imports only the wire contract, NumPy and Zenoh."""

from ...wire import Rejected
from .feed import Feed
from .frames import Frame
from .picture import Picture
from .process import ServiceProcess
from .session import TLS, Client, connect, session_config

__all__ = ["TLS", "Client", "Feed", "Frame", "Picture", "Rejected", "ServiceProcess",
           "connect", "session_config"]
