"""Tools for seeing what armd does: the scripted demo (:mod:`.demo`), the 3-D viewer
(:mod:`.view`), workspace maps (:mod:`.workspace`) and trajectory plots (:mod:`.plot`). They
need the ``view`` extra (matplotlib, meshcat)."""
