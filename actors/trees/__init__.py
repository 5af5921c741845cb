"""graft: actors/trees."""
