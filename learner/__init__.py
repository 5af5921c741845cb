"""graft: learner."""
