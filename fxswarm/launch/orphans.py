"""Children that die with their launcher, even a SIGKILLed one (Linux).

The Python roles watch their parent (``FXSWARM_PARENT_PID``) and leave when it is gone; a child
that is not ours, ``zenohd``, never would. On Linux the kernel can tell a child when its parent
dies: ``prctl(PR_SET_PDEATHSIG, SIGTERM)`` in the child between fork and exec, which
:func:`die_with_parent` returns for ``subprocess.Popen(preexec_fn=...)``.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
from typing import Callable

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(sig: int = signal.SIGTERM) -> Callable[[], None] | None:
    """A ``preexec_fn`` that has the kernel send ``sig`` to the child when this process dies;
    None where it cannot: not Linux, or not the main thread (the signal comes when the thread
    that forked the child ends, which for another thread may be long before the process).

    Everything is looked up here, before the fork: the child only calls into libc."""
    if not sys.platform.startswith("linux") or threading.current_thread() is not threading.main_thread():
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    prctl.restype = ctypes.c_int
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    parent, option, value, zero = os.getpid(), PR_SET_PDEATHSIG, int(sig), 0
    kill, getppid, getpid = os.kill, os.getppid, os.getpid

    def preexec() -> None:
        prctl(option, value, zero, zero, zero)
        if getppid() != parent:  # the parent died before the prctl: nobody will tell us
            kill(getpid(), value)

    return preexec
