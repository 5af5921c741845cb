"""graft: service."""
