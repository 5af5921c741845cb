"""Minecraft in three sub-packages: ``sim`` (the simulated world server), ``malmo`` (the MalmoEnv
wire protocol, client and missions) and ``agent`` (the obtain-diamond tree, A*, the travel task).

The rule: ``sim`` is only the simulator; ``malmo`` and ``agent`` never import it and are what runs
against a real Minecraft. ``blocks`` holds the Minecraft facts all three share."""
