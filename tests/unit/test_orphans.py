"""fxswarm.launch.orphans: the launcher's children die with it, even a SIGKILLed one (Linux);
the whole path is tested with a real launcher in tests/integration/test_router_restart.py."""

from __future__ import annotations


def test_a_child_dies_with_its_parent_only_when_spawned_from_the_main_thread():
    """PR_SET_PDEATHSIG fires when the thread that forked the child ends: from another thread
    the launcher's helper declines rather than have children die early."""
    import sys
    import threading

    from fxswarm.launch.orphans import die_with_parent

    assert (die_with_parent() is not None) == sys.platform.startswith("linux")
    found = []
    worker = threading.Thread(target=lambda: found.append(die_with_parent()))
    worker.start()
    worker.join()
    assert found == [None]
