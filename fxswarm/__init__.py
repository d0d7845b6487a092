"""fxswarm: a robot swarm in formation under a fixed-time behavioural control law.

The control law lives once, in :mod:`fxswarm.core.control`; the role nodes
(:mod:`fxswarm.agents`, :mod:`fxswarm.world`, :mod:`fxswarm.leader`) are
sans-I/O state machines that the in-process simulator and the Zenoh
processes drive alike.
"""

__version__ = "0.1.0"
