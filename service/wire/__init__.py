"""The wire contract (version 1, docs/protocol.md): keys, MessagePack codecs,
the checks of input messages and the Zenoh session options.

The one package that both the service and the clients import. It needs only msgpack
and the standard library (Zenoh is imported when a session is opened), so a display or
a feed can be written against it without the estimation code (tests/test_layers.py).
"""

from .cli import CONNECT_TIMEOUT, add_version, fail, missing_extra, need, open_or_exit, read_file
from .codec import (
    MSGPACK_ENCODING,
    REASON_CODES,
    Rejected,
    check_size,
    decode_frame,
    decode_map,
    f64_bin,
    f64_list,
    pack,
    reason_code,
    unpack,
)
from .keys import (
    BOUNDS,
    CHUNK,
    DEFAULT_NS,
    MAX_MEAS_BYTES,
    MAX_ROWS,
    MAX_SCAN_BYTES,
    MAX_TIME,
    PROTOCOL_VERSION,
    SHOWN,
    STATUSES,
    TIME_TOL,
    Keys,
)
from .messages import Measurement, parse_clock, parse_full, parse_measurement
from .origin import Origin, origin_message, parse_origin, parse_origin_message
from .plots import MAX_DETECTIONS, PlotScan, bad_rows, parse_plots
from .scans import LabelledScan, ScanColumns, parse_scan, parse_scan_columns
from .session import (
    BLOCK_WAIT_US,
    CONNECT_RETRY,
    DEFAULT_ENDPOINT,
    add_zenoh_args,
    free_port,
    listen_config,
    open_session,
    patient,
    peer_config,
    quick_retry,
    stamp_ns,
    stamping,
    wait_for_tracker,
    zenoh_config,
)
from .singles import Singles, parse_singles
from .stopping import STOP_GRACE, Stop, on_signals

__all__ = [
    "BLOCK_WAIT_US", "BOUNDS", "CHUNK", "CONNECT_RETRY", "DEFAULT_ENDPOINT", "DEFAULT_NS",
    "MAX_DETECTIONS", "MAX_MEAS_BYTES", "MAX_ROWS", "MAX_SCAN_BYTES", "MAX_TIME",
    "TIME_TOL", "MSGPACK_ENCODING", "PROTOCOL_VERSION", "REASON_CODES", "SHOWN", "STATUSES", "Keys",
    "LabelledScan", "Measurement", "PlotScan", "Rejected", "add_zenoh_args", "bad_rows",
    "check_size", "decode_frame", "decode_map", "f64_bin", "f64_list", "free_port",
    "open_session", "pack", "parse_clock", "parse_full", "parse_measurement", "parse_plots",
    "parse_scan", "parse_scan_columns", "parse_singles", "ScanColumns", "Singles", "patient",
    "listen_config", "peer_config", "quick_retry", "stamp_ns", "stamping",
    "reason_code", "unpack",
    "wait_for_tracker", "zenoh_config", "CONNECT_TIMEOUT", "fail", "open_or_exit", "read_file",
    "add_version", "missing_extra", "need", "STOP_GRACE", "Stop", "on_signals",
    "Origin", "origin_message", "parse_origin", "parse_origin_message",
]
