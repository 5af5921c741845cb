"""The replay client side, what actors and the learner import: ``ReplayClient``, the column
codec and sharding over several servers. Importing it does not load ``service.replay.server``."""
