"""The hardware adapter daemons: the common Zenoh side (:mod:`.base`: trajectories checked by
their motion, stops from the adapter's own state, events and states), the trajectory message
(:mod:`.trajectory_message`), the SSC-32 (:mod:`.ssc32`), GRBL (:mod:`.grbl`) and simulated
(:mod:`.sim`) arms, and emulators of the boards on pseudo-terminals (:mod:`.emulators`: test
tools)."""
