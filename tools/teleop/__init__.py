"""Teleoperation: an arm driven by hand through its tracking stream (``armd teleop``).

Each source is a file: a leader arm on its bus (:mod:`.leader`, mapped to its follower by
:mod:`.leader_map`), the keyboard (:mod:`.keyboard`) and a gamepad (:mod:`.gamepad`), the last
two jogging the tool (:mod:`.jog`, in the arm's own directions: :mod:`.frames`); the loop they
share (:mod:`.stream`) turns a source's readings into puts on ``<prefix>/<robot>/track`` at a
steady rate, and stops putting (the arm brakes at its deadman) when the source stops answering.
"""
