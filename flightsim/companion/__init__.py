"""A companion computer's side: ``secuav-feed`` makes sensor readings and sends them to the autopilot."""
