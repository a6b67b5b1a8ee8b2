"""The pipeline's stages: ``attack`` (the active profile) and ``secure`` (a secure estimator)."""
