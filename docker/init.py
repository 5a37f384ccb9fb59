#!/usr/bin/env python3
"""The container's first process: runs the command as its child, passes stop signals on to the command's whole
process group and waits until every process below it has ended, as tini does (`docker run --init`).

    python3 docker/init.py COMMAND [ARG ...]     # docker/entrypoint.sh execs it

Why: the kernel gives PID 1 no default signal action, so a first process without a SIGTERM handler ignores
`docker stop`'s SIGTERM and is killed at the end of the grace period. Jazzy's `ros2 run` sets none (and swallows
SIGINT), and it passes no signal to the node it starts: as the container's command, neither it nor its node would
stop. Here:

- this process is the child subreaper (PR_SET_CHILD_SUBREAPER): what is orphaned below it (a node whose `ros2
  run` has ended) becomes its child, as it would become PID 1's; so it is outside a container too (the tests);
- the command runs in a process group of its own, the terminal's foreground group when there is a terminal
  (Ctrl-C of `docker run -it` reaches the command and whatever it runs in its group, this process not);
- SIGTERM, SIGINT, SIGHUP, SIGQUIT, SIGUSR1 and SIGUSR2 sent to this process go to that whole group: the node
  under `ros2 run` gets `docker stop`'s SIGTERM and shuts down (msfsu_common.node_runner) while `ros2 run` dies;
- it exits once no child is left (the node's shutdown is not cut short by the container ending), with the
  command's exit status (128 + N for a command ended by signal N). A command that ends by itself has what it left
  running sent SIGTERM, and SIGKILL after LEFTOVER_GRACE_S.

Standard library only: it runs on the image's system Python before anything else.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import time
from pathlib import Path

PR_SET_CHILD_SUBREAPER = 36
FORWARDED = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1, signal.SIGUSR2)
LEFTOVER_GRACE_S = 5.0
POLL_S = 0.05


def become_subreaper() -> None:
    if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        print(f"init: cannot become the child subreaper: {os.strerror(ctypes.get_errno())}", file=sys.stderr)


def start(argv: list[str]) -> int:
    """Fork the command into a process group of its own (the terminal's foreground group if there is one)."""
    pid = os.fork()
    if pid == 0:
        try:
            os.setpgid(0, 0)
            if os.isatty(0):
                signal.signal(signal.SIGTTOU, signal.SIG_IGN)  # a background group may not take the terminal
                os.tcsetpgrp(0, os.getpgrp())
                signal.signal(signal.SIGTTOU, signal.SIG_DFL)
            os.execvp(argv[0], argv)
        except OSError as error:
            print(f"init: {argv[0]}: {error.strerror}", file=sys.stderr, flush=True)
        os._exit(127)
    try:
        os.setpgid(pid, pid)  # also here: a signal may come before the child has done it
    except OSError:  # the child did it first, or has exec'd
        pass
    return pid


def children() -> list[int]:
    """The live processes whose parent is this one (orphans it adopted included)."""
    me, found = os.getpid(), []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # gone meanwhile
            continue
        if int(fields[1]) == me and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


def signal_all(group: int, sig: signal.Signals) -> None:
    """`sig` to the command's process group and to every child left (which may have left the group)."""
    for target, send in [(group, os.killpg)] + [(pid, os.kill) for pid in children()]:
        try:
            send(target, sig)
        except ProcessLookupError:
            pass


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: init.py COMMAND [ARG ...]", file=sys.stderr)
        return 2
    become_subreaper()
    command = start(argv)
    stopping = False

    def forward(signum: int, frame) -> None:
        nonlocal stopping
        stopping = True
        try:
            os.killpg(command, signum)
        except ProcessLookupError:  # the group is empty: what is left is reaped below
            pass

    for sig in FORWARDED:
        signal.signal(sig, forward)
    exit_code, kill_at = None, None
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:  # no child left
            break
        if pid == 0:
            if kill_at is not None and time.monotonic() > kill_at:
                signal_all(command, signal.SIGKILL)
                kill_at = None
            time.sleep(POLL_S)
            continue
        if pid == command:
            code = os.waitstatus_to_exitcode(status)
            exit_code = 128 - code if code < 0 else code
            if not stopping:  # the command ended by itself: what it left running is stopped as docker stop would
                signal_all(command, signal.SIGTERM)
                kill_at = time.monotonic() + LEFTOVER_GRACE_S
    return exit_code if exit_code is not None else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
