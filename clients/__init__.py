"""armd's Python client library: :class:`ArmClient` and its typed replies. It needs Zenoh,
orjson and NumPy only (no Pinocchio, no Numba: those are the service's)."""

from armd.errors import NoReply, ServiceError

from .client import ArmClient, FKReply, IKReply, MoveReply, TrajectoryReply
from .track import Track, TrackEvent

__all__ = [
    "ArmClient",
    "FKReply",
    "IKReply",
    "MoveReply",
    "NoReply",
    "ServiceError",
    "Track",
    "TrackEvent",
    "TrajectoryReply",
]
