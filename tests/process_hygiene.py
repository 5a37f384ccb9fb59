"""What a finished command may leave behind: Fast DDS files in /dev/shm that no process uses, and processes.

Fast DDS (shared-memory transport and data sharing) creates fastrtps_*, fast_datasharing* and
sem.fastrtps_* files in /dev/shm and removes them when a participant is destroyed cleanly; a process
killed without cleanup leaves them. Other users' processes run on this machine too, so a test notes the
files present before it starts and afterwards looks for stale ones (no live process maps them) among the
new, and follows its own process tree.
"""

from __future__ import annotations

import time
from pathlib import Path

SHM = Path("/dev/shm")
FAST_DDS_PREFIXES = ("fastrtps_", "fast_datasharing", "sem.fastrtps_")


def _in_use() -> set[str]:
    """/dev/shm names mapped or open by any live process (that this user may inspect)."""
    names: set[str] = set()
    for process in Path("/proc").glob("[0-9]*"):
        try:
            for line in (process / "maps").read_text().splitlines():
                if "/dev/shm/" in line:
                    names.add(line.rsplit("/dev/shm/", 1)[1].removesuffix(" (deleted)"))
            for fd in (process / "fd").iterdir():
                target = str(fd.readlink())
                if target.startswith("/dev/shm/"):
                    names.add(target[len("/dev/shm/"):])
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return names


def fast_dds_files() -> set[str]:
    """Fast DDS files in /dev/shm, in use or not."""
    return {path.name for path in SHM.iterdir() if path.name.startswith(FAST_DDS_PREFIXES)} if SHM.is_dir() else set()


def _companion(name: str) -> str:
    """The segment a helper file belongs to: sem.fastrtps_portN_mutex -> fastrtps_portN, X_el -> X.

    A live participant keeps its segments mapped, not always their mutex or lock files (opened on use):
    a helper counts as in use while its segment is.
    """
    if name.startswith("sem.") and name.endswith("_mutex"):
        return name[len("sem."):-len("_mutex")]
    return name.removesuffix("_el")


def stale_shm_files() -> set[str]:
    """Fast DDS files in /dev/shm that no live process uses (directly, or through their segment)."""
    in_use = _in_use()
    return {name for name in fast_dds_files() if name not in in_use and _companion(name) not in in_use}


def remove_stale_shm_files(names: set[str]) -> None:
    """Clean up after a test that kills a process on purpose (SIGKILL leaves Fast DDS files)."""
    in_use = _in_use()
    for name in names - in_use:
        (SHM / name).unlink(missing_ok=True)


def descendants(pid: int) -> set[int]:
    """Every process below `pid` now (children, grandchildren, ...)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(parent, []).append(int(stat.parent.name))
    found, pending = set(), [pid]
    while pending:
        for child in children.get(pending.pop(), []):
            found.add(child)
            pending.append(child)
    return found


def alive(pids: set[int]) -> set[int]:
    """The ones still running (zombies count as gone)."""
    running = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        if state != "Z":
            running.add(pid)
    return running


def wait_until_gone(pids: set[int], timeout_s: float) -> set[int]:
    """The processes still alive after up to `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while alive(pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    return alive(pids)
