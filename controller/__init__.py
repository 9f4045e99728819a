"""The program that runs on the chair: link, arming, estimation, planner, tracking, safety, loop."""

from pathlib import Path

from dbc.runtime.compiled import use_sources_if_needed

#: Why the compiled kernels are not used (None: they are, where installed); dbc.runtime.compiled
SOURCES_BECAUSE = use_sources_if_needed(__name__, Path(__file__).resolve().parent)
