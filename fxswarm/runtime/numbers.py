"""Argument types for the command line's numbers (and swarm names): a value out of range is
refused by argparse, in one line naming the option, with exit status 2, before any process starts.

``fxswarm run --speed 0`` used to start every process and let each one die with a traceback;
``--tick-timeout 0`` ran a whole lock-step run on missed ticks and exited 0.
"""

from __future__ import annotations

import argparse
import math
from typing import Callable

from fxswarm.core.bus import SWARM_NAME_RULE, is_swarm_name


def _type(kind: type, low: float, high: float, what: str, strict: bool = False) -> Callable[[str], int | float]:
    """An argparse type: a finite ``kind`` in ``[low, high]`` (``(low, high]`` if ``strict``)."""

    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if not (low < value if strict else low <= value) or value > high:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    parse.__name__ = what  # what argparse's own messages would call it
    return parse


#: A speed, a period, a timeout that must end.
positive = _type(float, 0, math.inf, "a number > 0", strict=True)
#: A timeout where 0 means forever (or never).
non_negative = _type(float, 0, math.inf, "a number >= 0")
positive_int = _type(int, 0, math.inf, "an integer > 0", strict=True)
non_negative_int = _type(int, 0, math.inf, "an integer >= 0")
port = _type(int, 1, 65535, "a TCP port in 1..65535")


def times(text: str) -> list[float]:
    """Comma-separated times >= 0, s (``--times 10,20.5``)."""
    try:
        values = [non_negative(x) for x in text.split(",") if x.strip()]
    except argparse.ArgumentTypeError:
        values = []
    if not values:
        raise argparse.ArgumentTypeError(f"expected comma-separated seconds >= 0, got {text!r}")
    return values


times.__name__ = "comma-separated seconds"


def swarm_name(text: str) -> str:
    """A swarm name (``--swarm``): one key-expression chunk (:func:`fxswarm.core.bus.is_swarm_name`)."""
    if not is_swarm_name(text):
        raise argparse.ArgumentTypeError(f"expected a swarm name ({SWARM_NAME_RULE}), got {text!r}")
    return text


swarm_name.__name__ = "swarm name"
