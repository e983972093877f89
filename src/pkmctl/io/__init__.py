"""Files: atomic writes and results on disk."""
