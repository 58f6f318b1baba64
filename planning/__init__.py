"""armd's planning layer: Ruckig trajectories, limit checks, actuator commands per sample."""
