"""Runners above the roles: the in-process simulator, the local launcher, the compose writer."""
