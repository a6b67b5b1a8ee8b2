"""mitm_proxy package."""
