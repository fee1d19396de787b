"""The display channel of a recording: the picture of each `frame` as a Foxglove
`foxglove.SceneUpdate`, JSON-encoded, so Foxglove and Lichtblick draw the tracks of an
MCAP recording in their 3D panel without any plug-in (docs/clients.md).

Each track is one scene entity in frame `enu` (metres, x East, y North, z up): a sphere
of radius sigma (at least `marker` m, so a well-known track stays visible at the scale of
the picture), an arrow along the velocity (its length the distance flown in `arrow_s`
seconds), and its id as a label, coloured by status. Entity metadata carries status,
sigma and speed, shown when the entity is clicked. Every update first deletes all
entities, so tracks that ended disappear.

The JSON schema below is this project's own description of the subset of the
foxglove.SceneUpdate fields written here (field names and meanings from Foxglove's
published message schemas, docs.foxglove.dev "SceneUpdate").
"""

from __future__ import annotations

import json
import math
from typing import Any

SCHEMA_NAME = "foxglove.SceneUpdate"
TOPIC = "/scene"
FRAME_ID = "enu"
COLOURS = {  # RGBA by display status; unknown (no display/ keys recorded): blue
    "confirmed": (0.20, 0.80, 0.30), "tentative": (0.95, 0.75, 0.10),
    "coasting": (0.60, 0.60, 0.60), None: (0.25, 0.55, 1.00)}

_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"},
                                          "nsec": {"type": "integer"}}}


def _obj(**props: Any) -> dict[str, Any]:
    return {"type": "object", "properties": props}


def _array(item: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "items": item}


_NUM, _STR, _BOOL = {"type": "number"}, {"type": "string"}, {"type": "boolean"}
SCHEMA = {
    "title": SCHEMA_NAME,
    "description": "A visual scene: entities to add or replace, and deletions",
    **_obj(
        deletions=_array(_obj(timestamp=_TIME, type={"type": "integer"}, id=_STR)),
        entities=_array(_obj(
            timestamp=_TIME, frame_id=_STR, id=_STR, lifetime=_TIME, frame_locked=_BOOL,
            metadata=_array(_obj(key=_STR, value=_STR)),
            arrows=_array(_obj(pose=_POSE, shaft_length=_NUM, shaft_diameter=_NUM,
                               head_length=_NUM, head_diameter=_NUM, color=_COLOR)),
            spheres=_array(_obj(pose=_POSE, size=_VEC3, color=_COLOR)),
            texts=_array(_obj(pose=_POSE, billboard=_BOOL, font_size=_NUM,
                              scale_invariant=_BOOL, color=_COLOR, text=_STR)),
        )),
    ),
}
SCHEMA_BYTES = json.dumps(SCHEMA, separators=(",", ":")).encode()
DELETE_ALL = 1  # SceneEntityDeletion.type ALL


def _stamp(t: float) -> dict[str, int]:
    t = max(t, 0.0)
    sec = math.floor(t)
    return {"sec": sec, "nsec": min(int(round((t - sec) * 1e9)), 999_999_999)}


IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def _heading(v: tuple[float, float, float]) -> dict[str, float]:
    """The quaternion turning +x onto v (an arrow points along its pose's +x)."""
    n = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    if n == 0.0:
        return IDENTITY
    ux, uy, uz = v[0] / n, v[1] / n, v[2] / n
    w = 1.0 + ux  # half-angle form of the rotation from (1, 0, 0) to u: axis (1,0,0) x u
    if w < 1e-9:  # u = -x: half a turn about z
        return {"x": 0.0, "y": 0.0, "z": 1.0, "w": 0.0}
    q = (0.0, -uz, uy, w)
    qn = math.sqrt(sum(c * c for c in q))
    return {"x": q[0] / qn, "y": q[1] / qn, "z": q[2] / qn, "w": q[3] / qn}


def scene_update(t: float, ids: list[str], pos: list[float], vel: list[float],
                 sigma: list[float], status: dict[str, str], *, marker: float = 100.0,
                 arrow_s: float = 10.0) -> bytes:
    """The JSON SceneUpdate of one frame (pos, vel: flat x, y, z per track)."""
    stamp = _stamp(t)
    entities = []
    for n, tid in enumerate(ids):
        p = {"x": round(pos[3 * n], 2), "y": round(pos[3 * n + 1], 2),
             "z": round(pos[3 * n + 2], 2)}
        v = (vel[3 * n], vel[3 * n + 1], vel[3 * n + 2])
        speed = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        st = status.get(tid)
        r, g, b = COLOURS.get(st, COLOURS[None])
        size = round(2.0 * max(sigma[n], marker / 2.0), 2)
        ent: dict[str, Any] = {
            "timestamp": stamp, "frame_id": FRAME_ID, "id": tid,
            "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
            "metadata": [{"key": "status", "value": st or "-"},
                         {"key": "sigma_m", "value": f"{sigma[n]:.1f}"},
                         {"key": "speed_m_s", "value": f"{speed:.1f}"}],
            "spheres": [{"pose": {"position": p, "orientation": IDENTITY},
                         "size": {"x": size, "y": size, "z": size},
                         "color": {"r": r, "g": g, "b": b, "a": 0.35}}],
            "texts": [{"pose": {"position": p, "orientation": IDENTITY},
                       "billboard": True, "font_size": 14.0, "scale_invariant": True,
                       "color": {"r": r, "g": g, "b": b, "a": 1.0}, "text": tid}],
        }
        if speed > 0.0:
            length = speed * arrow_s
            ent["arrows"] = [{"pose": {"position": p, "orientation": _heading(v)},
                              "shaft_length": round(length * 0.8, 2),
                              "shaft_diameter": round(max(marker / 5.0, length * 0.02), 2),
                              "head_length": round(length * 0.2, 2),
                              "head_diameter": round(max(marker / 2.0, length * 0.06), 2),
                              "color": {"r": r, "g": g, "b": b, "a": 0.9}}]
        entities.append(ent)
    msg = {"deletions": [{"timestamp": stamp, "type": DELETE_ALL, "id": ""}],
           "entities": entities}
    return json.dumps(msg, separators=(",", ":")).encode()
