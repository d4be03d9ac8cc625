"""coplane.vehicle_agent: the vehicle agent process (services/vehicle_agent); see docs/bus.md."""
