"""What every fault wrapper around a node shares: the runners keep treating a wrapper as its node."""

from __future__ import annotations


class NodeWrapper:
    """A node seen through a fault (``self.node``): attributes not defined by the wrapper are the
    node's, its subscriptions are the node's, and ``inner`` is the node (the runtime's
    ``unwrap()`` walks ``.inner``)."""

    node: object

    @property
    def inner(self):
        """The wrapped node."""
        return self.node

    def __getattr__(self, name: str):
        if name == "node":  # not set yet (during __init__): no recursion through __getattr__
            raise AttributeError(name)
        return getattr(self.node, name)

    def subscriptions(self) -> list[str]:
        return self.node.subscriptions()
