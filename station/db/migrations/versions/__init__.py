"""One module per schema revision, in order: 0001 (schema 1 as it was), 0002, 0003."""
