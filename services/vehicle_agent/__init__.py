"""coplane.agent: thin service process (services/vehicle_agent), wired to the library in its own issue."""
