"""Trajectory-tracking controllers, one module each, chosen by name from a lazy registry."""
