"""What every role process stands on: the Zenoh bus, the process shell, the router, health, outputs."""
