"""A run: scenarios, the run plan, the three parts (bench, controller, recorder), the one
builder of their objects, the launcher that starts them as threads or processes, the one
runner of cross-process runs (``processes``), one experiment as a function, and live fault
injection."""
