"""graft: learner/td3."""
