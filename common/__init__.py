"""Shared infrastructure below every layer (bounded input readers, field types, the station
clock, addresses): imports nothing of the product."""
