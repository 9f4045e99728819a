"""The safety fault-injection suite: its cases, the runner, the criteria and the report table;
the attacks across processes; the verdict every result carries."""
