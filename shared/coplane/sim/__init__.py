"""coplane.sim."""
