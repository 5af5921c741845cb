"""graft: actors/behaviour_trees."""
