"""The service around actors and learner: the replay server and its client (``replay``), the weight
broadcast (``weights``), metrics, and the run orchestration on top of everything (``run``)."""
