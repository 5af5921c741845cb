"""graft: actors."""
