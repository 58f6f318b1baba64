"""The array types every layer shares (one definition: armd.robots is the bottom layer)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]  # positions, velocities, points, ... [SI units]
