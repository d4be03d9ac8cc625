"""coplane.fusion_server: the fusion server process (services/fusion_server); see docs/bus.md."""
