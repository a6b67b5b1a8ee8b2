"""Scenarios of the example plugin: every *.yaml here is a SecUAV scenario, by file name."""
