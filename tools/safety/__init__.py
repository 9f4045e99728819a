"""The safety fault-injection suite: its cases, the runner, the criteria and the report table."""
