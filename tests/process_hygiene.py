"""What a finished command may leave behind: Fast DDS files in /dev/shm whose owner is gone, and processes.

Fast DDS (shared-memory transport and data sharing) creates fastrtps_*, fast_datasharing* and
sem.fastrtps_* files in /dev/shm and removes them when a participant is destroyed cleanly; a process
killed without cleanup leaves them. Other users' processes run on this machine too, so a test notes the
files present before it starts and afterwards looks for stale ones (their owner is gone) among the new,
and follows its own process tree.
"""

from __future__ import annotations

import time
from pathlib import Path

SHM = Path("/dev/shm")
FAST_DDS_PREFIXES = ("fastrtps_", "fast_datasharing", "sem.fastrtps_")


def _open_shm_names(process: Path) -> set[str]:
    """/dev/shm names `process` (a /proc/<pid> directory) holds open as file descriptors."""
    names: set[str] = set()
    for fd in (process / "fd").iterdir():
        try:
            target = str(fd.readlink())
        except OSError:  # closed meanwhile: the process's other descriptors still count
            continue
        if target.startswith("/dev/shm/"):
            names.add(target[len("/dev/shm/"):])
    return names


def _in_use() -> tuple[set[str], set[str]]:
    """(/dev/shm names open as a file descriptor, names mapped) by any live process (that this user may inspect)."""
    opened: set[str] = set()
    mapped: set[str] = set()
    for process in Path("/proc").glob("[0-9]*"):
        try:
            for line in (process / "maps").read_text().splitlines():
                if "/dev/shm/" in line:
                    mapped.add(line.rsplit("/dev/shm/", 1)[1].removesuffix(" (deleted)"))
            opened |= _open_shm_names(process)
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return opened, mapped


def owned_segments(pid: int) -> set[str]:
    """The participant segments a live process owns: those whose `_el` lock file it holds (see stale_shm_files;
    its ports' lock files aside: a port is shared)."""
    return {_companion(name) for name in _open_shm_names(Path(f"/proc/{pid}"))
            if name.startswith("fastrtps_") and name.endswith("_el") and not _is_port_file(name)}


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


def _is_port_file(name: str) -> bool:
    """A port's files, shared by every participant that opens the port (see leaked_shm_files)."""
    return name.startswith(("fastrtps_port", "sem.fastrtps_port"))


def stale_shm_files() -> set[str]:
    """Fast DDS files in /dev/shm whose owner is gone.

    A participant holds its segment's lock file `<segment>_el` open for as long as it lives; once no live process
    holds it, the segment and the lock file are stale even while a reader still maps the segment: the owner removes
    its segment at a clean exit, readers never do. (Fast DDS's own `fastdds shm clean` takes a segment for a zombie
    the same way: when its _el lock is free.) Port files, shared by all who open the port, and files without a lock
    file (data-sharing segments) are stale when no live process maps or opens them.
    """
    opened, mapped = _in_use()
    in_use = opened | mapped
    files = fast_dds_files()
    stale = set()
    for name in files:
        segment = _companion(name)
        if not _is_port_file(name) and f"{segment}_el" in files:
            if f"{segment}_el" not in opened:
                stale.add(name)
        elif name not in in_use and segment not in in_use:
            stale.add(name)
    return stale


def leaked_shm_files(present_before: set[str]) -> set[str]:
    """The stale Fast DDS files a finished command left: new since `present_before`, port files aside.

    A port's files (fastrtps_portN, sem.fastrtps_portN_mutex) are one per port number, shared by every participant
    that uses it and reused by the next: Fast DDS leaves them on purpose when the last user's close cannot take the
    port mutex at once (nodes stopping together contend for it, more so on a loaded machine).
    They cannot pile up. Participant segments (80 MiB each, a new name per process) can: any one left is a leak.
    """
    return {name for name in stale_shm_files() - present_before if not _is_port_file(name)}


def remove_stale_shm_files(names: set[str]) -> None:
    """Clean up after a test that kills a process on purpose (SIGKILL leaves Fast DDS files): those of `names`
    that are stale now, a killed owner's segment too while a live reader still maps it."""
    for name in names & stale_shm_files():
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
