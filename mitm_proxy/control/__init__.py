"""The proxy's control plane: the runtime switches, their registry, the MQTT session that serves them."""
