"""Key expressions of the contract (docs/protocol.md) and its constants."""

from __future__ import annotations

import math
import re

PROTOCOL_VERSION = 1
DEFAULT_NS = "track"
CHUNK = re.compile(r"^[A-Za-z0-9_-]+$")  # one key chunk: sensor, target, instance
STATUSES = ("tentative", "confirmed", "coasting")  # display/<id> status
SHOWN = ("prediction", "blend", "smoothed")  # display/<id> shown (project extension)

# ---------------------------------------------------------------- input limits
# (docs/protocol.md §4): an input beyond one is rejected with a reason, nothing applied
MAX_MEAS_BYTES = 64 * 1024  # bytes of one meas/ or clock payload
MAX_SCAN_BYTES = 16 * 1024 * 1024  # bytes of one plots/ (or scan/) payload
MAX_ROWS = 100_000  # detections of one plots/ scan (rows of one scan/ message)
MAX_TIME = 1e10  # s: |t| beyond this is absurd (Unix seconds reach it in the year 2286)
# s: times this close are one instant: "strictly before t" (a display instant before an
# input), "older than the track's last update", "at the same time" (a duplicate)
TIME_TOL = 1e-6
MAX_DISTANCE = 1e9  # m: range, every coordinate and every distance noise
# angles: additive noise carries a measurement of a target at the zenith (scenario B's
# overhead pass) or at az = 2 pi a little past the bound; ANGLE_MARGIN (about 6 sigma of
# the default 0.5 deg noise) keeps those, and refuses everything farther
ANGLE_MARGIN = 0.05  # rad
MAX_AZ = 2 * math.pi + ANGLE_MARGIN  # rad: |az| ([-pi, pi] and [0, 2 pi) conventions fit)
MAX_EL = math.pi / 2 + ANGLE_MARGIN  # rad: |el|
MAX_ANGLE_NOISE = math.pi / 2  # rad: saz, sel (a wider 1-sigma says nothing of the angle)
MAX_SEQ = 2**53  # seq in [0, MAX_SEQ]
# s: sigma_t, the std of a measurement's time (a time a minute off locates nothing)
MAX_TIME_NOISE = 60.0
# the inclusive bounds of every numeric field (list fields: of each element)
BOUNDS: dict[str, tuple[float, float]] = {
    "t": (-MAX_TIME, MAX_TIME),
    "r": (0.0, MAX_DISTANCE), "az": (-MAX_AZ, MAX_AZ), "el": (-MAX_EL, MAX_EL),
    "sr": (0.0, MAX_DISTANCE), "saz": (0.0, MAX_ANGLE_NOISE), "sel": (0.0, MAX_ANGLE_NOISE),
    "sigma": (0.0, MAX_DISTANCE), "sigma_t": (0.0, MAX_TIME_NOISE),
    "pos": (-MAX_DISTANCE, MAX_DISTANCE), "sensor_pos": (-MAX_DISTANCE, MAX_DISTANCE),
}


class Keys:
    """Key expressions of one namespace."""

    def __init__(self, ns: str = DEFAULT_NS) -> None:
        self.ns = ns.strip("/")

    def space(self, what: str) -> str:
        """Everything under `<ns>/<what>/`, e.g. space("meas") = `<ns>/meas/**`."""
        return f"{self.ns}/{what}/**"

    def meas(self, sensor: str = "*", target: str = "*") -> str:
        return f"{self.ns}/meas/{sensor}/{target}"

    def plots(self, sensor: str = "*") -> str:
        return f"{self.ns}/plots/{sensor}"

    def display(self, target: str = "*") -> str:
        return f"{self.ns}/display/{target}"

    def tracks(self, target: str = "*") -> str:
        return f"{self.ns}/tracks/{target}"

    def truth(self, target: str = "*") -> str:
        """Extension: ground truth published by simulation feeds for evaluation."""
        return f"{self.ns}/truth/{target}"

    def errors(self, sensor: str = "*") -> str:
        return f"{self.ns}/errors/{sensor}"

    def alive(self, instance: str = "*") -> str:
        return f"{self.ns}/alive/tracker/{instance}"

    @property
    def frame(self) -> str:
        return f"{self.ns}/frame"

    @property
    def states(self) -> str:
        """Extension: the filtered states of each applied batch, columnar (bulk consumers)."""
        return f"{self.ns}/states"

    def scan(self, sensor: str = "*") -> str:
        """1.1: a batched labelled scan, columnar."""
        return f"{self.ns}/scan/{sensor}"

    @property
    def clock(self) -> str:
        return f"{self.ns}/clock"

    @property
    def status(self) -> str:
        return f"{self.ns}/status"

    @property
    def origin(self) -> str:
        """1.2: the deployment's geodetic frame (`wire.origin`), a queryable."""
        return f"{self.ns}/origin"

    def gateway(self, name: str = "*") -> str:
        """1.2: a gateway's own status, a queryable (`<ns>/gateway/<name>/status`)."""
        return f"{self.ns}/gateway/{name}/status"

    def chunks_after(self, key: str, what: str) -> list[str]:
        """The chunks of `key` after `<ns>/<what>/` (empty if the key is elsewhere)."""
        prefix = f"{self.ns}/{what}/"
        return key[len(prefix):].split("/") if key.startswith(prefix) else []
