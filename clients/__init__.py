"""armd's clients: the Python client library (and, later, the hardware adapter daemons)."""

from .client import ArmClient, FKReply, IKReply, MoveReply, NoReply, ServiceError, TrajectoryReply

__all__ = ["ArmClient", "FKReply", "IKReply", "MoveReply", "NoReply", "ServiceError", "TrajectoryReply"]
