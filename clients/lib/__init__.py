"""The client library of the track service (docs/client.md): a `Client` from `connect`,
a `Feed` that publishes checked measurements, a `Picture` of every frame as NumPy
columns (`Frame`), the frames of several instances merged into one picture (`Merge`).
Imports only the wire contract, NumPy and Zenoh."""

from zenoh_track.clients.lib.feed import Feed
from zenoh_track.clients.lib.frames import Frame
from zenoh_track.clients.lib.merge import Merge
from zenoh_track.clients.lib.picture import Picture
from zenoh_track.clients.lib.process import ServiceProcess
from zenoh_track.clients.lib.session import TLS, Client, connect, session_config
from zenoh_track.wire import Rejected

__all__ = ["TLS", "Client", "Feed", "Frame", "Merge", "Picture", "Rejected",
           "ServiceProcess", "connect", "session_config"]
