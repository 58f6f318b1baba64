"""armd's clients: the Python client library and the hardware adapter daemons."""
