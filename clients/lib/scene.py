"""The picture as Foxglove draws it: one implementation for the live server
(`track-foxglove`) and the recordings (`track-record`'s `/scene` channel), so Foxglove and
Lichtblick show the same thing live and afterwards, without any plug-in (docs/foxglove.md).

`scene_update`: a `foxglove.SceneUpdate` (protobuf) in frame `enu` (metres, x East,
y North, z up). The tracks of each status are one scene entity (`tracks/<status>`), its
primitives one per track: a cube of `marker` metres coloured by status, an arrow along
the velocity (the distance flown in `arrow_s` seconds), the id as a label and, where it
is larger than the cube, a translucent sphere of radius sigma (1 sigma). One entity per
status rather than per track: Foxglove draws each entity's primitives of a kind together,
and 10,000 entities would be 40,000 draws. Sensors and interceptors are entities of
their own. Every update first deletes all entities, so tracks that ended disappear.

`location_fixes`: a `foxglove.LocationFixes`, one `LocationFix` per track (latitude,
longitude, altitude from the deployment's geodetic origin by pymap3d, its 1-sigma as a
diagonal covariance, the colour of its status, the id as frame_id) for the Map panel.

Message and field numbers: Foxglove's schemas (the SDK's `get_schema()`, shipped here as
`schemas/*.bin`, the FileDescriptorSets that the channels and MCAP files carry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np
import numpy.typing as npt

from zenoh_track.clients.lib import protobuf_rows as pb
from zenoh_track.clients.lib.frames import NO_STATUS, STATUS_NAMES, Frame

F64 = npt.NDArray[np.float64]
TOPIC = "/scene"
FRAME_ID = "enu"
SCENE_SCHEMA = "foxglove.SceneUpdate"
LOCATION_SCHEMA = "foxglove.LocationFixes"
# RGB by status code (wire.STATUSES order: tentative, confirmed, coasting; then unknown)
COLOURS = ((0.95, 0.75, 0.10), (0.20, 0.80, 0.30), (0.60, 0.60, 0.60), (0.25, 0.55, 1.00))
SENSOR_RGB = (0.89, 0.91, 0.94)
INTERCEPTOR_RGB = (0.96, 0.45, 0.71)
SIGMA_ALPHA = 0.25
DELETE_ALL = 1  # SceneEntityDeletion.Type.ALL
DIAGONAL_KNOWN = 2  # LocationFix.PositionCovarianceType
# SceneEntity fields
E_TIMESTAMP, E_FRAME, E_ID, E_METADATA = 1, 2, 3, 6
E_ARROWS, E_CUBES, E_SPHERES, E_TEXTS = 7, 8, 9, 13


def schema(name: str) -> bytes:
    """The FileDescriptorSet of a Foxglove message (`foxglove.SceneUpdate`, ...)."""
    return (resources.files("zenoh_track.clients.lib") / "schemas" / f"{name}.bin") \
        .read_bytes()


@dataclass(frozen=True)
class Markers:
    """Things drawn alike: one row per thing (pos, vel: (n, 3) m, m/s)."""

    entity: str
    names: list[str]
    pos: F64
    vel: F64 | None
    rgb: tuple[float, float, float]
    sigma: F64 | None = None  # 1-sigma spheres where larger than the marker


def _timestamp(number: int, t: float) -> pb.Parts:
    t = max(t, 0.0) if math.isfinite(t) else 0.0
    sec = math.floor(t)
    nsec = min(int(round((t - sec) * 1e9)), 999_999_999)
    body = (pb.tag(1, pb.VARINT) + pb.varint(sec) if sec else b"") + \
        (pb.tag(2, pb.VARINT) + pb.varint(nsec) if nsec else b"")
    return [pb.tag(number, pb.LEN) + pb.varint(len(body)) + body]


def _colour(number: int, rgb: tuple[float, float, float], alpha: float) -> pb.Parts:
    return pb.message(number, [*pb.double(1, rgb[0]), *pb.double(2, rgb[1]),
                               *pb.double(3, rgb[2]), *pb.double(4, alpha)])


def _vec3(number: int, xyz: F64 | float) -> pb.Parts:
    """A Vector3 field: three columns of an (n, 3) table, or the same length thrice."""
    if isinstance(xyz, float):
        return pb.message(number, [*pb.double(1, xyz), *pb.double(2, xyz), *pb.double(3, xyz)])
    return pb.message(number, [*pb.doubles(1, xyz, 0), *pb.doubles(2, xyz, 1),
                               *pb.doubles(3, xyz, 2)])


def _pose(pos: F64, turn: F64 | None = None) -> pb.Parts:
    """A Pose field (1 in every primitive): position, orientation (identity when None,
    else `headings`' y, z, w: their x is 0)."""
    q = pb.message(2, pb.double(4, 1.0)) if turn is None else pb.message(2, [
        *pb.doubles(2, turn, 0), *pb.doubles(3, turn, 1), *pb.doubles(4, turn, 2)])
    return pb.message(1, [*_vec3(1, pos), *q])


def headings(vel: F64) -> F64:
    """Quaternions (y, z, w; x is 0) turning +x onto each velocity (an arrow points along
    its pose's +x): the half-angle form of the rotation from (1, 0, 0) to u, about the
    axis (1, 0, 0) x u = (0, -uz, uy); half a turn about z for u = -x."""
    u = vel / np.linalg.norm(vel, axis=1, keepdims=True)
    q = np.column_stack([-u[:, 2], u[:, 1], 1.0 + u[:, 0]])
    q[q[:, 2] < 1e-9] = (0.0, 1.0, 0.0)
    out: F64 = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


def _entity(m: Markers, stamp: pb.Parts, marker: float, arrow_s: float,
            labels: bool) -> list[pb.Block]:
    n = len(m.names)
    pos = np.ascontiguousarray(m.pos, dtype=np.float64).reshape(n, 3)
    head = [*stamp, *pb.string(E_FRAME, FRAME_ID), *pb.string(E_ID, m.entity),
            *pb.message(E_METADATA, [*pb.string(1, "count"), *pb.string(2, str(n))])]
    blocks: list[pb.Block] = [b"".join(p for p in head if isinstance(p, bytes))]
    # in field order (arrows 7, cubes 8, spheres 9, texts 13), as the SDK writes them
    if m.vel is not None:
        vel = np.ascontiguousarray(m.vel, dtype=np.float64).reshape(n, 3)
        speed = np.linalg.norm(vel, axis=1)
        moving = np.flatnonzero(speed > 0.0)
        length = speed[moving] * arrow_s
        blocks.append(pb.Rows(pb.message(E_ARROWS, [
            *_pose(pos[moving], headings(vel[moving])), *pb.double(2, 0.8 * length),
            *pb.double(3, np.maximum(marker / 5.0, 0.02 * length)),
            *pb.double(4, 0.2 * length), *pb.double(5, np.maximum(marker / 2.0, 0.06 * length)),
            *_colour(6, m.rgb, 0.9)]), len(moving)))
    blocks.append(pb.Rows(pb.message(E_CUBES, [*_pose(pos), *_vec3(2, float(marker)),
                                              *_colour(3, m.rgb, 1.0)]), n))
    if m.sigma is not None:
        big = np.flatnonzero(2.0 * m.sigma > marker)
        diameter = np.repeat(2.0 * m.sigma[big, None], 3, axis=1)
        blocks.append(pb.Rows(pb.message(E_SPHERES, [
            *_pose(pos[big]), *_vec3(2, diameter), *_colour(3, m.rgb, SIGMA_ALPHA)]), len(big)))
    if labels:
        for rows, text in pb.by_length(m.names):
            blocks.append(pb.Rows(pb.message(E_TEXTS, [
                *_pose(pos[rows]), *pb.boolean(2, True), *pb.double(3, 12.0),
                *pb.boolean(4, True), *_colour(5, m.rgb, 1.0), *pb.strings(6, text)]),
                len(rows)))
    return pb.field(2, blocks)


def track_markers(frame: Frame, codes: npt.NDArray[np.uint8] | None = None) -> list[Markers]:
    """The tracks of a frame, one Markers per status present (`codes`: instead of the
    frame's own status codes)."""
    codes = frame.codes if codes is None else codes
    codes = np.minimum(codes, NO_STATUS)
    out = []
    for code in np.unique(codes):
        rows = np.flatnonzero(codes == code)
        out.append(Markers(f"tracks/{STATUS_NAMES[code] if code < NO_STATUS else 'unknown'}",
                           [frame.id_list[i] for i in rows], frame.pos[rows], frame.vel[rows],
                           COLOURS[int(code)], frame.sigma[rows]))
    return out


def scene_update(frame: Frame, *, marker: float = 100.0, arrow_s: float = 10.0,
                 labels: bool = True, codes: npt.NDArray[np.uint8] | None = None,
                 sensors: list[dict[str, Any]] | None = None,
                 interceptors: list[dict[str, Any]] | None = None) -> bytes:
    """The SceneUpdate of one frame, with the sensors ({id, pos}) and interceptors
    ({id, pos, vel}) when given."""
    stamp = _timestamp(E_TIMESTAMP, frame.t)
    deletion = b"".join(p for p in [*_timestamp(1, frame.t), *pb.enum(2, DELETE_ALL)]
                        if isinstance(p, bytes))
    out: list[pb.Block] = [pb.tag(1, pb.LEN) + pb.varint(len(deletion)) + deletion]
    groups = track_markers(frame, codes)
    for name, things, rgb in (("sensors", sensors, SENSOR_RGB),
                              ("interceptors", interceptors, INTERCEPTOR_RGB)):
        if things:
            pos = np.array([s["pos"] for s in things], dtype=np.float64).reshape(-1, 3)
            vel = np.array([s.get("vel", [0.0] * 3) for s in things], np.float64).reshape(-1, 3)
            groups.append(Markers(name, [str(s["id"]) for s in things], pos,
                                  vel if name == "interceptors" else None, rgb))
    for m in groups:
        out += _entity(m, stamp, marker, arrow_s, labels)
    return pb.assemble(out)


def location_fixes(frame: Frame, origin: tuple[float, float, float] | list[float],
                   codes: npt.NDArray[np.uint8] | None = None) -> bytes:
    """The LocationFixes of one frame about the geodetic `origin` (lat, lon deg, alt m)."""
    import pymap3d  # type: ignore[import-untyped]

    codes = np.minimum(frame.codes if codes is None else codes, NO_STATUS)
    lat, lon, alt = pymap3d.enu2geodetic(frame.pos[:, 0], frame.pos[:, 1], frame.pos[:, 2],
                                         *origin)
    table = np.column_stack([np.asarray(v, dtype=np.float64).reshape(-1)
                             for v in (lat, lon, alt)])
    var = frame.sigma ** 2
    cov = np.zeros((len(frame), 9))
    cov[:, 0] = cov[:, 4] = cov[:, 8] = var
    stamp = _timestamp(6, frame.t)
    out: list[pb.Block] = []
    for rows, names in pb.by_length(frame.id_list):
        for code in np.unique(codes[rows]):
            keep = codes[rows] == code
            sub = rows[keep]
            geo = table[sub]
            cov_bytes = cov[sub].view(np.uint8).reshape(len(sub), 72)
            out.append(pb.Rows(pb.message(1, [
                *pb.doubles(1, geo, 0), *pb.doubles(2, geo, 1), *pb.doubles(3, geo, 2),
                pb.tag(4, pb.LEN) + pb.varint(72), pb.Column(cov_bytes),
                *pb.enum(5, DIAGONAL_KNOWN), *stamp, *pb.strings(7, names[keep]),
                *_colour(8, COLOURS[int(code)], 1.0)]), len(sub)))
    return pb.assemble(out)
