"""Key expressions of the contract (docs/protocol.md) and its constants."""

from __future__ import annotations

import re

PROTOCOL_VERSION = 1
DEFAULT_NS = "track"
CHUNK = re.compile(r"^[A-Za-z0-9_-]+$")  # one key chunk: sensor, target, instance
STATUSES = ("tentative", "confirmed", "coasting")  # display/<id> status
SHOWN = ("prediction", "blend", "smoothed")  # display/<id> shown (project extension)


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
    def clock(self) -> str:
        return f"{self.ns}/clock"

    @property
    def status(self) -> str:
        return f"{self.ns}/status"

    def chunks_after(self, key: str, what: str) -> list[str]:
        """The chunks of `key` after `<ns>/<what>/` (empty if the key is elsewhere)."""
        prefix = f"{self.ns}/{what}/"
        return key[len(prefix):].split("/") if key.startswith(prefix) else []
