"""attack_profiles package."""
