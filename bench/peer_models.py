"""Motion models shared by the benchmarks' peers: Stone Soup's constant-velocity model,
which is the continuous white-acceleration model of `service.estimation.models`
(Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2: Q = q^2 [[T^3/3, T^2/2], [T^2/2, T]]
with noise_diff_coeff = q^2), so that both sides filter with the same model. None when
Stone Soup (the bench extra) is not installed."""

from __future__ import annotations

try:
    from stonesoup.models.transition.linear import ConstantVelocity as OurConstantVelocity
except ImportError:  # optional peer (pip install '.[bench]')
    OurConstantVelocity = None  # type: ignore[assignment,misc]
