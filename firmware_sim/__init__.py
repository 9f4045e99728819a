"""The bench: chair physics, DC motors, ODrive-compatible drive nodes, localization node, faults."""
