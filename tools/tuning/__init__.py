"""Tuning: ``wheelchair-hil tune`` (one optimiser, one objective, one budget for every
controller, on scenarios disjoint from the evaluation's) and the tuned gains file."""
