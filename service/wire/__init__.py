"""The wire contract (version 1, docs/protocol.md): keys, MessagePack codecs,
the checks of input messages and the Zenoh session options.

The one package that both the service and the clients import. It needs only msgpack
and the standard library (Zenoh is imported when a session is opened), so a display or
a feed can be written against it without the estimation code (tests/test_layers.py).
"""

from .codec import Rejected, decode_frame, decode_map, f64_bin, f64_list, pack, unpack
from .keys import CHUNK, DEFAULT_NS, PROTOCOL_VERSION, SHOWN, STATUSES, Keys
from .messages import Measurement, parse_clock, parse_full, parse_measurement
from .plots import MAX_DETECTIONS, PlotScan, parse_plots
from .session import (
    BLOCK_WAIT_US,
    DEFAULT_ENDPOINT,
    add_zenoh_args,
    free_port,
    open_session,
    patient,
    peer_config,
    wait_for_tracker,
    zenoh_config,
)

__all__ = [
    "BLOCK_WAIT_US", "CHUNK", "DEFAULT_ENDPOINT", "DEFAULT_NS", "MAX_DETECTIONS",
    "PROTOCOL_VERSION", "SHOWN", "STATUSES", "Keys", "Measurement", "PlotScan", "Rejected",
    "add_zenoh_args", "decode_frame", "decode_map", "f64_bin", "f64_list", "free_port",
    "open_session", "pack", "parse_clock", "parse_full", "parse_measurement", "parse_plots",
    "patient", "peer_config", "unpack", "wait_for_tracker", "zenoh_config",
]
