"""armd: IK and motion for small robot arms, served over Eclipse Zenoh.

The layers of the data flow, each a subpackage (the folders at the top of the repository):
``armd.robots`` (arm models from URDF and robot.toml) -> ``armd.solvers`` (IK) ->
``armd.planning`` (jerk-limited trajectories) -> ``armd.service`` (the Zenoh service) ->
``armd.clients`` (the client library); beside the client, ``armd.adapters`` (the hardware
adapter daemons and the boards' emulators); above them ``armd.tools`` (demo, viewer, plots,
workspace maps) and ``armd.cli`` (the ``armd`` command). In-process::

    from armd import robots, solvers, planning
    from armd.clients import ArmClient
"""
