"""The Rerun logger: the swarm on the simulation-time timeline.

Layers, like the nodes (STYLE.md, sans I/O):

- :mod:`.recorder` -- :class:`SwarmRecorder`, the core: takes the world's
  ``WorldState`` messages (link health, as the robots measured it at their
  inboxes, rides in them), and writes rate-limited, column-batched frames to
  a ``rerun.RecordingStream``. No transport, no threads.
- :mod:`.style` -- entity paths, colours, the default blueprint.
- :mod:`.sinks` -- opens a recording on the outputs named by ``--rerun``.
- :mod:`.replay` -- a recording from a finished run folder (``fxswarm sim``
  output), through the same recorder.
- :mod:`.inbox` -- the bounded ring buffer between the bus callback and the
  recorder: the bus never waits on the logger, a slow logger drops frames.
- :mod:`.process` -- ``fxswarm logger``: the recorder on the Zenoh bus.
"""
