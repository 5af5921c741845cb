"""graft: actors/minecraft."""
