"""ECEF <-> ENU of the gateway (clients/dis/geodesy.py) within 1 mm of pymap3d over the
whole globe; the browser's ENU -> geodetic formula (web_static/geo.js, run by Node.js)
within 1 mm of pymap3d; DIS orientations from velocities; the origin's wire checks."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from zenoh_track.clients.dis import geodesy
from zenoh_track.wire import Origin, Rejected, origin_message, parse_origin, parse_origin_message

GEO_JS = Path(__file__).resolve().parent.parent / "clients" / "web" / "web_static" / "geo.js"
MM = 1e-3


def globe(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origins over the whole globe (poles and the antimeridian included), heights from
    -400 m to 10 km, and ENU offsets up to 1,000 km across and 100 km up."""
    rng = np.random.default_rng(seed)
    lat = np.concatenate([[90.0, -90.0, 0.0, 89.999, -45.0], rng.uniform(-90, 90, n - 5)])
    lon = np.concatenate([[0.0, 180.0, -180.0, 179.999, 360.0], rng.uniform(-180, 180, n - 5)])
    alt = rng.uniform(-400.0, 10_000.0, n)
    enu = rng.uniform([-1e6, -1e6, -1e3], [1e6, 1e6, 1e5], (n, 3))
    return np.stack([lat, lon, alt], 1), enu, rng.normal(0, 300, (n, 3))


def test_enu_frame_within_1_mm_of_pymap3d_over_the_globe() -> None:
    origins, enu, vel = globe(400, 0)
    worst = 0.0
    for (lat, lon, alt), d, v in zip(origins, enu, vel, strict=True):
        frame = geodesy.EnuFrame(Origin(lat, lon, alt))
        ecef = frame.to_ecef(d[None])[0]
        want = np.array(pymap3d.enu2ecef(*d, lat, lon, alt))
        back = frame.to_enu(ecef[None])[0]
        want_back = np.array(pymap3d.ecef2enu(*want, lat, lon, alt))
        v_ecef = frame.vectors_to_ecef(v[None])[0]
        want_v = np.array(pymap3d.enu2uvw(*v, lat, lon))
        worst = max(worst, *np.abs(ecef - want), *np.abs(back - want_back), *np.abs(back - d),
                    *np.abs(v_ecef - want_v), *np.abs(frame.vectors_to_enu(v_ecef[None])[0] - v))
    assert worst < MM, worst


def test_enu_frame_converts_a_batch_like_one_at_a_time() -> None:
    frame = geodesy.EnuFrame(Origin(-33.86, 151.21, 40.0))
    _, enu, _ = globe(1000, 1)
    ecef = frame.to_ecef(enu)
    one = np.array([pymap3d.enu2ecef(*d, -33.86, 151.21, 40.0) for d in enu[:50]])
    assert np.abs(ecef[:50] - one).max() < MM
    assert np.abs(frame.to_enu(ecef) - enu).max() < MM


@pytest.mark.skipif(shutil.which("node") is None, reason="Node.js runs the browser's module")
def test_browser_enu_to_geodetic_within_1_mm_of_pymap3d() -> None:
    origins, enu, _ = globe(300, 2)
    origins[:, 0] = np.clip(origins[:, 0], -89.9, 89.9)  # the browser's map stops at the poles
    cases = [[*o, *d] for o, d in zip(origins.tolist(), enu.tolist(), strict=True)]
    script = (f"import {{ enuToGeodetic }} from {json.dumps(GEO_JS.as_uri())};\n"
              f"const cases = {json.dumps(cases)};\n"
              "console.log(JSON.stringify(cases.map(c => enuToGeodetic(c.slice(0, 3), "
              "c[3], c[4], c[5]))));")
    out = subprocess.run(["node", "--input-type=module", "-e", script], capture_output=True,
                         text=True, check=True, timeout=60)
    got = np.array(json.loads(out.stdout))
    for (lat0, lon0, h0), d, (lat, lon, h) in zip(origins, enu, got, strict=True):
        # compare as points: the browser's answer back to ECEF, against pymap3d's
        mine = np.array(pymap3d.geodetic2ecef(lat, lon, h))
        want = np.array(pymap3d.enu2ecef(*d, lat0, lon0, h0))
        assert np.abs(mine - want).max() < MM, (lat0, lon0, d)


def test_orientation_follows_the_velocity_wings_level() -> None:
    frame = geodesy.EnuFrame(Origin(0.0, 0.0, 0.0))
    pos = frame.to_ecef(np.zeros((4, 3)))
    v_enu = np.array([[0, 100.0, 0], [100.0, 0, 0], [0, 100.0, 100.0], [0, 0, 0]])
    rot = geodesy.body_axes(pos, frame.vectors_to_ecef(v_enu))
    euler = geodesy.euler_of(rot)
    # at (0 N, 0 E) ECEF x is Up, y East, z North: North level is theta = -90 deg
    assert np.degrees(euler[0, 1]) == pytest.approx(-90.0)
    # East level: psi 90 deg, theta 0, phi -90 deg (the right wing South, ECEF -z)
    assert np.degrees(euler[1]) == pytest.approx([90.0, 0.0, -90.0], abs=1e-9)
    back = geodesy.rotation_of(euler)
    forward = back.apply(np.array([1.0, 0, 0]))
    want = frame.vectors_to_ecef(v_enu[:3])
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    assert np.abs(forward[:3] - want).max() < 1e-9
    right = back.apply(np.array([0, 1.0, 0]))
    up = frame.vectors_to_ecef(np.array([[0, 0, 1.0]]))[0]
    assert np.abs(right @ up).max() < 1e-9  # wings level
    assert np.abs(forward[3] - frame.vectors_to_ecef(np.array([[0, 1.0, 0]]))[0]).max() < 1e-9


def test_turn_rate_of_a_level_turn() -> None:
    frame = geodesy.EnuFrame(Origin(50.0, 8.0, 0.0))
    pos = frame.to_ecef(np.zeros((1, 3)))
    v = frame.vectors_to_ecef(np.array([[0, 100.0, 0]]))  # North at 100 m/s
    a = frame.vectors_to_ecef(np.array([[10.0, 0, 0]]))  # turning right (East)
    omega = geodesy.turn_rate(geodesy.body_axes(pos, v), v, a)[0]
    assert omega == pytest.approx([0.0, 0.0, 0.1], abs=1e-12)  # yaw right about body z


def test_origin_parse_and_message() -> None:
    o = parse_origin("48.85,2.35,35")
    assert parse_origin_message(origin_message(o)) == o
    assert parse_origin_message(origin_message(None)) is None
    assert o.same(Origin(48.85, 2.35 + 360.0 - 360.0, 35.0005))
    assert not o.same(Origin(48.85, 2.3501, 35.0))
    for bad in ("48.85,2.35", "91,0,0", "0,0,1e9", "x,0,0", "nan,0,0"):
        with pytest.raises(Rejected):
            parse_origin(bad)
