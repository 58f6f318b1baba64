"""How a leader arm's pose becomes its follower's put.

- The same kind of arm (:class:`JointMap`): joint to joint. The leader's counts are its joint
  angles through its own calibration (read before); the follower is put the same angles, and
  its adapter turns them into its own counts through its own calibration. A joint beyond the
  follower's limits is taken to the limit by the service, which says so (``unreachable``,
  reason ``limits``).
- Another kind (:class:`PoseMap`): by the tool. The leader's tool point (its model's FK) is
  put as the follower's target, in the follower's base frame turned so that the two arms face
  the same way (:func:`.frames.heading`): the follower's tool goes where the leader's is, as
  seen from its base. Where the follower chooses its tool's pitch, the leader's pitch goes
  with it (``approach``). What the follower cannot reach, it comes closest to (``unreachable``).
- The gripper, either way: the leader's opening (its gripper servo between its ``closed``
  and ``open`` counts), if both arms have one.
"""

from __future__ import annotations

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.types import FloatArray

from .frames import heading, turned
from .stream import Put


class JointMap:
    """``leader``'s joints as ``follower``'s: arms of one kind (the same joints)."""

    def __init__(self, leader: Robot, follower: Robot) -> None:
        if tuple(leader.joint_names) != tuple(follower.joint_names):
            raise BadRequest(
                f"{leader.name} leads {follower.name} joint to joint only with the same joints: "
                f"{', '.join(leader.joint_names)} against {', '.join(follower.joint_names)}",
                field="leader_robot",
            )
        self.gripper = follower.gripper is not None

    def put(self, q: FloatArray, opening: float | None) -> Put:
        """The put of the leader at joints ``q`` [rad] with its gripper at ``opening`` (or None)."""
        return Put(joints=tuple(float(x) for x in q), gripper=opening if self.gripper else None)


class PoseMap:
    """``leader``'s tool point (and pitch) as ``follower``'s target: arms of two kinds."""

    def __init__(self, leader: Robot, follower: Robot) -> None:
        self.leader = leader
        self.turn = heading(follower) - heading(leader)  # [rad] the leader's frame into the follower's
        self.pitch = follower.chooses_pitch
        self.gripper = follower.gripper is not None

    def put(self, q: FloatArray, opening: float | None) -> Put:
        """The put of the leader at joints ``q`` [rad] with its gripper at ``opening`` (or None)."""
        pose = self.leader.pose(q)
        p = turned(pose.position, self.turn)
        return Put(
            target=(float(p[0]), float(p[1]), float(p[2])),
            approach=float(pose.pitch) if self.pitch else None,
            gripper=opening if self.gripper else None,
        )


LeaderMap = JointMap | PoseMap
