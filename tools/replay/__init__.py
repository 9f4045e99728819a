"""Replay of a recorded log: re-transmission on a bus, offline verification of a controller
against the recorded frames, and what-if runs."""
