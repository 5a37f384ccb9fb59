"""Child processes that never outlive the process that started them.

Every tool that starts the node graph (the bringup launcher for its nodes, msfsu-eval-bag and the
closed-loop benchmark for the launcher) passes `preexec_fn=die_with_parent()`, and the benchmark's
worker processes call `tie_to_parent` first thing: should the parent end
in any way, SIGKILL and a SIGTERM without a handler included, the child gets SIGTERM, on which rclpy
nodes and the launcher shut down cleanly (Fast DDS removes its /dev/shm files). Linux only (prctl);
elsewhere the children are merely not tied to their parent.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable

PR_SET_PDEATHSIG = 1


def tie_to_parent(parent: int, sig: signal.Signals = signal.SIGTERM) -> None:
    """In a child: ask the kernel for `sig` when the parent dies (at once if `parent` is gone already).

    For children that are not exec'd with a preexec_fn, e.g. multiprocessing workers (call it first thing).
    """
    if not sys.platform.startswith("linux"):
        return
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig))
    if os.getppid() != parent:  # the parent died before the request was in place
        os.kill(os.getpid(), sig)


def die_with_parent(sig: signal.Signals = signal.SIGTERM) -> Callable[[], None] | None:
    """A `preexec_fn` (run in the child before exec) asking the kernel for `sig` when this process dies."""
    if not sys.platform.startswith("linux"):
        return None
    parent = os.getpid()

    def arm() -> None:
        tie_to_parent(parent, sig)

    return arm


def _raise_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def interrupt_on_signals() -> None:
    """From now on SIGTERM and SIGINT end this process as Ctrl-C does in a terminal: a KeyboardInterrupt, so
    `finally` blocks and context managers run (children stopped, rclpy shut down, records flushed) instead of
    the default outright exit of SIGTERM. SIGINT too, because a shell starts background jobs with SIGINT
    ignored and Python then never raises KeyboardInterrupt: `kill -INT` would do nothing."""
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, _raise_interrupt)
