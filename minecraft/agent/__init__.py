"""The Minecraft agent: the obtain-diamond behaviour tree and its leaves, A*, the travel controller,
the travel task and its gymnasium env, the observation encoding and tree rendering."""
