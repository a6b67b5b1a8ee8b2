"""MAVSDK controllers the demos fly; each is a plain script (also linked from examples/)."""
