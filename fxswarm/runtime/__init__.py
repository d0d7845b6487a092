"""Runners: the in-process simulator, the role processes, the launcher."""
