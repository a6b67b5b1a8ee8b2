"""The proxy's edge to the world: endpoints (UDP; TCP and serial), their routing rules, the link, the factory."""
