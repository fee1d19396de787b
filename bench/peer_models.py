"""Motion models shared by the benchmarks' peers: Stone Soup's constant-velocity model
with our discrete piecewise-constant white acceleration noise (Bar-Shalom, Li &
Kirubarajan 2001, sec. 6.3.2), so that both sides filter with the same model. None when
Stone Soup (the bench extra) is not installed."""

from __future__ import annotations

import numpy as np

try:
    from stonesoup.models.transition.linear import ConstantVelocity
    from stonesoup.types.array import CovarianceMatrix

    class PiecewiseConstantVelocity(ConstantVelocity):
        """Stone Soup's 1-D CV model with the discrete piecewise-constant white
        acceleration noise of `service.estimation.models` (noise_diff_coeff = q^2)."""

        def covar(self, time_interval, **kwargs):
            dt = abs(time_interval.total_seconds())
            return CovarianceMatrix(self.noise_diff_coeff * np.array(
                [[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]))
except ImportError:  # optional peer (pip install '.[bench]')
    PiecewiseConstantVelocity = None  # type: ignore[assignment,misc]
