"""Talking to a MalmoEnv server, the simulator or a real Minecraft: the wire protocol, the client,
mission XML building (``mission_xml``) and parsing (``mission``), and the sample mission."""
