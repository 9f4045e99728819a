"""The logs: the bus recorder (MCAP), the forked writer tap, reading and merging MCAP files,
MCAP as a python-can log format, and a run's summary computed from its log alone."""
