"""A run: scenarios, the run plan, the three parts (bench, controller, recorder), the one
builder of their objects, the three parts run in this process or as OS processes, the one
runner of cross-process runs (``processes``), the run's summary, one experiment as a
function, branches of one run, and live fault injection."""
