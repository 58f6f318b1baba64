"""A URDF frame by its name, as robot.toml and requests name it.

A URDF may give a link and a joint the same name (the Braccio's ``gripper_fix``): Pinocchio
then has two frames of that name, and its ``getFrameId(name)`` refuses to choose. A frame named
in robot.toml (``tool_frame``, ``base_frame``, a sensor's ``frame``) or in a request is a place
on the arm, which the URDF calls a link: of several frames of one name, the link's is meant
(else, in this order, an operational frame's, a fixed joint's, a joint's).
"""

from __future__ import annotations

import pinocchio as pin

_PREFERRED = (pin.FrameType.BODY, pin.FrameType.OP_FRAME, pin.FrameType.FIXED_JOINT, pin.FrameType.JOINT)


def frame_id(model: pin.Model, name: str) -> int:
    """The index of the frame ``name`` of ``model`` (see the module's doc); ``model.nframes``
    if no frame has that name."""
    found = [i for i, f in enumerate(model.frames) if f.name == name]
    if len(found) <= 1:
        return found[0] if found else int(model.nframes)
    rank = {t: k for k, t in enumerate(_PREFERRED)}
    return min(found, key=lambda i: rank.get(model.frames[i].type, len(rank)))
