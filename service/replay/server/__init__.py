"""service/replay/server."""
