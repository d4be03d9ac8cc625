"""coplane.evaluate."""
