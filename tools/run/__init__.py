"""A run: scenarios, the run plan, the three parts (bench, controller, recorder), the launcher
that starts them as threads or processes, one experiment as a function, and live fault injection."""
