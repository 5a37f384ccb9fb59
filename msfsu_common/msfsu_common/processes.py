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
from collections.abc import Callable, Iterator
from contextlib import contextmanager

PR_SET_PDEATHSIG = 1
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)  # how a user, a shell or a supervisor asks a process to stop


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


_deferring = 0  # depth of nested interrupts_deferred() blocks
_pending = False  # a signal arrived inside one


def _raise_interrupt(signum: int, frame: object) -> None:
    global _pending
    if _deferring:
        _pending = True
        return
    raise KeyboardInterrupt


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold a SIGTERM / SIGINT handled by `interrupt_on_signals` until the block ends, then raise it.

    For code that calls back into Python from C++ (Panda3D's task loop renders a frame in a Python task): a
    KeyboardInterrupt raised in the middle of it is printed as a traceback by the task manager before it
    propagates, and can leave the engine half-stepped. Wrapped in this, the block finishes (one simulator step,
    ~0.1 s) and the interrupt comes at its end. Nested blocks raise at the outermost end; a block that ends with an
    exception of its own lets that one propagate (a KeyboardInterrupt counts as the held one; any other leaves
    the interrupt pending for the next block's end).
    """
    global _deferring, _pending
    _deferring += 1
    try:
        yield
    except KeyboardInterrupt:  # the block's own (Panda3D defers Ctrl-C to the end of its step too): the same stop
        _pending = False
        raise
    finally:
        _deferring -= 1
    if not _deferring and _pending:
        _pending = False
        raise KeyboardInterrupt


def interrupt_on_signals() -> None:
    """From now on SIGTERM and SIGINT end this process as Ctrl-C does in a terminal: a KeyboardInterrupt, so
    `finally` blocks and context managers run (children stopped, rclpy shut down, records flushed) instead of
    the default outright exit of SIGTERM. SIGINT too, because a shell starts background jobs with SIGINT
    ignored and Python then never raises KeyboardInterrupt: `kill -INT` would do nothing."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, _raise_interrupt)


@contextmanager
def stop_signals_handled(handler: Callable[[int, object], None]) -> Iterator[None]:
    """SIGTERM and SIGINT go to `handler` while the block runs; at its end the handlers from before are back. A handler
    Python did not install (one set from C, e.g. rclpy's) cannot be put back from Python: `handler` stays then."""
    before = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, previous in before.items():
            if previous is not None:
                signal.signal(sig, previous)


@contextmanager
def signals_interrupt() -> Iterator[None]:
    """`interrupt_on_signals` for the block only (a `main` called as a function, tests); where the handler from before
    cannot be put back (`stop_signals_handled`), ours stays and raises KeyboardInterrupt as Python's default SIGINT
    handler does."""
    with stop_signals_handled(_raise_interrupt):
        yield
