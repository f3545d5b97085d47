"""The `station` command line: main.py (the entry point) and one module per group of
commands."""
