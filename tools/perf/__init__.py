"""Benchmarks that print figures: step times, real-time factor, lateness, latency, bus load, memory."""
