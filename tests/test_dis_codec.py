"""The vectorised DIS codec (clients/dis/pdu.py) against opendis's own serialisation,
byte for byte, both ways; and the timestamps against the standard's units."""

from __future__ import annotations

import io

import numpy as np
import pytest
from opendis.DataInputStream import DataInputStream
from opendis.DataOutputStream import DataOutputStream
from opendis.dis7 import (
    EntityID,
    EntityStatePdu,
    EntityType,
    EulerAngles,
    RemoveEntityPdu,
    Vector3Double,
    Vector3Float,
)

from zenoh_track.clients.dis import pdu

TYPE_FIELDS = ("kind", "domain", "country", "category", "subcategory", "specific", "extra")
OPENDIS_TYPE = ("entityKind", "domain", "country", "category", "subcategory", "specific",
                "extra")


def random_states(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = pdu.entity_state(n)
    pdu.header(p, pdu.ENTITY_STATE, pdu.FAMILY_ENTITY_INFO, 3,
               rng.integers(0, 2**32, n, dtype=np.uint64))
    for f in ("site", "application", "entity"):
        p[f] = rng.integers(0, 65536, n)
    p["force"] = rng.integers(0, 4, n)
    for f in TYPE_FIELDS:
        hi = 65536 if f == "country" else 256
        p["entity_type"][f] = rng.integers(0, hi, n)
        p["alternative_type"][f] = rng.integers(0, hi, n)
    p["velocity"] = rng.normal(0, 300, (n, 3))
    p["location"] = rng.normal(0, 6.4e6, (n, 3))
    p["orientation"] = rng.uniform(-np.pi, np.pi, (n, 3))
    p["appearance"] = rng.integers(0, 2**32, n, dtype=np.uint64)
    p["dr_algorithm"] = rng.integers(1, 10, n)
    p["dr_parameters"] = rng.integers(0, 256, (n, 15))
    p["acceleration"] = rng.normal(0, 10, (n, 3))
    p["angular_velocity"] = rng.normal(0, 0.1, (n, 3))
    p["marking_set"] = pdu.MARKING_ASCII
    p["marking"] = pdu.markings([f"TRK{i:08d}"[: 1 + i % 11] for i in range(n)])
    p["capabilities"] = rng.integers(0, 2**32, n, dtype=np.uint64)
    return p


def opendis_state(row: np.void) -> EntityStatePdu:
    """The same PDU built with opendis's objects (every field set: some of its defaults
    are None or bytes that do not serialise)."""
    e = EntityStatePdu()
    e.exerciseID, e.timestamp, e.length = int(row["exercise"]), int(row["timestamp"]), 144
    e.pduType, e.protocolFamily, e.pduStatus = 1, 1, 0
    e.entityID = EntityID(int(row["site"]), int(row["application"]), int(row["entity"]))
    e.forceId = int(row["force"])
    e.entityType = EntityType(*(int(row["entity_type"][f]) for f in TYPE_FIELDS))
    e.alternativeEntityType = EntityType(*(int(row["alternative_type"][f])
                                           for f in TYPE_FIELDS))
    e.entityLinearVelocity = Vector3Float(*map(float, row["velocity"]))
    e.entityLocation = Vector3Double(*map(float, row["location"]))
    e.entityOrientation = EulerAngles(*map(float, row["orientation"]))
    e.entityAppearance = int(row["appearance"])
    dr = e.deadReckoningParameters
    dr.deadReckoningAlgorithm = int(row["dr_algorithm"])
    dr.parameters = [int(v) for v in row["dr_parameters"]]
    dr.entityLinearAcceleration = Vector3Float(*map(float, row["acceleration"]))
    dr.entityAngularVelocity = Vector3Float(*map(float, row["angular_velocity"]))
    e.marking.characterSet = int(row["marking_set"])
    e.marking.setString(row["marking"].decode())
    e.capabilities = int(row["capabilities"])
    return e


def serialise(obj: object) -> bytes:
    buf = io.BytesIO()
    obj.serialize(DataOutputStream(buf))  # type: ignore[attr-defined]
    return buf.getvalue()


def test_entity_state_bytes_equal_opendis() -> None:
    rows = random_states(200)
    ours = rows.tobytes()
    theirs = b"".join(serialise(opendis_state(r)) for r in rows)
    assert len(ours) == 200 * 144 and ours == theirs


def test_opendis_reads_our_entity_state_and_we_read_its() -> None:
    rows = random_states(50, seed=1)
    for row in rows:
        got = EntityStatePdu()
        got.parse(DataInputStream(io.BytesIO(row.tobytes())))
        assert (got.entityID.siteID, got.entityID.applicationID, got.entityID.entityID) == \
            (row["site"], row["application"], row["entity"])
        assert got.entityLocation.x == row["location"][0]  # float64 to the bit
        assert got.entityLinearVelocity.z == pytest.approx(float(row["velocity"][2]), rel=1e-7)
        assert got.deadReckoningParameters.deadReckoningAlgorithm == row["dr_algorithm"]
        assert got.marking.charactersString() == row["marking"].decode()
        back = np.frombuffer(serialise(got), pdu.ENTITY_STATE_PDU)[0]
        assert back.tobytes() == row.tobytes()


def test_remove_entity_bytes_equal_opendis() -> None:
    rows = pdu.remove_entity(20)
    pdu.header(rows, pdu.REMOVE_ENTITY, pdu.FAMILY_SIMULATION_MANAGEMENT, 9,
               np.arange(20) * 12345)
    rows["originating"]["site"], rows["originating"]["application"] = 17, 4000
    rows["receiving"]["site"], rows["receiving"]["application"] = 17, 4000
    rows["receiving"]["entity"] = np.arange(20) + 100
    rows["request_id"] = np.arange(20) * 7
    theirs = []
    for r in rows:
        e = RemoveEntityPdu(int(r["request_id"]))
        e.exerciseID, e.timestamp, e.length, e.pduStatus = 9, int(r["timestamp"]), 28, 0
        e.pduType, e.protocolFamily = 12, 5  # opendis's instances start at 0
        e.originatingEntityID = EntityID(17, 4000, 0)
        e.receivingEntityID = EntityID(17, 4000, int(r["receiving"]["entity"]))
        theirs.append(serialise(e))
    assert rows.tobytes() == b"".join(theirs)


def test_timestamps_count_the_hour_in_2_31_units_with_the_absolute_bit() -> None:
    t = np.array([0.0, 1.0, 1799.5, 3599.9999, 3600.0 + 12.25, 1.7e9 + 0.5])
    for absolute in (True, False):
        stamp = pdu.timestamp(t, absolute)
        assert np.all((stamp & 1) == absolute)
        back = pdu.seconds_past_hour(stamp)
        assert np.abs(back - np.mod(t, 3600.0)).max() <= 3600.0 / 2**31
    assert pdu.timestamp([1.0], True)[0] >> 1 == round(2**31 / 3600)  # one second
    assert pdu.parse_entity_type("1.2.225.1") == (1, 2, 225, 1, 0, 0, 0)
    with pytest.raises(ValueError):
        pdu.parse_entity_type("1.2.70000")
