"""Everything around the chair's two programs: the ``wheelchair-hil`` command line (``cli``), the
bus (``bus``), runs (``run``), logs (``logs``), metrics, evaluation, replay, the safety suite and
the benchmarks (``perf``).  ``tools`` may import ``controller``, ``firmware_sim`` and ``dbc``;
nothing imports ``tools``."""
