"""An aircraft's reach: how far from a prediction it can be after dt seconds.

One rule for every test that asks whether a detection or a track lies where the target
could have gone: from its last position alone (velocity not trusted) it flies at most
`speed` m/s; from its extrapolation (position and velocity) it strays at most
0.5 `accel` dt^2, and its velocity changes by at most `accel` dt; either way plus
`sigmas` standard deviations of the positions compared (a speed gate, Blackman & Popoli,
"Design and Analysis of Modern Tracking Systems", 1999, sec. 4.5). The speed gate, the
second look, its far test and the stitcher all ask this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import defaults


@dataclass(frozen=True)
class Reach:
    """The kinematic limits of the targets: `speed` m/s, `accel` m/s^2, and the margin of
    `sigmas` standard deviations given to the uncertainty of the positions compared."""

    speed: float = defaults.MAX_SPEED
    accel: float = defaults.MAX_ACCEL
    sigmas: float = defaults.REACH_SIGMAS

    def flown(self, dt: np.ndarray | float, var: np.ndarray | float) -> np.ndarray | float:
        """The farthest a target is from its last position dt later (positions' summed
        variance `var`): `speed` dt plus `sigmas` sigma."""
        return self.speed * dt + self.sigmas * np.sqrt(var)

    def strayed(self, dt: np.ndarray | float, var: np.ndarray | float) -> np.ndarray | float:
        """The farthest a target is from its own extrapolation (by its velocity and, if
        kept, its acceleration) dt later: 0.5 `accel` dt^2 plus `sigmas` sigma."""
        return 0.5 * self.accel * dt * dt + self.sigmas * np.sqrt(var)

    def turned(self, dt: np.ndarray | float, var: np.ndarray | float) -> np.ndarray | float:
        """The largest change of a target's velocity over dt: `accel` dt plus `sigmas`
        sigma of the velocities compared."""
        return self.accel * dt + self.sigmas * np.sqrt(var)


def extrapolated(x: np.ndarray, d: int, order: int, dt: float | np.ndarray) -> np.ndarray:
    """A state's position `dt` later by its own motion (velocity, acceleration); states
    as columns of x, one dt each, too."""
    pred = x[:d] + x[d:2 * d] * dt
    return pred + 0.5 * x[2 * d:3 * d] * dt * dt if order == 3 else pred
