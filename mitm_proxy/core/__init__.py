"""The sans-I/O frame path: the pipeline, its counters, and its observers (recorder, readings tap)."""
