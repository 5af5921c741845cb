"""A run's replay servers as child processes: started, supervised and restarted, sharded,
and their checkpoint folder kept or set aside across a resume. Knows nothing of actors,
learners or a run's config; the replay service itself is `service.replay`."""
