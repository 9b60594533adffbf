"""The base package: the one settings module (`cmrt.settings`)."""
