"""``python -m tools.cli``: the command line, as the launcher starts the parts of a run."""

from tools.cli import entry

entry()
