"""armd's planning layer: jerk-limited trajectories (Ruckig), Cartesian lines, the safety gate.

>>> from armd import robots, planning
>>> arm = robots.load("gupta3")
>>> traj = planning.plan(arm, arm.neutral, [0.5, 1.0, -1.2])
>>> traj.rate_hz, bool(abs(traj.duration * traj.rate_hz - round(traj.duration * traj.rate_hz)) < 1e-9)
(50.0, True)
"""

from .checks import actuator_commands, check_samples
from .goal import CartesianGoal
from .plan import DEFAULT_RATE_HZ, plan, plan_stop
from .state import JointState, joint_state
from .trajectory import Trajectory

__all__ = [
    "DEFAULT_RATE_HZ",
    "CartesianGoal",
    "JointState",
    "Trajectory",
    "actuator_commands",
    "check_samples",
    "joint_state",
    "plan",
    "plan_stop",
]
