"""coplane.api: thin service process (services/api), wired to the library in its own issue."""
