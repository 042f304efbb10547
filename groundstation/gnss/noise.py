"""Measurement noise of a u-blox L1 receiver as a function of signal strength.

One model for every stage that weighs measurements (the conditioning's slip tests and the
integrity stage's least squares): the thermal noise of a tracking loop grows as
10^((45 - C/N0) / 20) below 45 dBHz and does not shrink above it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

PHASE_SIGMA_45_CYC = 0.0105
"""Carrier-phase noise of one receiver at 45 dBHz (2 mm), the thermal noise of a phase-locked
loop."""
CODE_SIGMA_45_M = 0.3
"""Pseudorange noise of one receiver at 45 dBHz (a u-blox L1 code loop), same growth."""
UNKNOWN_CNO_DBHZ = 30.0
"""Signal strength assumed where a receiver reports none (weak, so never over-trusted)."""


def cno_scale(cno_dbhz: FloatArray) -> FloatArray:
    """Noise growth factor of a measurement at ``cno_dbhz`` relative to 45 dBHz (at least 1)."""
    cno = np.where(np.nan_to_num(cno_dbhz) > 0, cno_dbhz, UNKNOWN_CNO_DBHZ)
    return np.asarray(10.0 ** ((45.0 - np.minimum(cno, 45.0)) / 20.0), dtype=np.float64)
