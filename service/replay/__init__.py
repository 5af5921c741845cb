"""service/replay."""
