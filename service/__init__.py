"""armd's service layer: the Zenoh service, its JSON protocol and the command line."""
