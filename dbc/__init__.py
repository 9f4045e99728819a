"""The wire contract: ``wheelchair.dbc``, its typed codec, the error tree and typed parameters."""
