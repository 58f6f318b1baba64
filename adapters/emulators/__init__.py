"""Emulators of robot controllers, speaking their real serial protocols over a pseudo-terminal:
test tools, for running adapters without hardware."""
