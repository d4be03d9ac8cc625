"""coplane.fusion: thin service process (services/fusion_server), wired to the library in its own issue."""
