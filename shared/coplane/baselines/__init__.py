"""coplane.baselines."""
