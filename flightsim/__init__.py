"""flightsim package."""
