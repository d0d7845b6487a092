"""The leader role: the virtual leader's trajectory (node + process entry point)."""
