"""The bus's sender check, parsed once per key, still refuses a stranger speaking for a robot."""

from __future__ import annotations

import numpy as np
import pytest

from fxswarm.core.messages import Clock, Command, Estimate, LeaderState, Sense, WireError
from fxswarm.runtime.zenoh_bus import check_sender

V = np.zeros(3)


def cmd(robot: int, sender: int | None = None) -> Command:
    return Command("agent", robot if sender is None else sender, 1, 1, 0.01, robot, V, V, False, 0, (), ())


@pytest.mark.parametrize("topic,msg", [
    ("agent/3/cmd", cmd(3)),
    ("agent/3/estimate", Estimate("agent", 3, 1, 1, 0.01, 3, V)),
    ("world/sense/3", Sense("world", 0, 1, 1, 0.01, 3, V, None, None)),
    ("leader/state", LeaderState("leader", 0, 1, 1, 0.01, V)),
    ("clock", Clock("world", 0, 1, 1, 0.01)),
    ("logger/whatever", Clock("test", 0, 1, 1, 0.01)),  # not the bus's to check
])
def test_what_belongs_passes(topic, msg):
    check_sender(topic, msg)


@pytest.mark.parametrize("topic,msg", [
    ("agent/3/cmd", cmd(4)),  # robot 4's command on robot 3's key
    ("agent/3/cmd", cmd(3, sender=4)),  # robot 4 signing for robot 3
    ("agent/03/cmd", cmd(3)),  # an id not written as the id is
    ("agent/3/estimate", cmd(3)),  # a command where an estimate belongs
    ("agent/3/other", cmd(3)),
    ("world/sense/3", Sense("world", 0, 1, 1, 0.01, 2, V, None, None)),
    ("world/sense/3", Sense("agent", 0, 1, 1, 0.01, 3, V, None, None)),
    ("leader/state", LeaderState("agent", 0, 1, 1, 0.01, V)),
    ("clock", Clock("leader", 0, 1, 1, 0.01)),
])
def test_a_stranger_is_refused(topic, msg):
    with pytest.raises(WireError, match="does not belong"):
        check_sender(topic, msg)
