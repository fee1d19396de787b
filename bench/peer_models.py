"""Motion models shared by the benchmarks' peers: Stone Soup's constant-velocity model,
the continuous white-acceleration model of `zenoh_track.estimation.models` (Bar-Shalom, Li &
Kirubarajan 2001, sec. 6.2.2), with the density ours takes over a step T, q^2 |T|
(noise_diff_coeff = q^2), so that both sides filter with the same model. None when Stone
Soup (the bench extra) is not installed."""

from __future__ import annotations

try:
    from stonesoup.models.transition.linear import ConstantVelocity
    from stonesoup.types.array import CovarianceMatrix

    class OurConstantVelocity(ConstantVelocity):
        """Stone Soup's 1-D CV model with the density noise_diff_coeff x |T|."""

        def covar(self, time_interval, **kwargs):
            dt = abs(time_interval.total_seconds())
            return CovarianceMatrix(dt * super().covar(time_interval, **kwargs))
except ImportError:  # optional peer (pip install '.[bench]')
    OurConstantVelocity = None  # type: ignore[assignment,misc]
