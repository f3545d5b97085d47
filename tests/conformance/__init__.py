"""Conformance of each instrument family to its maker's documents (docs/instruments.md).

One module per family (`<role>_<family>.py`, e.g. `chamber_watlow_f4.py`) holds that family's
table, `TABLE`, and the tests that check its rows against the driver and the twin.
`table.py` holds the row type, the registry of tables and the Markdown the docs carry;
`test_tables.py` keeps the docs and the tests in step with the tables.
"""
