"""Behaviour policies: how an env actor turns observations into actions and replay columns."""
