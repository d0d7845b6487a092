"""Secure mode: the swarm's own CA and per-process keys (:mod:`.keys`), and each process's
rights on the bus (:mod:`.policy`), Zenoh's access control by certificate common name."""
