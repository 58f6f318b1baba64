"""The one angle wrap of armd: every angle it reports wrapped (a tool pitch, a pitch error, a
difference of pitches) is in ``[-pi, pi)``, by the same formula for one value (:func:`wrap`,
which the solver's compiled code compiles too) and for an array (:func:`wrap_array`).

>>> import math
>>> wrap(math.pi) == -math.pi and wrap(-math.pi) == -math.pi and wrap(3.0) == 3.0
True
>>> wrap_array(np.array([math.pi, 7.0])).round(6).tolist()
[-3.141593, 0.716815]
"""

from __future__ import annotations

import math

import numpy as np

from .types import FloatArray

TWO_PI = 2.0 * math.pi


def wrap(x: float) -> float:
    """``x`` [rad] plus the multiple of 2 pi that puts it in ``[-pi, pi)`` (exact for an angle
    already there)."""
    return x - TWO_PI * math.floor(x / TWO_PI + 0.5)


def wrap_array(x: FloatArray) -> FloatArray:
    """:func:`wrap`, elementwise."""
    return x - TWO_PI * np.floor(x / TWO_PI + 0.5)
