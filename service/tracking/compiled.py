"""The modules whose kernels the tracker runs compiled once they serve: what
`estimation.jit.prepare` compiles and loads for the service, its benchmarks and tests."""

from __future__ import annotations

from ..estimation import gate_jit, imm_jit
from . import frame

KERNELS = (imm_jit, gate_jit, frame)
