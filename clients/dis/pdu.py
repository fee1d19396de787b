"""The DIS PDUs the gateway speaks, as NumPy structured types written from IEEE 1278.1
(version 7): the PDU header (5.2.1 / 6.2.66), the Entity State PDU without variable
parameters (7.2.2, 144 octets) and the Remove Entity PDU (7.5.3, 28 octets). Every field
is big-endian (network order). A whole batch of datagrams is decoded or encoded in one
array operation; `tests/test_dis_codec.py` checks the bytes against opendis's own
serialisation, field by field, both ways.

Why not opendis itself: its objects read and write one field at a time in Python (about
30 calls per PDU; at 10,000 entities a second that is the gateway's whole budget), and its
only release pins NumPy below 2, which the service requires."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

VERSION = 7  # IEEE 1278.1-2012 (DIS 7)
ENTITY_STATE = 1  # PDU type (UID 4)
REMOVE_ENTITY = 12
FAMILY_ENTITY_INFO = 1  # protocol family (UID 5)
FAMILY_SIMULATION_MANAGEMENT = 5
HEADER_SIZE = 12
MARKING_ASCII = 1  # character set (UID 45)
DEACTIVATED = 1 << 23  # appearance bit 23, "State": the entity is deactivated (UID 31-43)
ABSOLUTE = 1  # timestamp's least significant bit: 1 absolute (UTC), 0 relative
TICKS_PER_HOUR = 2**31  # timestamp units: 3600 s / 2^31 past the hour (6.2.88)

HEADER_FIELDS = [
    ("version", "u1"), ("exercise", "u1"), ("pdu_type", "u1"), ("family", "u1"),
    ("timestamp", ">u4"), ("length", ">u2"), ("status", "u1"), ("padding", "u1"),
]
HEADER = np.dtype(HEADER_FIELDS)
ENTITY_ID = [("site", ">u2"), ("application", ">u2"), ("entity", ">u2")]
ENTITY_TYPE = [("kind", "u1"), ("domain", "u1"), ("country", ">u2"), ("category", "u1"),
               ("subcategory", "u1"), ("specific", "u1"), ("extra", "u1")]
ENTITY_STATE_PDU = np.dtype([
    *HEADER_FIELDS, *ENTITY_ID, ("force", "u1"), ("variable_count", "u1"),
    ("entity_type", ENTITY_TYPE), ("alternative_type", ENTITY_TYPE),
    ("velocity", ">f4", (3,)),  # m/s, in the frame the dead-reckoning algorithm names
    ("location", ">f8", (3,)),  # m, geocentric (ECEF, WGS-84)
    ("orientation", ">f4", (3,)),  # psi, theta, phi, rad
    ("appearance", ">u4"),
    ("dr_algorithm", "u1"), ("dr_parameters", "u1", (15,)),
    ("acceleration", ">f4", (3,)), ("angular_velocity", ">f4", (3,)),  # m/s^2, rad/s body
    ("marking_set", "u1"), ("marking", "S11"),
    ("capabilities", ">u4"),
])
REMOVE_ENTITY_PDU = np.dtype([
    *HEADER_FIELDS, ("originating", ENTITY_ID), ("receiving", ENTITY_ID), ("request_id", ">u4"),
])
assert HEADER.itemsize == HEADER_SIZE
assert ENTITY_STATE_PDU.itemsize == 144 and REMOVE_ENTITY_PDU.itemsize == 28


def header(pdus: npt.NDArray[np.void], pdu_type: int, family: int, exercise: int,
           timestamp: npt.ArrayLike) -> None:
    """Fill the header fields of a block of PDUs of one type (its own size as length)."""
    pdus["version"], pdus["exercise"] = VERSION, exercise
    pdus["pdu_type"], pdus["family"] = pdu_type, family
    pdus["timestamp"], pdus["length"] = timestamp, pdus.dtype.itemsize
    pdus["status"], pdus["padding"] = 0, 0


def entity_state(n: int) -> npt.NDArray[np.void]:
    """N zeroed Entity State PDUs (fill every field you need, then `header`)."""
    return np.zeros(n, ENTITY_STATE_PDU)


def remove_entity(n: int) -> npt.NDArray[np.void]:
    return np.zeros(n, REMOVE_ENTITY_PDU)


def timestamp(seconds: npt.ArrayLike, absolute: bool) -> npt.NDArray[np.uint32]:
    """DIS timestamps of times in seconds (Unix time, or any clock whose hours start at
    multiples of 3600 s): the time past the hour in units of 3600/2^31 s, shifted left
    one bit, the low bit set for absolute (UTC) time."""
    past = np.mod(np.asarray(seconds, float), 3600.0)
    ticks = np.minimum(np.round(past * (TICKS_PER_HOUR / 3600.0)), TICKS_PER_HOUR - 1)
    out: npt.NDArray[np.uint32] = (ticks.astype(np.uint32) << 1) | np.uint32(ABSOLUTE if
                                                                            absolute else 0)
    return out


def seconds_past_hour(stamp: npt.NDArray[np.integer]) -> npt.NDArray[np.float64]:
    """The time past the hour, s, of DIS timestamps (the low bit dropped)."""
    return (np.asarray(stamp, np.uint32) >> 1).astype(float) * (3600.0 / TICKS_PER_HOUR)


def markings(texts: list[str]) -> npt.NDArray[np.bytes_]:
    """ASCII markings, 11 characters at most (the caller shortens longer ones)."""
    return np.array([t.encode("ascii", "replace")[:11] for t in texts], "S11")


def parse_entity_type(text: str) -> tuple[int, ...]:
    """`KIND.DOMAIN.COUNTRY.CATEGORY.SUBCATEGORY.SPECIFIC.EXTRA` (SISO-REF-010 numbers);
    missing trailing numbers are 0. ValueError for anything else."""
    parts = [int(v) for v in text.split(".")]
    if not 1 <= len(parts) <= 7:
        raise ValueError(f"entity type takes 1 to 7 numbers K.D.C.C.S.S.E, not {text!r}")
    parts += [0] * (7 - len(parts))
    limits = (255, 255, 65535, 255, 255, 255, 255)
    if any(not 0 <= v <= hi for v, hi in zip(parts, limits, strict=True)):
        raise ValueError(f"entity type {text!r}: a number out of range")
    return tuple(parts)
