"""The soak: real-time runs of bench, controller and recorder for many minutes, routes back to
back, with every fault kind, a rogue node and process kills at seeded random moments, judged
from the logs (docs/safety.md, "Soak").

* :mod:`tools.soak.schedule`: what happens when (deterministic from the seed);
* :mod:`tools.soak.orchestrate`: the processes in a private namespace and the schedule
  carried out on them;
* :mod:`tools.soak.analyse`: the report and its verdict from the run's directory.

``wheelchair-hil soak`` (:mod:`tools.cli.soak`) is the command line around them.
"""
