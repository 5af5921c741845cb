"""service/run."""
