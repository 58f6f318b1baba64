"""armd's solvers: closed-form geometric IK seeds refined by a QP with hard joint limits.

>>> from armd import robots, solvers
>>> arm = robots.load("insomniac")
>>> r = solvers.solve_ik(arm, [0.25, 0.05, 0.12], approach="perpendicular")
>>> r.status, r.position_error < 1e-9
('ok', True)
"""

from .batch import BatchIKResult, reachable, solve_ik_batch
from .detect import DetectedObject, detect
from .ik import DEFAULT_TOLERANCE, solve_ik
from .result import APPROXIMATE, COLLISION, OK, UNREACHABLE, Branch, IKResult
from .target import PARALLEL, PERPENDICULAR, SensorReading, approach_pitch, target_point

__all__ = [
    "APPROXIMATE",
    "COLLISION",
    "DEFAULT_TOLERANCE",
    "OK",
    "PARALLEL",
    "PERPENDICULAR",
    "UNREACHABLE",
    "BatchIKResult",
    "Branch",
    "DetectedObject",
    "IKResult",
    "SensorReading",
    "approach_pitch",
    "detect",
    "reachable",
    "solve_ik",
    "solve_ik_batch",
    "target_point",
]
