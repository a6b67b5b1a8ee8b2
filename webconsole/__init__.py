"""``secuav-console``: watch and steer attacks live in a browser, over the MQTT control plane only."""
