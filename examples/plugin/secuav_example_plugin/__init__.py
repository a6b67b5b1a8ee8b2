"""An example SecUAV plugin: nothing here is imported until SecUAV asks for one of its names."""
