"""The contract between the chair's host and its drives: ``wheelchair.dbc`` with its typed codec
and wire errors (the wire), the MCAP log layout and schemas (``logschema``, the log), and in
``dbc.runtime`` the shared infrastructure that is not contract but that both sides import."""
