"""A stage's products committed when it ends, and its progress while it runs (written by hand: no pipeline tool
commits), so that a lost machine costs one stage, or one epoch of a training stage.

A submission takes at most SUBMISSION_MIB of diffs, counted as git's binary patches (a changed fp16 checkpoint counts
about two and a half times its size). So a stage's progress commits are one commit, amended after each look while it
is the newest and not yet submitted (else a new one follows the commit made in between), and one that would take the
unsubmitted commits past the progress limit is undone, its files left on disk. The unsubmitted commits start after
the branch's first reflog entry (the checkout's start: what had landed), or after SUBMIT_BASE where a checkout
outlives a landed submission.
"""

from __future__ import annotations

import os
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from enum import Enum
from pathlib import Path

SUBMISSION_MIB = 256


class Outcome(Enum):
    MADE = "made"
    UNCHANGED = "unchanged"  # nothing to commit
    FAILED = "failed"  # git refused (another git command held the index): tried again at the next look
    UNDONE = "undone"  # over the progress limit: undone, the files left on disk


def git(*args: str, check: bool = False) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["git", *args], capture_output=True, text=True, check=check)


def submit_base() -> str:
    """The commit after which the unsubmitted commits start: SUBMIT_BASE, else the branch's first reflog entry."""
    if os.environ.get("SUBMIT_BASE"):
        return os.environ["SUBMIT_BASE"]
    branch = git("symbolic-ref", "-q", "--short", "HEAD").stdout.strip()
    entries = git("reflog", "show", "--format=%H", branch).stdout.split()
    return entries[-1] if entries else git("rev-parse", "HEAD").stdout.strip()


def unsubmitted_mib() -> int:
    """The unsubmitted commits' diffs as a submission counts them (git's binary patches), in whole MiB."""
    size = 0
    with subprocess.Popen(["git", "log", "-p", "--binary", "--format=", f"{submit_base()}..HEAD"],
                          stdout=subprocess.PIPE, stderr=subprocess.DEVNULL) as log:
        assert log.stdout is not None
        while chunk := log.stdout.read(1 << 20):
            size += len(chunk)
    return size // (1 << 20)


def commit_paths(subject: str, paths: Sequence[str]) -> Outcome:
    """`paths` (and only they) committed as one commit named `subject`; nothing when they did not change."""
    if git("add", "--", *paths).returncode != 0:
        return Outcome.FAILED
    if git("diff", "--cached", "--quiet", "--", *paths).returncode == 0:
        return Outcome.UNCHANGED
    return Outcome.MADE if git("commit", "-q", "-m", subject, "--", *paths).returncode == 0 else Outcome.FAILED


def commit_progress(subject: str, paths: Sequence[str], limit_mib: int) -> tuple[Outcome, int]:
    """`paths` committed as the progress commit named `subject`: amended while it is the newest commit and not yet
    submitted; undone when it takes the unsubmitted commits past `limit_mib`. With the unsubmitted MiB it made."""
    before = git("rev-parse", "HEAD").stdout.strip()
    newest = git("log", "-1", "--format=%s").stdout.rstrip("\n") == subject
    submitted = git("merge-base", "--is-ancestor", "HEAD", submit_base()).returncode == 0
    amend = ["--amend"] if newest and not submitted else []
    if git("add", "--", *paths).returncode != 0:
        return Outcome.FAILED, 0
    if git("commit", "-q", *amend, "-m", subject, "--", *paths).returncode != 0:
        return Outcome.FAILED, 0
    size = unsubmitted_mib()
    if size > limit_mib:
        git("reset", "-q", "--soft", before)
        git("reset", "-q", "--", *paths)
        return Outcome.UNDONE, size
    return Outcome.MADE, size


class ProgressCommitter:
    """Beside a running stage: a look at `watched` every `poll_s`; after each change that has stood still `settle_s`
    (its writer done), `commit()` under `lock`. Stopped with `final`, one last look commits the last change at once
    (the stage's command has ended); stopped without (the command failed), none."""

    def __init__(self, commit: Callable[[], Outcome], watched: Path, poll_s: float, settle_s: float,
                 lock: threading.Lock) -> None:
        self.commit, self.watched, self.poll_s, self.settle_s, self.lock = commit, watched, poll_s, settle_s, lock
        self._stop = threading.Event()
        self._final = False
        self._seen: int | None = None
        self._thread = threading.Thread(target=self._run, name=f"committer {watched}", daemon=True)

    def start(self) -> ProgressCommitter:
        self._thread.start()
        return self

    def stop(self, final: bool) -> None:
        self._final = final
        self._stop.set()
        self._thread.join()

    def _look(self, stopping: bool) -> None:
        try:
            changed = self.watched.stat().st_mtime_ns
        except OSError:
            return
        if changed == self._seen or (not stopping and time.time() - changed / 1e9 < self.settle_s):
            return
        with self.lock:
            outcome = self.commit()
        if outcome is not Outcome.FAILED:
            self._seen = changed

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            self._look(stopping=False)
        if self._final:
            self._look(stopping=True)
