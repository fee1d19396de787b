"""Geocentric (ECEF, WGS-84) <-> the deployment's East-North-Up frame, and an entity's
DIS orientation from its velocity. The geodesy is pymap3d's; the frame caches the
origin's ECEF point and its ENU axes (from `pymap3d.enu2uvw`) so that a batch of
thousands of entities converts in one matrix product."""

from __future__ import annotations

import warnings

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from zenoh_track.wire import Origin, missing_extra

try:
    import pymap3d
except ImportError as exc:  # the dis extra's: one line naming it, for every program here
    missing_extra(exc, "dis", "track-dis")

F64 = npt.NDArray[np.float64]
STILL = 0.1  # m/s: slower than this an entity has no heading of its own (faces North, level)


class EnuFrame:
    """East-North-Up metres about `origin` (WGS-84 ellipsoid heights)."""

    def __init__(self, origin: Origin) -> None:
        self.origin = origin
        self.ecef0 = np.array(pymap3d.geodetic2ecef(origin.lat, origin.lon, origin.alt))
        # rows: the East, North and Up unit vectors in ECEF
        self.axes = np.array([pymap3d.enu2uvw(*unit, origin.lat, origin.lon)
                              for unit in np.eye(3)])

    def to_enu(self, ecef: F64) -> F64:
        """(N, 3) ECEF metres -> (N, 3) ENU metres."""
        out: F64 = (np.asarray(ecef, float) - self.ecef0) @ self.axes.T
        return out

    def to_ecef(self, enu: F64) -> F64:
        """(N, 3) ENU metres -> (N, 3) ECEF metres."""
        out: F64 = np.asarray(enu, float) @ self.axes + self.ecef0
        return out

    def vectors_to_enu(self, v: F64) -> F64:
        """(N, 3) ECEF vectors (velocity, acceleration) -> ENU."""
        out: F64 = np.asarray(v, float) @ self.axes.T
        return out

    def vectors_to_ecef(self, v: F64) -> F64:
        out: F64 = np.asarray(v, float) @ self.axes
        return out


def local_axes(ecef: F64) -> tuple[F64, F64]:
    """Each point's local North and Up unit vectors in ECEF, (N, 3) each."""
    lat, lon, _ = pymap3d.ecef2geodetic(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    zero, one = np.zeros_like(lat), np.ones_like(lat)
    north = np.stack(pymap3d.enu2uvw(zero, one, zero, lat, lon), axis=1)
    up = np.stack(pymap3d.enu2uvw(zero, zero, one, lat, lon), axis=1)
    return north, up


def body_matrix(vel: F64, north: F64, up: F64) -> F64:
    """Body-to-ECEF matrices (N, 3, 3) of entities flying along their velocity, wings
    level, given each one's local North and Up: x forward (the velocity; North for an
    entity slower than STILL), y to the right in the local horizontal plane, z = x cross
    y (down when level)."""
    speed = np.linalg.norm(vel, axis=1, keepdims=True)
    forward = np.where(speed > STILL, vel / np.maximum(speed, STILL), north)
    right = np.cross(forward, up)
    norm = np.linalg.norm(right, axis=1, keepdims=True)
    # straight up or down: the right wing points East of North
    right = np.where(norm > 1e-9, right / np.maximum(norm, 1e-9), np.cross(north, up))
    out: F64 = np.stack([forward, right, np.cross(forward, right)], axis=2)
    return out


def body_axes(ecef: F64, vel: F64) -> Rotation:
    """`body_matrix` at each entity's own position, as rotations."""
    return Rotation.from_matrix(body_matrix(vel, *local_axes(ecef)))


def angle_between(a: F64, b: F64) -> F64:
    """The angle (N,) rad of the rotation from each matrix of `a` to that of `b`."""
    cos = (np.einsum("nij,nij->n", a, b) - 1.0) / 2.0
    out: F64 = np.arccos(np.clip(cos, -1.0, 1.0))
    return out


def euler_of(rot: Rotation) -> F64:
    """DIS Euler angles (psi, theta, phi), (N, 3) rad: the body axes reached from ECEF by
    rotations about z, then the new y, then the new x (IEEE 1278.1, 6.2.33). Straight
    up or down (theta +-90 deg) psi and phi turn about one axis: phi is then 0."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # scipy's gimbal-lock note
        out: F64 = rot.as_euler("ZYX")
    return out


def rotation_of(euler: F64) -> Rotation:
    """The body-to-ECEF rotations of DIS Euler angles (N, 3)."""
    return Rotation.from_euler("ZYX", np.asarray(euler, float))


def turn_rate(rot: Rotation, vel: F64, acc: F64) -> F64:
    """Body angular velocity (N, 3) rad/s of an entity whose velocity turns with the
    acceleration: omega = v x a / |v|^2 in ECEF, expressed in body axes."""
    speed2 = np.sum(vel * vel, axis=1, keepdims=True)
    omega = np.where(speed2 > STILL**2, np.cross(vel, acc) / np.maximum(speed2, STILL**2), 0.0)
    out: F64 = rot.inv().apply(omega)
    return out
