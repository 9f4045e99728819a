"""The ``wheelchair-hil`` command line: run, sim, control, sandbox, record, evaluate, replay, bench."""
