"""Plays a bag through the real node graph with the bringup `replay` profile and records its outputs.

Every node runs in its own process exactly as deployed; this module only chooses profile
arguments, keeps the nodes' logs in a file and shows progress on the terminal.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from rosbags.rosbag2 import Reader
from tqdm import tqdm

from msfsu_evaluation.recording import RECORDED_TOPICS

# The recorder finds the outputs by discovery (a poll every 0.2 s): the player waits this long after
# perception subscribed so the first frame's action is recorded too.
START_DELAY_S = 1.0
# Time for perception to finish the last frame after the bag ends (a ResNet-50 at 224x224 takes ~0.1 s).
END_DELAY_S = 2.0
STARTUP_ALLOWANCE_S = 120.0  # importing torch, loading the checkpoint, discovery on a busy machine
LOG_TAIL_LINES = 30


class ReplayError(RuntimeError):
    """The graph did not run the bag to its end; the message carries the end of the nodes' log."""


@dataclass(frozen=True)
class ReplayRequest:
    bag: Path
    checkpoint: Path
    recording: Path  # bag directory the outputs are recorded into (must not exist)
    log: Path  # the nodes' stdout/stderr
    rate: float = 1.0
    remap: Mapping[str, str] | None = None  # bag topic -> graph topic
    play_topics: Sequence[str] = ()  # bag topics to play (empty: all)


def replay_command(request: ReplayRequest) -> list[str]:
    """`python -m msfsu_bringup replay --arg ...`; lists and mappings go as JSON, which is YAML flow text."""
    arguments = {
        "bag": str(request.bag),
        "checkpoint": str(request.checkpoint),
        "rate": str(request.rate),
        "record": str(request.recording),
        "record_topics": json.dumps(list(RECORDED_TOPICS)),
        "record_sim_time": "false",
        "remap": json.dumps(dict(request.remap or {})),
        "play_topics": json.dumps(list(request.play_topics)),
        "start_delay": str(START_DELAY_S),
        "end_delay": str(END_DELAY_S),
    }
    command = [sys.executable, "-m", "msfsu_bringup", "replay"]
    for name, value in arguments.items():
        command += ["--arg", f"{name}={value}"]
    return command


def bag_duration_s(bag: Path) -> float:
    with Reader(bag) as reader:
        return reader.duration * 1e-9


def run_replay(request: ReplayRequest, show_progress: bool = True) -> None:
    """Run the replay profile to the end of the bag; ReplayError if it fails or hangs."""
    expected_s = bag_duration_s(request.bag) / request.rate + START_DELAY_S + END_DELAY_S
    timeout_s = expected_s * 2 + STARTUP_ALLOWANCE_S
    started = time.monotonic()
    with request.log.open("w") as log, tqdm(total=round(expected_s, 1), unit="s", desc="replay",
                                            disable=not show_progress, leave=False) as progress:
        process = subprocess.Popen(replay_command(request), stdout=log, stderr=subprocess.STDOUT)
        try:
            while process.poll() is None:
                elapsed = time.monotonic() - started
                if elapsed > timeout_s:
                    raise ReplayError(f"replay still running after {timeout_s:.0f} s\n{_tail(request.log)}")
                progress.n = round(min(elapsed, expected_s), 1)
                progress.refresh()
                time.sleep(0.2)
        finally:
            if process.poll() is None:  # timeout or Ctrl-C: the launcher stops its nodes on SIGINT
                process.send_signal(signal.SIGINT)
                process.wait()
    if process.returncode != 0:
        raise ReplayError(f"the replay graph exited with code {process.returncode}\n{_tail(request.log)}")


def _tail(log: Path) -> str:
    lines = log.read_text(errors="replace").splitlines()[-LOG_TAIL_LINES:]
    return f"last lines of {log}:\n" + "\n".join(lines)
