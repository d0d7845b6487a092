"""The world role: true robot positions, obstacles and the clock (node + process entry point)."""
