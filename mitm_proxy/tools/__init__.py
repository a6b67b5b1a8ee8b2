"""Client commands around the proxy: ``secuav-attack`` (and its ``status --watch`` view), ``secuav-record``."""
