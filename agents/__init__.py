"""The agent role: one robot's estimator and control law (node + process entry point)."""
