"""Attack profiles of the example plugin: every *.yaml here is a SecUAV library profile."""
